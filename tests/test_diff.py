"""Sensitivities of optimal solutions (jaxhumanoid.diff): implicit differentiation of the KKT
conditions checked against central differences of warm-started IPOPT re-solves, ``make_solve``
with IPOPT and with the IPM, and inverse optimal control of the cost weights.

Each task (A,F+C,1S, N = 15, dynamic model) is solved once per module (tol 1e-10) and reused.
Agreement is measured in the 2-norm over all NLP variables, ||dx_ift - dx_fd||_2 / ||dx_fd||_2,
and must be below 1e-4, while a wrong sign, a missed active set or flipped multipliers must miss
by more than 1e-2. The default run covers T3 (every parameter group) and T1 (two groups) and
one inverse problem; ``-m slow`` adds every group on T1, T2, T4 and the inverse problem on all
four tasks.
"""

from __future__ import annotations

import dataclasses
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("cyipopt")

from jaxhumanoid import diff as S  # noqa: E402
from jaxhumanoid.outputs import cli  # noqa: E402
from jaxhumanoid.strategy.problem import build_problem  # noqa: E402

TOL = S.FD_TOL  # 1e-4 relative, 2-norm
EPS = 1e-5  # relative step of the central differences (directions are relative to p)
MUTATION_MIN = 1e-2  # a wrong sign or a missed active set must miss by more than this
ALL_GROUPS = S.GROUPS + ("goal",)
# default run: every parameter group on T3 and two on T1 (warm re-solves dominate the runtime)
DEFAULT_CASES = (("T3", ALL_GROUPS), ("T1", ("weights", "goal")))
SLOW_CASES = (("T1", ALL_GROUPS), ("T2", ALL_GROUPS), ("T4", ALL_GROUPS))


@pytest.fixture(scope="module")
def solved():
    """One converged reference solve per task (A,F+C,1S, N = 15, tol 1e-10), built on demand."""
    cache = {}

    def get(task):
        if task not in cache:
            prob = build_problem(task, "A,F+C,1S", N=15, T=5.0)
            cache[task] = (prob, S.reference_solve(prob, tol=1e-10))  # IPOPT, with option fall-backs
        return cache[task]

    return get


@pytest.fixture(scope="module")
def case(solved):
    prob, res = solved("T1")
    return prob, res, S.KKTSensitivity(prob, res)


def _check_groups(solved, task, groups):
    prob, res = solved(task)
    out = S.check_against_fd(problem=prob, result=res, eps=EPS, groups=groups, verbose=False)
    rep = out["active_set"]
    assert rep["strict_complementarity"]
    assert rep["stationarity"] < 1e-7  # IPOPT's sign convention: grad f + J^T lam - z_l + z_u = 0
    assert rep["n_active_ineq"] + rep["n_lower"] + rep["n_upper"] > 0  # bounds/inequalities to get right
    assert [r["group"] for r in out["rows"]] == list(groups)
    for r in out["rows"]:
        assert r["norm_dx"] > 0, r["group"]
        assert r["rel_err_dx_2norm"] < TOL, r
        assert r["rel_err_dV_env_fd"] < TOL, r  # envelope theorem against FD of the optimal value
        assert r["rel_err_dV_env_chain"] < 1e-8, r  # envelope against the chain rule through dx*
        assert r["dropped_residual"] < 1e-8, r  # dependent active rows (if any) hold to first order
    # the tolerance is tight enough to reject a wrong sign, a missed active set and multipliers
    # read with the opposite sign convention
    assert min(out["mutations_weights_rel_err_dx"].values()) > MUTATION_MIN, out["mutations_weights_rel_err_dx"]
    rows = S.table_rows(out)
    assert len(rows) == 2 * len(out["rows"]) and all(r["ok"] for r in rows)


@pytest.mark.parametrize("task, groups", DEFAULT_CASES)
def test_sensitivities_match_finite_differences(solved, task, groups):
    _check_groups(solved, task, groups)


@pytest.mark.slow
@pytest.mark.parametrize("task, groups", SLOW_CASES)
def test_sensitivities_match_finite_differences_slow(solved, task, groups):
    _check_groups(solved, task, groups)


def test_vjp_jvp_consistency(case):
    prob, res, kkt = case
    ct = np.random.default_rng(5).normal(size=prob.nlp.n)
    dp_bar, goal_bar = kkt.vjp(ct, goal=True)
    for group in S.GROUPS:
        dp = S.param_direction(prob.p, group, seed=2)
        lhs, rhs = S.tree_vdot(dp_bar, dp), ct @ kkt.jvp(dp)
        assert abs(lhs - rhs) < 1e-9 * max(abs(rhs), 1.0), group
    dgoal = np.random.default_rng(6).uniform(-1, 1, prob.p.model.n)
    assert abs(goal_bar @ dgoal - ct @ kkt.jvp(None, dgoal=dgoal)) < 1e-9 * max(abs(goal_bar @ dgoal), 1.0)
    # the functional API gives the same
    dp_fun = S.solution_vjp(prob, res, ct)
    assert S.rel_err(np.asarray(dp_fun.weights), np.asarray(dp_bar.weights)) < 1e-12


def test_weakly_active_pair_warns(case):
    prob, res, kkt = case
    x = res.x.copy()
    i = np.flatnonzero(kkt.active.lower)[0]
    z_l = res.z_l.copy()
    z_l[i] = 1e-9  # active bound with a vanishing multiplier
    with pytest.warns(S.StrictComplementarityWarning):
        S.identify_active_set(prob.bounds, x, kkt.g_val, res.lam_g, z_l, res.z_u, ignore_bounds=S.implied_bounds(prob))


def test_jax_grad_through_solve(case):
    prob, res, kkt = case
    solve = S.make_solve(prob, options={"tol": 1e-10})
    warm = S.warm_start(res, prob.p)
    ct = np.random.default_rng(7).normal(size=prob.nlp.n)
    ref = kkt.vjp(ct)

    def loss_w(w):
        return jnp.dot(ct, solve(dataclasses.replace(prob.p, weights=w), warm)[0])

    def loss_c(kappa, f0, xhat, mu):
        c = jax.tree.unflatten(jax.tree.structure(prob.p.contact), [kappa, f0, xhat, mu])
        return jnp.dot(ct, solve(dataclasses.replace(prob.p, contact=c), warm)[0])

    gw = jax.grad(loss_w)(jnp.asarray(prob.p.weights))
    assert S.rel_err(gw, ref.weights) < 1e-8
    leaves = [jnp.asarray(v, dtype=jnp.float64) for v in jax.tree.leaves(prob.p.contact)]
    gc = jax.grad(loss_c, argnums=(0, 1, 2, 3))(*leaves)
    assert S.rel_err(np.array(gc), np.array([np.asarray(v) for v in jax.tree.leaves(ref.contact)])) < 1e-8


def test_solve_depends_only_on_its_inputs(case):
    """The same (p, warm) gives the same x*, multipliers and gradient whatever was solved before."""
    prob, res, _ = case
    solve = S.make_solve(prob, options={"tol": 1e-10})
    warm = S.warm_start(res, prob.p)
    ct = jnp.asarray(np.random.default_rng(8).normal(size=prob.nlp.n))
    w0 = jnp.asarray(prob.p.weights)

    def loss(w):
        x, point = solve(dataclasses.replace(prob.p, weights=w), warm)
        return jnp.dot(ct, x), point

    grad = jax.value_and_grad(loss, has_aux=True)
    (_, first), g_first = grad(w0 * 1.1)
    _, point = solve(prob.p, warm)  # another solve in between, and its result as a warm start
    solve(dataclasses.replace(prob.p, weights=w0 * 0.9), point)
    (_, again), g_again = grad(w0 * 1.1)
    assert bool(first.success) and int(first.iterations) == int(again.iterations)
    for a, b in zip(first[:4], again[:4]):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    assert np.array_equal(np.asarray(g_first), np.asarray(g_again))


def test_grad_through_ipm_matches_ipopt_and_fd():
    """jax.grad through the jitted IPM (no callback in the forward pass) agrees with the IPOPT
    path and with central differences of IPOPT re-solves (T3, N = 10: from IPOPT's solution the
    IPM converges in a few iterations; at N = 15 its primal warm start fails)."""
    prob = build_problem("T3", "A,F+C,1S", N=10, T=5.0)
    res = S.reference_solve(prob, tol=1e-10)
    ct = jnp.asarray(np.random.default_rng(9).normal(size=prob.nlp.n))
    dw = S.param_direction(prob.p, "weights", seed=3).weights
    w0 = jnp.asarray(prob.p.weights)

    def loss_of(solve, warm):
        def loss(w):
            x, point = solve(dataclasses.replace(prob.p, weights=w), warm)
            return jnp.dot(ct, x), point

        return loss

    ipm = S.make_solve(prob, solver="ipm", options={"tol": 1e-10})
    (_, point), g_ipm = jax.value_and_grad(loss_of(ipm, S.warm_start(res, prob.p)), has_aux=True)(w0)
    assert bool(point.success) and S.rel_err(point.x, res.x) < 1e-6  # the same local optimum as IPOPT
    ipopt = S.make_solve(prob, options={"tol": 1e-10})
    (_, _), g_ipopt = jax.value_and_grad(loss_of(ipopt, S.warm_start(res, prob.p)), has_aux=True)(w0)
    assert S.rel_err(g_ipm, g_ipopt) < 1e-6
    dx_fd, _, _ = S.fd_directional(prob, res, dataclasses.replace(S.zeros_like_params(prob.p), weights=dw))
    fd = float(np.asarray(ct) @ dx_fd)
    assert abs(float(np.asarray(g_ipm) @ dw) - fd) < 1e-4 * abs(fd)
    with pytest.raises(ValueError, match="solver"):
        S.make_solve(prob, solver="casadi")


# Inverse optimal control: weights perturbed by factors 2-5 are recovered from the trajectory.


def _inverse(solved, task, method):
    prob, res = solved(task)
    w_true = np.asarray(prob.p.weights, dtype=float)
    fit = S.WeightFit(prob, res.x, S.perturbed_weights(w_true, seed=0))  # factors 2-5, w_qd fixed
    theta = fit.gauss_newton() if method == "gn" else fit.lbfgs()
    out = fit.summary(theta, w_true)
    assert out["loss_initial"] > 1e-2  # the perturbed weights give a visibly different motion
    return out


@pytest.mark.parametrize("task", ["T3"])
def test_inverse_ocp_recovers_weights(solved, task):
    out = _inverse(solved, task, "gn")
    assert out["max_rel_weight_error"] < 1e-6, out["recovered_factors"]
    assert out["max_abs_q_error_rad"] < 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("task", ["T1", "T2", "T4"])
def test_inverse_ocp_recovers_weights_slow(solved, task):
    test_inverse_ocp_recovers_weights(solved, task)


@pytest.mark.slow
def test_inverse_ocp_lbfgs_through_make_solve(solved):
    out = _inverse(solved, "T3", "lbfgs")
    assert out["loss_final"] < 1e-3 * out["loss_initial"]
    assert out["max_rel_weight_error"] < 0.1, out["recovered_factors"]


def test_weight_fit_rejects_bad_input(case):
    prob, res, _ = case
    with pytest.raises(ValueError, match="w_init"):
        S.WeightFit(prob, res.x, -np.ones(8))
    with pytest.raises(ValueError, match="x_data"):
        S.WeightFit(prob, res.x[:-1], np.ones(8))


@pytest.mark.slow
def test_cli_check_sensitivities(capsys):
    assert cli.main(["check", "--sensitivities", "--task", "T3"]) == 0
    text = capsys.readouterr().out
    assert "dx* weights" in text and "12 passed, 0 failed" in text


@pytest.mark.slow
def test_cli_check_sensitivities_of_a_task_file(capsys):
    path = pathlib.Path(__file__).resolve().parents[1] / "examples" / "paper" / "T4.toml"
    assert cli.main(["check", "--sensitivities", "--task-file", str(path)]) == 0
    text = capsys.readouterr().out
    assert "T4 A,F+C,1S N=15" in text and "12 passed, 0 failed" in text
