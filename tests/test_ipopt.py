"""The IPOPT path (C interface through ctypes): known optimum and multipliers on HS071, the same
iterates as cyipopt's own binding of the same IPOPT build, warm start, errors."""

import dataclasses
import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.solvers import ipopt_capi
from jaxhumanoid.solvers.ipopt import solve_cyipopt_reference, solve_ipopt
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.validation import testproblems as tp


def test_hs071_optimum_and_multipliers():
    nlp, bounds, p, f_star = tp.hs071()
    r = solve_ipopt(nlp, p, bounds, options={"tol": 1e-10})
    assert r.status == "Solve_Succeeded" and r.success
    assert abs(r.objective - f_star) < 1e-7
    np.testing.assert_allclose(r.x, [1.0, 4.74299963, 3.82114998, 1.37940829], atol=1e-7)
    np.testing.assert_allclose(r.lam_g, [-0.55229366, 0.16146857], atol=1e-7)
    grad = np.asarray(nlp.grad(jnp.asarray(r.x), p))
    J = np.zeros((nlp.m, nlp.n))
    J[nlp.jac_rows, nlp.jac_cols] = np.asarray(nlp.jac_values(jnp.asarray(r.x), p))
    np.testing.assert_allclose(grad + J.T @ r.lam_g - r.z_l + r.z_u, 0.0, atol=1e-8)
    assert r.history["objective"].size == r.iterations + 1
    assert "EXIT: Optimal Solution Found" in r.log
    # f+g and grad+J are fused: at most one fused call per trial point plus one per iterate and H
    assert r.history["eval_calls"] <= 4 * (r.iterations + 1) + 10


def _logged_iterations(log: str) -> list[str]:
    return re.findall(r"^ *\d+r?[ -]+\d", log, flags=re.MULTILINE)


def test_iterations_are_ipopt_s_count_through_the_restoration_phase():
    """IPOPT reports the iterate where its restoration phase returns twice; the count is its own."""
    nlp, bounds, p, _ = tp.wachter_biegler()
    x0 = np.array([-1.0, 3.0, 0.5])
    reports = []
    r = solve_ipopt(nlp, p, bounds, x0=x0, progress=lambda k, f, c: reports.append(k))
    assert r.status == "Solve_Succeeded" and "r " in r.log  # it went through the restoration phase
    assert len(reports) == len(set(reports)) + 1  # one iterate reported twice
    assert r.iterations == len(_logged_iterations(r.log)) - 1 == 15
    assert r.history["objective"].size == r.iterations + 1
    # ended by the restoration phase, which reports one iterate more than IPOPT counts
    r = solve_ipopt(nlp, p, bounds, x0=bounds.x0)
    assert r.status == "Infeasible_Problem_Detected"
    assert r.iterations == len(_logged_iterations(r.log)) - 1 == 16


def test_same_iterates_as_cyipopt_on_the_humanoid():
    pytest.importorskip("cyipopt")
    pr = build_problem("T1", "A,F+C,1S", N=8)
    opts = {"max_iter": 25, "tol": 1e-8}
    ours = solve_ipopt(pr.nlp, pr.p, pr.bounds, options=opts, library_path=ipopt_capi.wheel_library_path())
    x_ref, info, _ = solve_cyipopt_reference(pr.nlp, pr.p, pr.bounds, options=opts)
    # one IPOPT build (the cyipopt wheel's), the same callback values: the iterates agree to round-off
    np.testing.assert_allclose(ours.x, x_ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ours.lam_g, info["mult_g"], rtol=0, atol=1e-6 * max(1.0, np.abs(info["mult_g"]).max()))
    assert abs(ours.objective - info["obj_val"]) <= 1e-9 * max(1.0, abs(info["obj_val"]))


def test_programs_compiled_ahead_are_the_ones_the_solve_runs():
    pr = build_problem("T1", "A,F+C,1S", N=6)
    first = pr.nlp.precompile(pr.bounds.x0, pr.p)
    first.result()
    # the same shapes (another point, another law): the first call's future, no second compilation
    moved = dataclasses.replace(pr.p, contact=ContactParams.relaxed())
    assert pr.nlp.precompile(pr.bounds.x0 + 0.1, moved) is first
    ev = pr.nlp.jitted()
    sizes = [fn._cache_size() for fn in (ev.fg, ev.grad_jac, ev.hess)]
    assert sizes == [1, 1, 1]
    solve_ipopt(pr.nlp, pr.p, pr.bounds, options={"max_iter": 3})
    assert [fn._cache_size() for fn in (ev.fg, ev.grad_jac, ev.hess)] == sizes  # no other signature traced
    wrong = pr.nlp.precompile(np.zeros(pr.nlp.n + 1), pr.p)  # other shapes: a compilation of their own
    assert wrong is not first
    with pytest.raises(ValueError):  # an error in a program comes back through the future
        wrong.result()


def test_warm_start_from_multipliers_converges_at_once():
    nlp, bounds, p, _ = tp.hs071()
    cold = solve_ipopt(nlp, p, bounds, options={"tol": 1e-10})
    warm = solve_ipopt(
        nlp,
        p,
        bounds,
        x0=cold.x,
        warm=cold,
        options={
            "tol": 1e-10,
            "warm_start_init_point": "yes",
            "mu_init": 1e-9,
            "warm_start_bound_push": 1e-12,
            "warm_start_mult_bound_push": 1e-12,
        },
    )
    assert warm.success and warm.iterations <= 2 < cold.iterations
    np.testing.assert_allclose(warm.x, cold.x, atol=1e-8)


def test_both_ipopt_libraries_solve_to_one_optimum():
    # the casadi wheel's IPOPT (the default where present) and the cyipopt wheel's
    casadi_lib = ipopt_capi.casadi_library_path()
    if casadi_lib is None:
        pytest.skip("the casadi wheel ships no IPOPT library here")
    assert ipopt_capi.default_library_path() == casadi_lib or "JAXHUMANOID_IPOPT_LIBRARY" in os.environ
    nlp, bounds, p, expected = tp.hs071()
    runs = [solve_ipopt(nlp, p, bounds, options={"tol": 1e-10}, library_path=lib) for lib in (casadi_lib, None)]
    runs.append(solve_ipopt(nlp, p, bounds, options={"tol": 1e-10}, library_path=ipopt_capi.wheel_library_path()))
    for r in runs:
        assert r.success
        np.testing.assert_allclose(r.x, runs[0].x, atol=1e-8)
    assert "3.14.19" in runs[0].log and "3.14.11" in runs[2].log  # the banner names each build


def test_errors_are_clear():
    nlp, bounds, p, _ = tp.hs071()
    with pytest.raises(ValueError, match="options\\['no_such_option'\\]"):
        solve_ipopt(nlp, p, bounds, options={"no_such_option": 1})
    with pytest.raises(ValueError, match="options\\['tol'\\]"):
        solve_ipopt(nlp, p, bounds, options={"tol": -1.0})
    with pytest.raises(ValueError, match="x0: expected shape"):
        solve_ipopt(nlp, p, bounds, x0=np.zeros(3))


def test_integral_values_of_number_options_are_taken():
    # a command line or a TOML file gives mu_init=1 and tol=1 as integers; IPOPT's integer setter
    # rejects number options, so they must reach its number setter
    nlp, bounds, p, _ = tp.hs071()
    opts = {"mu_init": 1, "tol": 1, "acceptable_tol": 10}
    ipopt_capi.check_options(opts)
    res = solve_ipopt(nlp, p, bounds, options={**opts, "tol": 1e-8})
    assert res.success
    loose = solve_ipopt(nlp, p, bounds, options=opts)
    assert loose.iterations < res.iterations  # tol=1 was set, not ignored
    # integer options still go to the integer setter, with their range checked
    capped = solve_ipopt(nlp, p, bounds, options={"max_iter": 1, "mu_init": 1})
    assert capped.status == "Maximum_Iterations_Exceeded" and capped.iterations == 1
    with pytest.raises(ValueError, match="options\\['max_iter'\\]"):
        ipopt_capi.check_options({"max_iter": -1})


def test_an_exception_in_a_callback_is_raised_not_reported_as_a_status():
    nlp, bounds, p, _ = tp.hs071()

    class Boom(RuntimeError):
        pass

    calls = {"n": 0}

    def g(x, p):
        return jax.pure_callback(_raise_after(calls, Boom), jax.ShapeDtypeStruct((2,), jnp.float64), x)

    broken = dataclasses.replace(nlp, g=g, name="broken")
    # JAX re-wraps an exception raised on the host; its message survives
    with pytest.raises(Exception, match="model error"):
        solve_ipopt(broken, p, bounds)


def _raise_after(calls, exc):
    def host(x):
        calls["n"] += 1
        if calls["n"] > 2:  # the compile-time warm-up call passes, IPOPT's first calls fail
            raise exc("model error")
        return np.zeros(2)

    return host
