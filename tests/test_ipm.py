"""The own interior-point method on Hock-Schittkowski problems, a restoration case, an infeasible
problem, a staged optimal-control problem, a vmap batch, warm start and option validation."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp.nlp import Bounds
from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, with_force_limit
from jaxhumanoid.solvers.ipm import IPMOptions, batch_solve_ipm, kkt, solve_ipm
from jaxhumanoid.solvers.ipopt import solve_cyipopt_reference, solve_ipopt
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.studies.bench import BENCH_STAGE1_OPTIONS
from jaxhumanoid.validation import testproblems as tp

# degenerate HS013 (no constraint qualification at x*): IPOPT 3.14 and the IPM both stop at
# f = 0.994579 after 55 iterations, 5.4e-3 from f* = 1
F_TOL = {"hs013": 1e-2}


# each problem is one XLA compilation (~10 s on 2 cores): the default run keeps three
# representative ones (equality+bounds nonconvex, linear inequality QP, nonconvex inequality);
# the rest run with ``-m slow``
FAST_HS = ("hs071", "hs035", "hs010")


@pytest.mark.parametrize(
    "name", [n if n in FAST_HS else pytest.param(n, marks=pytest.mark.slow) for n in sorted(tp.HS_PROBLEMS)]
)
def test_hock_schittkowski_optimum(name):
    nlp, bounds, p, f_star = tp.HS_PROBLEMS[name]()
    r = solve_ipm(nlp, p, bounds)
    assert r.success, (r.status, r.log)
    assert abs(r.objective - f_star) <= F_TOL.get(name, 1e-6) * max(1.0, abs(f_star)), r.log
    assert r.max_constraint_violation <= 1e-6
    assert r.history["obj"].shape == (r.iterations + 1,)
    assert "EXIT: " + r.status in r.log
    # the same algorithm as IPOPT 3.14 with its defaults: the same iteration count on every problem
    assert r.iterations == solve_ipopt(nlp, p, bounds).iterations


def test_hs071_multipliers_match_ipopt_convention():
    nlp, bounds, p, _ = tp.hs071()
    r = solve_ipm(nlp, p, bounds)
    assert r.status == "Solve_Succeeded" and r.iterations <= 15
    np.testing.assert_allclose(r.x, [1.0, 4.74299963, 3.82114998, 1.37940829], atol=1e-6)
    # Lagrangian L = f + lam^T g: IPOPT reports lam = (-0.55229366, 0.16146857) for HS071
    np.testing.assert_allclose(r.lam_g, [-0.55229366, 0.16146857], atol=1e-6)
    grad = np.asarray(nlp.grad(jnp.asarray(r.x), p))
    J = np.asarray(nlp.jac_values(jnp.asarray(r.x), p)).reshape(nlp.m, nlp.n)
    np.testing.assert_allclose(grad + J.T @ r.lam_g - r.z_l + r.z_u, 0.0, atol=1e-6)


def test_a_warm_start_push_reaches_the_slacks_as_in_ipopt():
    """IPOPT pushes the inequality slacks by bound_push and bound_frac unless slack_bound_push and
    slack_bound_frac are given. HS071's start sits on its inequality's bound (g1 = 25), so the
    slack push decides the first step: with a warm start's small push the IPM's first iterate is
    IPOPT's, and with the slacks pushed by the old fixed 1e-2 it is not."""
    nlp, bounds, p, _ = tp.hs071()
    warm = {"mu_init": 1e-5, "bound_push": 1e-6, "bound_frac": 1e-6, "max_iter": 1}
    ref = solve_ipopt(nlp, p, bounds, options=warm).x
    assert IPMOptions(bound_push=1e-6).slack_bound_frac == 1e-2 and IPMOptions(bound_push=1e-6).slack_bound_push == 1e-6
    np.testing.assert_allclose(solve_ipm(nlp, p, bounds, options=warm).x, ref, rtol=1e-9, atol=1e-12)
    fixed = solve_ipm(nlp, p, bounds, options={**warm, "slack_bound_push": 1e-2, "slack_bound_frac": 1e-2}).x
    assert np.abs(fixed - ref).max() > 1e-5  # 1e4 times the agreement above


def test_one_sided_bounds_are_damped_with_ipopt_s_kappa_d():
    """IPOPT 3.14 damps one-sided bounds with kappa_d = 1e-5 (the paper's Sec. 3.7 has 1e-4).
    HS001's x2 has only a lower bound: with IPOPT's value the IPM ends at IPOPT's point to
    rounding, in as many iterations, and with the paper's it lands 1e-10 away."""
    nlp, bounds, p, _ = tp.hs001()
    ref = solve_ipopt(nlp, p, bounds)
    r = solve_ipm(nlp, p, bounds)
    assert r.iterations == ref.iterations and np.abs(r.x - ref.x).max() <= 1e-13
    paper = solve_ipm(nlp, p, bounds, options={"kappa_d": 1e-4})
    assert np.abs(paper.x - ref.x).max() > 1e-11


@pytest.mark.parametrize(
    "x0,status", [((-2.0, 1.0, 1.0), "Infeasible_Problem_Detected"), ((-1.0, 3.0, 0.5), "Solve_Succeeded")]
)
def test_restoration_phase_as_ipopt_on_wachter_biegler_example(x0, status):
    """The filter line search fails on this example and both starts enter the l1 restoration
    phase; IPOPT 3.14 then ends at the locally infeasible point (-1, 0, 0) from the paper's start
    and at the optimum from the other one. The IPM must do the same, in as many iterations (where
    it converges; IPOPT's count, which takes the iterate where the restoration phase returns once)."""
    nlp, b, p, f_star = tp.wachter_biegler()
    bounds = Bounds(np.array(x0), b.xl, b.xu, b.gl, b.gu)
    r = solve_ipm(nlp, p, bounds)
    ref = solve_ipopt(nlp, p, bounds)
    assert r.status == ref.status == status, r.log
    assert ord("R") in r.history["kind"], "the filter line search alone must fail on this example"
    assert r.history["resto_iters"][-1] > 0 and r.history["mode"].sum() == r.history["resto_iters"][-1]
    # IPOPT tightens the restoration problem's tolerance once before declaring infeasibility
    assert abs(r.iterations - ref.iterations) <= (0 if status == "Solve_Succeeded" else 4), (
        r.iterations,
        ref.iterations,
    )
    np.testing.assert_allclose(r.x, ref.x, atol=1e-6)
    if status == "Solve_Succeeded":
        assert abs(r.objective - f_star) < 1e-6


def test_infeasible_problem_detected():
    nlp, bounds, p, _ = tp.infeasible_disk()
    r = solve_ipm(nlp, p, bounds)
    assert r.status == "Infeasible_Problem_Detected" and not r.success
    assert r.max_constraint_violation > 0.1


def test_staged_cartpole_block_tridiagonal_against_ipopt():
    nlp, bounds, p, _ = tp.cartpole_swingup(N=25, P=1)
    st = kkt.structure_of(nlp)
    assert st.S == 26 and st.nb == 10
    r = solve_ipm(nlp, p, bounds)
    assert r.success, r.log
    assert r.max_constraint_violation < 1e-8
    # fixed initial / terminal states stay exactly at their values
    np.testing.assert_array_equal(r.x[:4], bounds.xl[:4])
    np.testing.assert_array_equal(r.x[-4:], bounds.xl[-4:])
    pytest.importorskip("cyipopt")

    _, info, _ = solve_cyipopt_reference(nlp, p, bounds)
    assert info["status"] == 0
    assert abs(r.objective - info["obj_val"]) <= 1e-6 * abs(info["obj_val"])


def test_vmap_batch_of_perturbed_hs071():
    nlp, bounds, p, _ = tp.hs071()
    P = np.array([[25.0, 40.0], [24.0, 39.0], [26.0, 41.0], [25.5, 40.5]])
    res = batch_solve_ipm(nlp, jnp.asarray(P), bounds)
    assert len(res) == 4
    assert all(r.success for r in res), [r.status for r in res]
    assert abs(res[0].objective - 17.0140172891) < 1e-6
    for pk, rb in zip(P, res):
        rs = solve_ipm(nlp, jnp.asarray(pk), bounds)
        assert abs(rs.objective - rb.objective) < 1e-7
        np.testing.assert_allclose(rb.x, rs.x, atol=1e-6)
        assert rs.iterations == rb.iterations  # frozen members do not drift
    assert len({r.iterations for r in res}) >= 1


def test_warm_start_and_max_iter():
    nlp, bounds, p, _ = tp.hs071()
    cold = solve_ipm(nlp, p, bounds)
    warm = solve_ipm(nlp, p, bounds, x0=cold.x + 1e-3, options={"mu_init": 1e-4})
    assert warm.success and warm.iterations < cold.iterations
    short = solve_ipm(nlp, p, bounds, options=IPMOptions(max_iter=3))
    assert short.status == "Maximum_Iterations_Exceeded" and not short.success
    assert short.iterations == 3 and short.history["mu"].shape == (4,)
    assert "EXIT: Maximum_Iterations_Exceeded" in short.log


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"tol": -1.0}, "tol"),
        ({"kappa_mu": 1.5}, "kappa_mu"),
        ({"max_iter": 0}, "max_iter"),
        ({"nlp_scaling_method": "foo"}, "nlp_scaling_method.*gradient-based"),
        ({"kkt_method": "lu"}, "kkt_method.*block_ldl.*condensed"),
        ({"no_such_option": 1}, "unknown IPM option"),
    ],
)
def test_bad_options_raise(bad, match):
    with pytest.raises(ValueError, match=match):
        IPMOptions(**bad) if "no_such_option" not in bad else solve_ipm(*tp.hs071()[:1], None, None, options=bad)


def test_humanoid_pseudo_static_stage_small_n_as_ipopt():
    """Stage 1 of 2S on T3 (pseudo-static (8), relaxed contact law) at N1 = 10 with the benchmarks'
    fixed stage-1 options (``mu_init = 1e-2``). A fixed initial state makes one end pivot block
    structurally singular, which the elimination order must handle (kkt.build_structure); the
    iteration follows IPOPT's (filter, inertia correction, degeneracy test), so both reach the same
    optimum in as many iterations (78 each, with IPOPT 3.14.11 and 3.14.19). The path passes
    through a restoration phase in which mu decreases: with the proximity term of the restoration
    Hessian at the new mu instead of IPOPT's (evaluated before the update,
    ``direction.kkt_factor``) the IPM takes 90."""
    task = with_force_limit("T3", NO_FORCE_LIMIT)
    relaxed = ContactParams.relaxed()
    final = build_problem(task, "A,F+C,2S", N=20)
    q1, _ = reseat_for_contact(final.p, final.p.q_start, final.layout.active, relaxed)
    prob = build_problem(task, "A,F+C,2S", N=10, pseudo_static=True, contact=relaxed, q_start=q1)
    r = solve_ipm(prob.nlp, prob.p, prob.bounds, options=BENCH_STAGE1_OPTIONS)
    ref = solve_ipopt(prob.nlp, prob.p, prob.bounds, options=BENCH_STAGE1_OPTIONS)
    assert r.status == ref.status == "Solve_Succeeded", r.log
    assert r.max_constraint_violation <= 1e-6
    assert abs(r.iterations - ref.iterations) <= 0.1 * ref.iterations, (r.iterations, ref.iterations)
    assert abs(r.objective - ref.objective) <= 1e-8 * abs(ref.objective)
    np.testing.assert_allclose(r.x, ref.x, atol=1e-5)

    # the reported multipliers make the Lagrangian stationary (IPOPT's sign convention), as
    # closely as IPOPT's own (both stop on the scaled problem's dual infeasibility)
    def stationarity(res):
        grad = np.asarray(prob.nlp.grad(jnp.asarray(res.x), prob.p))
        jt = np.zeros(prob.nlp.n)
        np.add.at(
            jt,
            prob.nlp.jac_cols,
            np.asarray(prob.nlp.jac_values(jnp.asarray(res.x), prob.p)) * res.lam_g[prob.nlp.jac_rows],
        )
        return np.max(np.abs(grad + jt - res.z_l + res.z_u))

    assert stationarity(r) <= max(10 * stationarity(ref), 1e-6), (stationarity(r), stationarity(ref))


@pytest.mark.slow
def test_full_task_t3_two_stage_as_ipopt():
    """The paper's T3 with A,F+C,2S at N = 100: both stages succeed with the IPM and reach
    IPOPT's optimum (objective and trajectory), in no more iterations than 1.5x IPOPT's."""
    a = solve("T3", "A,F+C,2S", solver="ipm")
    b = solve("T3", "A,F+C,2S", solver="ipopt")
    assert all(s.status == "Solve_Succeeded" for s in a.stages), [s.status for s in a.stages]
    assert abs(a.objective - b.objective) <= 1e-6 * abs(b.objective)
    assert np.max(np.abs(a.q - b.q)) <= 1e-4
    assert sum(s.iterations for s in a.stages) <= 1.5 * sum(s.iterations for s in b.stages)


def test_progress_sees_every_iterate_and_keeps_the_iterates(monkeypatch):
    # with a progress callback the IPM runs its iterations in chunks (here one per call) of the
    # loop that runs them all at once without it: the same iterates, bit for bit, reported once
    # per iteration (0..k), with the history's objective and infeasibility
    from jaxhumanoid.solvers.ipm import driver

    nlp, bounds, p, _ = tp.hs071()
    plain = solve_ipm(nlp, p, bounds)
    seen = []
    monkeypatch.setattr(driver, "MAX_CHUNK", 1)
    stepped = solve_ipm(nlp, p, bounds, progress=lambda k, f, inf: seen.append((k, f, inf)))
    np.testing.assert_array_equal(stepped.history["obj"], plain.history["obj"])
    assert stepped.iterations == plain.iterations and np.array_equal(stepped.x, plain.x)
    assert [k for k, _, _ in seen] == list(range(plain.iterations + 1))
    np.testing.assert_array_equal([f for _, f, _ in seen], plain.history["obj"])
    np.testing.assert_array_equal([i for _, _, i in seen], plain.history["inf_pr"])
    ipopt_seen = []
    ref = solve_ipopt(nlp, p, bounds, progress=lambda k, f, inf: ipopt_seen.append((k, f, inf)))
    assert [k for k, _, _ in ipopt_seen] == list(range(ref.iterations + 1))
    assert abs(ipopt_seen[-1][1] - ref.objective) <= 1e-9 * abs(ref.objective)
    with pytest.raises(ValueError, match="keep_history"):
        solve_ipm(nlp, p, bounds, options={"keep_history": False}, progress=lambda *a: None)


@pytest.mark.parametrize("with_progress", [False, True])
def test_precompile_compiles_what_the_solve_runs(with_progress):
    """``precompile_ipm`` compiles, in the background, the programs a later solve runs, with or
    without a progress callback: the solve compiles nothing more and its iterates are those of a
    solve that compiled by itself."""
    from jaxhumanoid.solvers.ipm import precompile_ipm

    progress = (lambda *a: None) if with_progress else None
    cached, bounds, p, _ = tp.hs071()
    alone = solve_ipm(dataclasses.replace(cached), p, bounds)
    nlp = dataclasses.replace(cached)  # the same NLP with an empty cache: nothing compiled
    future = precompile_ipm(nlp, p, bounds)
    assert precompile_ipm(nlp, p, bounds) is future
    future.result()
    compiled = nlp.cache[("ipm", "stepped")]["compiled"]
    before = set(compiled)
    assert {key[0] for key in before} == {"prepare", "grad_jac", "fg", "start", "advance", "finish"}
    res = solve_ipm(nlp, p, bounds, progress=progress)
    assert set(compiled) == before and res.compile_time_s == 0.0
    assert res.iterations == alone.iterations and np.array_equal(res.x, alone.x)
