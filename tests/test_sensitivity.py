"""Sensitivities of optimal solutions (issue 7): implicit differentiation of the KKT conditions
checked against central differences of warm-started IPOPT re-solves.

One small problem with real contacts (T1, A,F+C,1S, N = 15, dynamic model) is solved once per
module (tol 1e-10); every check reuses it. Agreement is measured in the 2-norm over all NLP
variables: ||dx_ift - dx_fd||_2 / ||dx_fd||_2.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("cyipopt")

from jaxhumanoid import sensitivity as S  # noqa: E402
from jaxhumanoid.strategy.problem import build_problem  # noqa: E402

TOL = 1e-4  # relative, 2-norm
EPS = 1e-5  # relative step of the central differences (directions are relative to p)


@pytest.fixture(scope="module")
def case():
    prob = build_problem("T1", "A,F+C,1S", N=15, T=5.0)
    res = S.reference_solve(prob, tol=1e-10)  # IPOPT, with option fall-backs
    kkt = S.KKTSensitivity(prob, res)
    return prob, res, kkt, {}


def _fd(case, group):
    prob, res, _, cache = case
    if group not in cache:
        dp = S.param_direction(prob.p, group, seed=1)
        dx, dV, _ = S.fd_directional(prob, res, dp, eps=EPS)
        cache[group] = (dp, dx, dV)
    return cache[group]


def test_active_set_has_contacts_and_strict_complementarity(case):
    prob, res, kkt, _ = case
    rep = kkt.report()
    assert rep["strict_complementarity"]
    # steady-foot constraints (5), joint limits, goal box (which ones depends on the local optimum)
    assert rep["n_active_ineq"] + rep["n_lower"] + rep["n_upper"] > 0
    assert rep["stationarity"] < 1e-7  # IPOPT's sign convention: grad f + J^T lam - z_l + z_u = 0
    assert rep["min_active_multiplier"] > 1e-4


@pytest.mark.parametrize("group", ["weights", "contact", "model"])
def test_jvp_matches_finite_differences(case, group):
    prob, res, kkt, _ = case
    dp, dx_fd, _ = _fd(case, group)
    dx = kkt.jvp(dp)
    assert np.linalg.norm(dx) > 0
    assert S.rel_err(dx, dx_fd) < TOL
    assert kkt.dropped_residual < 1e-8  # dependent active rows (if any) hold to first order


def test_goal_jvp_matches_finite_differences(case):
    prob, res, kkt, _ = case
    dgoal = np.random.default_rng(0).uniform(-1, 1, 5)
    dx_fd, dV_fd, _ = S.fd_directional(prob, res, dgoal=dgoal, eps=EPS)
    dx = kkt.jvp(None, dgoal=dgoal)
    assert S.rel_err(dx, dx_fd) < TOL
    _, dV_goal = kkt.objective_gradient(goal=True)
    assert abs(dV_goal @ dgoal - dV_fd) < TOL * abs(dV_fd)


@pytest.mark.parametrize("group", ["weights", "contact", "model"])
def test_objective_derivative_envelope(case, group):
    prob, res, kkt, _ = case
    dp, _, dV_fd = _fd(case, group)
    env = S.tree_vdot(kkt.objective_gradient(), dp)
    chain = kkt.objective_jvp(dp)
    assert abs(env - chain) < 1e-8 * abs(env)
    assert abs(env - dV_fd) < TOL * abs(dV_fd)


def test_vjp_jvp_consistency(case):
    prob, res, kkt, _ = case
    ct = np.random.default_rng(5).normal(size=prob.nlp.n)
    dp_bar, goal_bar = kkt.vjp(ct, goal=True)
    for group in S.GROUPS:
        dp = S.param_direction(prob.p, group, seed=2)
        lhs, rhs = S.tree_vdot(dp_bar, dp), ct @ kkt.jvp(dp)
        assert abs(lhs - rhs) < 1e-9 * max(abs(rhs), 1.0), group
    dgoal = np.random.default_rng(6).uniform(-1, 1, 5)
    assert abs(goal_bar @ dgoal - ct @ kkt.jvp(None, dgoal=dgoal)) < 1e-9 * max(abs(goal_bar @ dgoal), 1.0)
    # the functional API gives the same
    dp_fun = S.solution_vjp(prob, res, ct)
    assert S.rel_err(np.asarray(dp_fun.weights), np.asarray(dp_bar.weights)) < 1e-12


def test_mutation_wrong_multiplier_sign_fails_check(case):
    prob, res, kkt, _ = case
    dp, dx_fd, _ = _fd(case, "contact")
    # flipped multiplier signs: wrong Hessian of the Lagrangian, wrong right-hand side and a
    # wrong active set (IPOPT's sign convention for g >= 0 read the other way round)
    bad = S.KKTSensitivity(prob, res, lam_g=-res.lam_g, warn=False)
    assert S.rel_err(bad.jvp(dp), dx_fd) > 1e-2


def test_mutation_wrong_active_set_fails_check(case):
    prob, res, kkt, _ = case
    dp, dx_fd, _ = _fd(case, "weights")
    act = kkt.active
    # forget the active inequalities (steady-foot constraints) and the active bounds
    wrong = dataclasses.replace(act, rows=act.rows & ~act.ineq_active, ineq_active=np.zeros_like(act.ineq_active), lower=np.zeros_like(act.lower), upper=np.zeros_like(act.upper))
    bad = S.KKTSensitivity(prob, res, active=wrong)
    assert S.rel_err(bad.jvp(dp), dx_fd) > 1e-2
    # the correct set passes the same check
    assert S.rel_err(kkt.jvp(dp), dx_fd) < TOL


def test_weakly_active_pair_warns(case):
    prob, res, kkt, _ = case
    x = res.x.copy()
    i = np.flatnonzero(kkt.active.lower)[0]
    z_l = res.z_l.copy()
    z_l[i] = 1e-9  # active bound with a vanishing multiplier
    with pytest.warns(S.StrictComplementarityWarning):
        S.identify_active_set(prob.bounds, x, kkt.g_val, res.lam_g, z_l, res.z_u, ignore_bounds=S.implied_bounds(prob))


def test_jax_grad_through_solve(case):
    prob, res, kkt, _ = case
    solve = S.make_solve(prob, result=res, options={"tol": 1e-10})
    ct = np.random.default_rng(7).normal(size=prob.nlp.n)
    ref = kkt.vjp(ct)

    def loss_w(w):
        return jnp.dot(ct, solve(dataclasses.replace(prob.p, weights=w)))

    def loss_c(kappa, f0, xhat, mu):
        c = jax.tree.unflatten(jax.tree.structure(prob.p.contact), [kappa, f0, xhat, mu])
        return jnp.dot(ct, solve(dataclasses.replace(prob.p, contact=c)))

    gw = jax.grad(loss_w)(jnp.asarray(prob.p.weights))
    assert S.rel_err(gw, ref.weights) < 1e-8
    leaves = [jnp.asarray(v, dtype=jnp.float64) for v in jax.tree.leaves(prob.p.contact)]
    gc = jax.grad(loss_c, argnums=(0, 1, 2, 3))(*leaves)
    assert S.rel_err(np.array(gc), np.array([np.asarray(v) for v in jax.tree.leaves(ref.contact)])) < 1e-8
    assert solve.stats["solves"] == 2 and solve.stats["adjoints"] == 2

