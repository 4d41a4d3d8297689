"""Transcription, schemes, sparse derivatives and the end-to-end solve."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401
from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.scheme import Scheme, parse_scheme
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.solve import reseat_for_contact


@pytest.mark.parametrize(
    "task,scheme,expected",
    [("T1", "E,F,1S", 1485), ("T1", "A,F,1S", 2485), ("T1", "A,F+C,1S", 2085), ("T3", "A,F+C,1S", 1885), ("T4", "E,F+C,1S", 1485)],
)
def test_variable_count_matches_paper_formula(task, scheme, expected):
    pr = build_problem(task, scheme, N=100)
    n, N, nF = 5, 100, len(pr.layout.active) if pr.layout.augmented else 0
    assert pr.nlp.n == 2 * n * (N + 1) + n * N + 2 * nF * N - 3 * n - 2 * n == expected


def test_scheme_parsing_and_errors():
    assert parse_scheme("A,F+C,2S") == Scheme("A", "F+C", 2)
    assert parse_scheme("e-f-1s") == Scheme("E", "F", 1)
    with pytest.raises(ValueError, match="scheme"):
        parse_scheme("B,F,1S")
    with pytest.raises(ValueError, match="task"):
        tasks.get_task("T9")
    assert tasks.get_task("supine-to-stand").key == "T3"
    with pytest.raises(ValueError, match="N"):
        build_problem("T1", "A,F,1S", N=2)


CASES = [("T1", "E,F,1S", False), ("T1", "A,F,1S", False), ("T3", "A,F+C,1S", False), ("T2", "A,F+C,2S", True)]


@pytest.mark.parametrize("task,scheme,pseudo", CASES)
def test_sparse_derivatives_equal_dense_and_patterns_complete(task, scheme, pseudo):
    pr = build_problem(task, scheme, N=6, pseudo_static=pseudo, contact=ContactParams.relaxed() if pseudo else None)
    nlp, p = pr.nlp, pr.p
    rng = np.random.default_rng(1)
    x = pr.bounds.x0 + 0.05 * rng.normal(size=nlp.n)
    lam = rng.normal(size=nlp.m)
    J = np.zeros((nlp.m, nlp.n))
    J[nlp.jac_rows, nlp.jac_cols] = np.asarray(jax.jit(nlp.jac_values)(x, p))
    J_dense = np.asarray(jax.jit(jax.jacfwd(nlp.g))(x, p))
    assert np.max(np.abs(J - J_dense)) <= 1e-12 * max(1.0, np.max(np.abs(J_dense)))
    assert not np.any((J_dense != 0) & ~np.isin(np.arange(J.size), nlp.jac_rows * nlp.n + nlp.jac_cols).reshape(J.shape))
    H = np.zeros((nlp.n, nlp.n))
    H[nlp.hess_rows, nlp.hess_cols] = np.asarray(jax.jit(nlp.hess_values)(x, lam, 0.7, p))
    H_dense = np.tril(np.asarray(jax.jit(jax.hessian(lambda z, lam, p: 0.7 * nlp.f(z, p) + jnp.dot(lam, nlp.g(z, p))))(x, lam, p)))
    assert np.max(np.abs(H - H_dense)) <= 1e-11 * max(1.0, np.max(np.abs(H_dense)))
    assert np.all(nlp.hess_rows >= nlp.hess_cols)
    # gradient against central differences
    i = rng.choice(nlp.n, 8, replace=False)
    eps = 1e-6
    f = jax.jit(nlp.f)
    fd = [(f(x + eps * np.eye(nlp.n)[k], p) - f(x - eps * np.eye(nlp.n)[k], p)) / (2 * eps) for k in i]
    assert np.allclose(np.asarray(jax.jit(nlp.grad)(x, p))[i], fd, rtol=1e-6, atol=1e-6)


def test_stage_structure_is_block_tridiagonal():
    pr = build_problem("T1", "A,F,1S", N=8)
    nlp = pr.nlp
    d = nlp.var_stage[nlp.jac_cols] - nlp.con_stage[nlp.jac_rows]
    assert set(np.unique(d)) <= {0, 1}
    assert np.max(np.abs(nlp.var_stage[nlp.hess_rows] - nlp.var_stage[nlp.hess_cols])) <= 1


def test_initial_guess_respects_frozen_first_interval_and_bounds():
    pr = build_problem("T1", "A,F+C,1S", N=20)
    Z = pr.full(pr.bounds.x0)
    assert np.allclose(Z[1, 0:5], Z[0, 0:5])
    assert np.all(pr.bounds.x0 >= pr.bounds.xl) and np.all(pr.bounds.x0 <= pr.bounds.xu)
    g0 = np.asarray(jax.jit(pr.nlp.g)(pr.bounds.x0, pr.p)).reshape(20, -1)
    assert np.max(np.abs(g0[0, :5])) < 1e-12  # (6a) holds on the frozen interval


@pytest.mark.parametrize("key", ["T1", "T2", "T3", "T4"])
def test_start_postures_are_equilibria_with_foot_margin(key):
    task = tasks.get_task(key)
    p = tr.default_params(task)
    for contact in ("nominal", "relaxed"):
        q = np.asarray(task.start)
        if contact == "relaxed":
            q, shift = reseat_for_contact(p, q, task.active, ContactParams.relaxed())
            assert shift < 0.02  # millimetres, not a new posture
        pc = tr.default_params(task, contact=getattr(ContactParams, contact)())
        u = tr.equilibrium_torques(pc, jnp.asarray(q), task.active)
        f = ct.contact_forces(pc.model, pc.foot, pc.contact, jnp.asarray(q), jnp.zeros(5), task.active)
        f0 = ft.foot_reaction(pc.model, jnp.asarray(q), jnp.zeros(5), jnp.zeros(5), f)
        margins = np.asarray(ft.foot_constraints(pc.foot, pc.contact.mu, f0, u[0]))
        assert np.all(margins > 0.04 * 100.0), (key, contact, margins)
        gaps = np.asarray(kin.contact_gaps(pc.model, pc.foot, jnp.asarray(q)))
        others = [i - 1 for i in range(1, 6) if i not in task.active]
        assert np.all(gaps[others] > 0.01)  # clearance joints are off the ground
        assert np.all((tasks.Q_MIN < q) & (q < tasks.Q_MAX))


def test_cli_solve_two_stage_t1(tmp_path):
    """The README's main job: T1 with A,F+C,2S converges, report.json and figures are written."""
    from jaxhumanoid.outputs.cli import main
    from jaxhumanoid.outputs.solution import Solution

    out = tmp_path / "T1"
    assert main(["--no-cache", "solve", "--task", "T1", "--out", str(out), "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    for key in ("task", "scheme", "solver", "success", "status", "iterations", "solve_time_s", "compile_time_s", "objective", "n_variables", "n_constraints", "max_constraint_violation"):
        assert key in report
    assert report["success"] and report["status"] == "Solve_Succeeded"
    assert len(report["iterations"]) == 2 and report["n_variables"] == 2085
    assert report["max_constraint_violation"] < 1e-6
    sol = Solution.load(out)
    goal = tasks.get_task("T1").goal
    assert np.all(np.abs(sol.q[-1] - goal) <= tasks.GOAL_TOLERANCE + 1e-7)
    assert np.all(sol.foot_margins > -1e-6)
    assert np.allclose(sol.qd[-1], 0) and np.allclose(sol.qd[-2], 0)
    for name in ("solution.png", "contacts.png"):
        assert (out / name).stat().st_size > 10_000


def test_cli_reports_bad_input_clearly(capsys):
    from jaxhumanoid.outputs.cli import main

    assert main(["--no-cache", "solve", "--task", "T7", "--out", "/tmp/never"]) == 2
    assert "task" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("key", ["T2", "T3", "T4"])
def test_two_stage_converges_on_every_task(key):
    from jaxhumanoid.strategy.solve import solve

    sol = solve(key, "A,F+C,2S")
    assert sol.success, [s.status for s in sol.stages]


def test_failed_stage_one_retries_with_the_fallback_and_counts_every_run(monkeypatch):
    from jaxhumanoid.solvers.result import NLPResult
    from jaxhumanoid.strategy import solve as strat

    calls = []

    def fake_run(solver, problem, x0, options, verbose):
        calls.append((problem.layout.N, dict(options)))
        fail = problem.layout.pseudo_static and len(calls) == 1
        n, m = problem.nlp.n, problem.nlp.m
        return NLPResult(x=np.asarray(x0, float), lam_g=np.zeros(m), z_l=np.zeros(n), z_u=np.zeros(n),
                         status="Infeasible_Problem_Detected" if fail else "Solve_Succeeded", success=not fail,
                         iterations=100 + len(calls), solve_time_s=1.0, compile_time_s=0.5, objective=1.0,
                         max_constraint_violation=0.0)

    monkeypatch.setattr(strat, "_run_solver", fake_run)
    sol = strat.solve("T1", "A,F+C,2S", N=10, N1=5)
    assert [c[0] for c in calls] == [5, 5, 10]
    assert calls[0][1]["mu_init"] == strat.STAGE1_DEFAULTS["mu_init"] and "mu_strategy" not in calls[0][1]
    assert calls[1][1]["mu_strategy"] == "adaptive"
    first, second = sol.stages
    assert first.attempts == 2 and first.success and first.status == "Solve_Succeeded"
    assert first.iterations == 101 + 102 and first.solve_time_s == 2.0
    assert second.attempts == 1 and second.iterations == 103
    # the own IPM takes no IPOPT options: no fallback, the failure is reported as it is
    calls.clear()
    sol = strat.solve("T1", "A,F+C,2S", solver="ipm", N=10, N1=5)
    assert len(calls) == 2 and sol.stages[0].status == "Infeasible_Problem_Detected" and sol.stages[0].attempts == 1
