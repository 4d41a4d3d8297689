"""The 1S/2S strategies: stage hand-over, the stage-1 fallbacks, convergence on every task (slow)."""

import dataclasses

import numpy as np
import pytest

from jaxhumanoid.solvers.result import NLPResult
from jaxhumanoid.strategy import solve as strat


@pytest.mark.slow
@pytest.mark.parametrize("key", ["T2", "T3", "T4"])
def test_two_stage_converges_on_every_task(key):
    sol = strat.solve(key, "A,F+C,2S")
    assert sol.success, [s.status for s in sol.stages]


@pytest.mark.parametrize("solver", ["ipopt", "ipm"])
def test_failed_stage_one_retries_with_the_fallback_and_counts_every_run(monkeypatch, solver):
    calls = []

    def fake_run(solver, problem, x0, options, verbose, progress=None):
        calls.append((problem.layout.N, dict(options), np.array(x0)))
        fail = problem.layout.pseudo_static and len(calls) == 1
        n, m = problem.nlp.n, problem.nlp.m
        return NLPResult(
            x=np.asarray(x0, float),
            lam_g=np.zeros(m),
            z_l=np.zeros(n),
            z_u=np.zeros(n),
            status="Infeasible_Problem_Detected" if fail else "Solve_Succeeded",
            success=not fail,
            iterations=100 + len(calls),
            solve_time_s=1.0,
            compile_time_s=0.5,
            objective=1.0,
            max_constraint_violation=0.0,
        )

    monkeypatch.setattr(strat, "_run_solver", fake_run)
    sol = strat.solve("T1", "A,F+C,2S", solver=solver, N=10, N1=5)
    assert [c[0] for c in calls] == [5, 5, 10]
    assert calls[0][1]["mu_init"] == strat.STAGE1_DEFAULTS["mu_init"] and "mu_strategy" not in calls[0][1]
    assert calls[1][1]["mu_strategy"] == "adaptive"
    first, second = sol.stages
    assert first.attempts == 2 and first.success and first.status == "Solve_Succeeded"
    assert first.iterations == 101 + 102 and first.solve_time_s == 2.0
    assert second.attempts == 1 and second.iterations == 103
    # a stage 1 that fails in every run is reported as failed, and stage 2 still runs from it
    calls.clear()
    failing = lambda *a: dataclasses.replace(fake_run(*a), status="Error", success=False)  # noqa: E731
    monkeypatch.setattr(strat, "_run_solver", failing)
    sol = strat.solve("T1", "A,F+C,2S", solver=solver, N=10, N1=5)
    runs = 1 + len(strat.STAGE1_FALLBACKS)
    assert len(calls) == runs + 1 and sol.stages[0].status == "Error" and sol.stages[0].attempts == runs
    assert not sol.success
    # the restarts move the linear guess by about STAGE1_RESTART_SIGMA, the same way for one seed
    x = [c[2] for c in calls[:runs]]
    np.testing.assert_array_equal(x[0], x[1])
    assert 0 < np.max(np.abs(x[2] - x[0])) < 10 * strat.STAGE1_RESTART_SIGMA
    np.testing.assert_array_equal(x[2], x[3])
    assert np.max(np.abs(x[4] - x[2])) > 0
