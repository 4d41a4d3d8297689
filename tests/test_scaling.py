"""The physical scaling of the NLP (``ocp.scaling``): its factors follow the variable and row kinds,
the scaled NLP's functions are the derivatives of the scaled problem, and a solve of the scaled
problem comes back in the original units: its multipliers satisfy the original problem's KKT
conditions (and the scaled ones do not), for every backend, at the unscaled solve's optimum."""

from __future__ import annotations

import dataclasses
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.ocp import scaling as sc
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.runner import Runner
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solve import solve

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_nlinks import CHAINS, TASKS  # noqa: E402  (the small chains and their tasks)


def _kinds(layout: tr.Layout) -> np.ndarray:
    """0 for q and qd, 1 for u, 2 for f, per NLP variable."""
    sl, Z = layout.stage_slices(), np.zeros((layout.N + 1, layout.s))
    Z[:, sl["u"]], Z[:, sl["f"]] = 1, 2
    return np.asarray(tr.free_from_full(layout, Z)).astype(int)


@pytest.mark.parametrize("pseudo_static", [False, True])
def test_factors_follow_the_variable_and_row_kinds(pseudo_static):
    problem = build_problem("T1", "A,F+C,1S", N=6, T=3.0)
    layout = dataclasses.replace(problem.layout, pseudo_static=pseudo_static)
    s = sc.physical_scaling(layout, 3.0)
    assert s.x.shape == (problem.nlp.n,) and s.g.shape == (problem.nlp.m,)
    unit = np.array([1.0, 1.0 / sc.TORQUE_UNIT, 1.0 / sc.FORCE_UNIT])
    np.testing.assert_array_equal(s.x, unit[_kinds(layout)])
    rows, n, nf = s.g.reshape(layout.N, layout.n_con), layout.n_links, layout.n_f
    dyn = 1.0 / sc.TORQUE_UNIT if layout.pseudo_static else layout.N / (sc.TORQUE_UNIT * 3.0)  # (8) or h (6b)
    assert np.all(rows[:, :n] == 1.0) and np.allclose(rows[:, n : 2 * n], dyn)
    assert np.all(rows[:, 2 * n : 2 * n + nf + tr.N_FOOT] == 1.0 / sc.FORCE_UNIT)
    assert np.all(rows[:, 2 * n + nf + tr.N_FOOT :] == 1.0 / sc.LENGTH_UNIT)
    assert s.obj == 1.0 / sc.OBJECTIVE_UNIT


def test_the_scaled_functions_are_the_derivatives_of_the_scaled_problem():
    problem = build_problem("T1", "A,F+C,1S", N=4)
    nlp, p = problem.nlp, problem.p
    s = sc.physical_scaling(problem.layout, float(p.T))
    view, ps = sc.scaled_nlp(nlp), (p, sc.as_jax(s))
    assert sc.scaled_nlp(nlp) is view  # built once per NLP
    rng = np.random.default_rng(0)
    x = problem.bounds.x0 + 0.01 * rng.standard_normal(nlp.n)
    y, lam, sigma = jnp.asarray(x * s.x), jnp.asarray(rng.standard_normal(nlp.m)), 0.7

    def f(y_):
        return s.obj * nlp.f(y_ / s.x, p)

    def g(y_):
        return s.g * nlp.g(y_ / s.x, p)

    assert float(view.f(y, ps)) == pytest.approx(float(s.obj * nlp.f(jnp.asarray(x), p)), rel=1e-14)
    np.testing.assert_allclose(view.g(y, ps), s.g * np.asarray(nlp.g(jnp.asarray(x), p)), rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(view.grad(y, ps), jax.grad(f)(y), rtol=1e-10, atol=1e-12)
    J = np.zeros((nlp.m, nlp.n))
    J[nlp.jac_rows, nlp.jac_cols] = np.asarray(view.jac_values(y, ps))
    np.testing.assert_allclose(J, jax.jacfwd(g)(y), rtol=1e-10, atol=1e-10)
    H = np.asarray(jax.hessian(lambda y_: sigma * f(y_) + lam @ g(y_))(y))
    np.testing.assert_allclose(
        view.hess_values(y, lam, sigma, ps), H[nlp.hess_rows, nlp.hess_cols], rtol=1e-9, atol=1e-9
    )
    b = sc.scaled_bounds(problem.bounds, s)
    np.testing.assert_allclose(b.x0 / s.x, problem.bounds.x0, rtol=1e-15)
    np.testing.assert_array_equal(np.isfinite(b.gu), np.isfinite(problem.bounds.gu))


def _stationarity(problem, res) -> float:
    """max |grad f + J^T lam - z_l + z_u| at res.x, relative to max |grad f| (the original problem)."""
    nlp, p, x = problem.nlp, problem.p, jnp.asarray(res.x)
    grad = np.asarray(nlp.grad(x, p))
    J = np.zeros((nlp.m, nlp.n))
    J[nlp.jac_rows, nlp.jac_cols] = np.asarray(nlp.jac_values(x, p))
    r = grad + J.T @ res.lam_g - res.z_l + res.z_u
    return float(np.max(np.abs(r)) / np.max(np.abs(grad)))


@pytest.mark.slow
@pytest.mark.parametrize("solver", ["ipopt", "ipm", "casadi"])
def test_a_scaled_solve_comes_back_in_the_original_units(solver):
    problem = build_problem(TASKS[2], "A,F+C,1S", N=15, T=0.6, model=CHAINS[2])
    plain = Runner(solver).run(problem, problem.bounds.x0, {}, "single stage")
    scaled = Runner(solver, scaling="physical").run(problem, problem.bounds.x0, {}, "single stage")
    assert plain.success and scaled.success
    assert scaled.objective == pytest.approx(plain.objective, rel=1e-6)
    np.testing.assert_allclose(scaled.x, plain.x, atol=1e-4)
    assert scaled.max_constraint_violation < 1e-6
    assert _stationarity(problem, scaled) < 1e-6
    s = sc.physical_scaling(problem.layout, 0.6)
    raw = dataclasses.replace(scaled, lam_g=scaled.lam_g * s.obj / s.g)  # the multipliers left scaled
    assert _stationarity(problem, raw) > 1e-2  # the mutation: the KKT check sees the missing unscaling


@pytest.mark.slow
def test_three_backends_reach_one_optimum_through_the_scaled_two_stage_solve():
    settings = SolveSettings(N1=8, scaling="physical")
    kw = dict(task=TASKS[2], scheme="A,F+C,2S", N=15, T=0.6, model=CHAINS[2], settings=settings)
    sols = {s: solve(solver=s, **kw) for s in ("ipopt", "ipm", "casadi")}
    assert all(sol.success for sol in sols.values())
    ref = sols["ipopt"]
    for sol in sols.values():
        assert sol.objective == pytest.approx(ref.objective, rel=1e-6)
        np.testing.assert_allclose(sol.q, ref.q, atol=1e-4)


def test_an_unknown_scaling_is_refused_before_any_work():
    with pytest.raises(ValueError, match=r"scaling: expected one of \('none', 'physical'\), got 'unit'"):
        SolveSettings(scaling="unit")
