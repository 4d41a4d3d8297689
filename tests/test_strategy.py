"""The 1S/2S strategies: stage hand-over, the stage-1 fallbacks, convergence on every task (slow)."""

import dataclasses
import time

import numpy as np
import pytest

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.tasks import CONTACT_FORCE_LIMIT, get_task
from jaxhumanoid.solvers.result import NLPResult
from jaxhumanoid.strategy import handover, stage_one
from jaxhumanoid.strategy import solve as solve_module
from jaxhumanoid.strategy.posture import rest_foot_rows
from jaxhumanoid.strategy.problem import build_problem, with_guess
from jaxhumanoid.strategy.runner import Runner
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solve import solve

DIRECT = SolveSettings(N1=5, guess="linear", handover="direct")


def _fake_result(problem, x0, status="Solve_Succeeded", iterations=10) -> NLPResult:
    n, m = problem.nlp.n, problem.nlp.m
    return NLPResult(
        x=np.asarray(x0, float),
        lam_g=np.zeros(m),
        z_l=np.zeros(n),
        z_u=np.zeros(n),
        status=status,
        success=status == "Solve_Succeeded",
        iterations=iterations,
        solve_time_s=1.0,
        compile_time_s=0.0,
        objective=1.0,
        max_constraint_violation=0.0,
    )


@pytest.mark.slow
@pytest.mark.parametrize("key", ["T2", "T3", "T4"])
def test_two_stage_converges_on_every_task(key):
    sol = solve(key, "A,F+C,2S")
    assert sol.success, [s.status for s in sol.stages]


@pytest.mark.parametrize("solver", ["ipopt", "ipm"])
def test_failed_stage_one_retries_with_the_fallback_and_counts_every_run(monkeypatch, solver):
    calls = []

    def fake_run(runner, problem, x0, options, stage):
        calls.append((problem.layout.N, dict(options), np.array(x0), problem))
        fail = problem.layout.pseudo_static and len(calls) == 1
        return _fake_result(problem, x0, "Infeasible_Problem_Detected" if fail else "Solve_Succeeded", 100 + len(calls))

    monkeypatch.setattr(Runner, "run", fake_run)
    paper = SolveSettings(N1=5, guess="linear", handover="direct", stage1_solver="same")
    sol = solve("T1", "A,F+C,2S", solver=solver, N=10, settings=paper)
    assert [c[0] for c in calls] == [5, 5, 10]
    assert calls[0][1]["mu_init"] == stage_one.STAGE1_DEFAULTS["mu_init"] and "mu_strategy" not in calls[0][1]
    assert "mu_strategy" not in calls[1][1]  # the first fallback: the same options from the other guess
    first, second = sol.stages
    assert first.attempts == 2 and first.success and first.status == "Solve_Succeeded"
    assert first.iterations == 101 + 102 and first.solve_time_s == 2.0
    assert second.attempts == 1 and second.iterations == 103
    # a stage 1 that fails in every run is reported as failed, and stage 2 still runs from it
    calls.clear()
    failing = lambda *a: dataclasses.replace(fake_run(*a), status="Error", success=False)  # noqa: E731
    monkeypatch.setattr(Runner, "run", failing)
    sol = solve("T1", "A,F+C,2S", solver=solver, N=10, settings=paper)
    # T1 has no force limit: the runs that only lift it are skipped, those with twice the torque box run
    kept = [fb for fb in stage_one.STAGE1_FALLBACKS if not fb.lift_force_limit or fb.strength != 1.0]
    runs = 1 + len(kept)
    assert len(calls) == runs + 1 and sol.stages[0].status == "Error" and sol.stages[0].attempts == runs
    assert not sol.success and not sol.stages[0].force_limit_lifted and sol.stages[0].strength_factor == 1.0
    u_max = [np.max(c[3].full(c[3].bounds.xu)[:-1, c[3].layout.stage_slices()["u"]]) for c in calls]
    assert u_max[:-3] == [u_max[0]] * (runs - 2) and u_max[-3:-1] == [2 * u_max[0]] * 2
    assert u_max[-1] * stage_one.STAGE1_STRENGTH == u_max[0]  # stage 2 keeps the body's box
    x = [c[2] for c in calls[:runs]]
    adaptive = ["mu_strategy" in c[1] for c in calls[:runs]]
    assert adaptive == [False] + [fb.options.get("mu_strategy") == "adaptive" for fb in kept]
    # the other guess is the inverse-dynamics one of the same stage-1 problem
    np.testing.assert_array_equal(x[1], with_guess(calls[0][3], "inverse_dynamics").bounds.x0)
    assert np.max(np.abs(x[1] - x[0])) > 1.0  # torques and forces of the inverse dynamics
    np.testing.assert_array_equal(x[2], x[0])
    np.testing.assert_array_equal(x[3], x[1])
    # the restarts move a guess by about STAGE1_RESTART_SIGMA, the same way for one seed
    assert 0 < np.max(np.abs(x[4] - x[0])) < 10 * stage_one.STAGE1_RESTART_SIGMA
    assert 0 < np.max(np.abs(x[5] - x[1])) < 10 * stage_one.STAGE1_RESTART_SIGMA
    np.testing.assert_array_equal(x[6], x[4])


def test_compile_time_counts_every_set_up_step_of_its_stage(monkeypatch):
    """The start's seating and the relaxed-law start's re-seating are set-up a cold solve waits
    for: they count as compile time, the first with the dynamic stage's, the second with stage 1's."""
    monkeypatch.setattr(Runner, "run", lambda runner, problem, x0, options, stage: _fake_result(problem, x0))
    monkeypatch.setattr(Runner, "precompile", lambda *a: None)

    def slowed(fn, seconds):
        def wrapper(*args, **kwargs):
            time.sleep(seconds)
            return fn(*args, **kwargs)

        return wrapper

    solve("T1", "A,F+C,2S", N=10, settings=DIRECT)  # compiled and cached: the set-up left is quick
    monkeypatch.setattr(solve_module, "_seated_task", slowed(solve_module._seated_task, 1.0))
    monkeypatch.setattr(solve_module, "relaxed_stage_problem", slowed(solve_module.relaxed_stage_problem, 2.0))
    t0 = time.perf_counter()
    first, second = solve("T1", "A,F+C,2S", N=10, settings=DIRECT).stages
    wall = time.perf_counter() - t0
    assert 2.0 <= first.compile_time_s < 3.0 and 1.0 <= second.compile_time_s < 2.0
    assert first.compile_time_s + second.compile_time_s <= wall  # nothing counted twice


def test_stage_one_of_a_task_with_a_force_limit_falls_back_to_none_and_stage_two_keeps_it(monkeypatch):
    calls = []

    def fake_run(runner, problem, x0, options, stage):
        calls.append((problem, np.array(x0)))
        limited = problem.task.contact_force_limit is not None
        fail = problem.layout.pseudo_static and limited
        return _fake_result(problem, x0, "Infeasible_Problem_Detected" if fail else "Solve_Succeeded", 7)

    monkeypatch.setattr(Runner, "run", fake_run)
    with pytest.warns(UserWarning, match="stage 1 failed .* solved with no contact-force limit; "):
        sol = solve("T3", "A,F+C,2S", N=10, settings=DIRECT)
    runs = 2 + sum(not fb.lift_force_limit for fb in stage_one.STAGE1_FALLBACKS)
    first, second = sol.stages
    assert first.success and first.force_limit_lifted and first.attempts == runs and first.iterations == 7 * runs
    assert [c[0].task.contact_force_limit for c in calls] == [2.0] * (runs - 1) + [None, 2.0]
    lifted, final = calls[runs - 1][0], calls[runs][0]
    assert lifted.layout.N == 5 and not lifted.layout.force_rows
    f1 = lifted.layout.stage_slices()["f"]
    assert np.max(lifted.full(lifted.bounds.xu)[:-1, f1]) == CONTACT_FORCE_LIMIT
    # stage 2 is posed with the limit, from stage 1's solution clipped into its bounds
    weight = float(np.sum(final.p.model.m)) * float(final.p.model.g)
    f2 = final.layout.stage_slices()["f"]
    assert np.max(final.full(final.bounds.xu)[:-1, f2]) == pytest.approx(2.0 * weight)
    x2 = calls[runs][1]
    assert np.all(x2 >= final.bounds.xl) and np.all(x2 <= final.bounds.xu)
    assert not second.force_limit_lifted and first.strength_factor == 1.0
    # the same task in which stage 1 succeeds under its limit never lifts it
    calls.clear()
    monkeypatch.setattr(Runner, "run", lambda *a, **k: _fake_result(a[1], a[2]))
    sol = solve("T3", "A,F+C,2S", N=10, settings=DIRECT)
    assert sol.stages[0].attempts == 1 and not sol.stages[0].force_limit_lifted


def test_stage_one_that_fails_within_the_strengths_falls_back_to_twice_the_torque_box(monkeypatch):
    def fake_run(runner, problem, x0, options, stage):
        u_max = np.max(problem.full(problem.bounds.xu)[:-1, problem.layout.stage_slices()["u"]])
        strong = u_max > 2 * stage_one.STAGE1_STRENGTH * 300.0
        fail = problem.layout.pseudo_static and not strong  # the strongest joint holds 500 N m
        return _fake_result(problem, x0, "Infeasible_Problem_Detected" if fail else "Solve_Succeeded", 3)

    monkeypatch.setattr(Runner, "run", fake_run)
    with pytest.warns(
        UserWarning, match=r"solved with stage 1's torque box x2; the dynamic stages keep the task's bounds"
    ):
        sol = solve("T1", "A,F+C,2S", N=10, settings=DIRECT)
    first = sol.stages[0]
    assert sol.success and first.strength_factor == 2.0 and not first.force_limit_lifted
    assert first.attempts == 2 + sum(not fb.lift_force_limit for fb in stage_one.STAGE1_FALLBACKS)
    final = build_problem("T1", "A,F+C,2S", N=10)
    u_max = np.asarray(build_problem("T1", "A,F+C,1S", N=5).model.u_max)
    body = stage_one.stage_one_problem("T1", "A,F+C,2S", final, 5, strength=2.0)
    np.testing.assert_array_equal(body.model.u_max, 2.0 * u_max)
    # stage 1 poses the body with STAGE1_STRENGTH times its torque box; the final problem keeps it
    default = stage_one.stage_one_problem("T1", "A,F+C,2S", final, 5)
    np.testing.assert_array_equal(default.model.u_max, stage_one.STAGE1_STRENGTH * u_max)
    np.testing.assert_array_equal(final.model.u_max, u_max)


def test_law_path_runs_geometrically_from_the_relaxed_to_the_nominal_law():
    first, last = ContactParams.relaxed(), ContactParams.nominal()
    laws = handover.law_path(first, last, 4)
    assert len(laws) == 5 and laws[-1] is last
    for k in ("kappa", "f0", "xhat"):
        values = np.array([float(getattr(law, k)) for law in laws])
        assert values[0] == pytest.approx(float(getattr(first, k)), rel=1e-15)
        np.testing.assert_allclose(np.diff(np.log(values)), np.log(values[-1] / values[0]) / 4, rtol=1e-12)


def test_with_law_reseats_the_start_so_that_it_stays_the_same_equilibrium():
    final = build_problem("T1", "A,F+C,2S", N=10)
    relaxed = handover.with_law(final, ContactParams.relaxed())
    assert relaxed.nlp is final.nlp and handover.with_law(final, final.p.contact) is final
    moved = np.abs(np.asarray(relaxed.p.q_start) - np.asarray(final.p.q_start)).max()
    assert 1e-6 < moved < 0.05  # the relaxed law (f0 = 300 N) needs another gap for the same load
    active = final.layout.active

    def normal_forces(p, q):
        return np.asarray(ct.contact_forces(p.model, p.foot, p.contact, q, np.zeros(q.shape), active))[:, 1]

    f_nominal = normal_forces(final.p, final.p.q_start)
    assert f_nominal.max() > 100.0
    np.testing.assert_allclose(normal_forces(relaxed.p, relaxed.p.q_start), f_nominal, atol=1e-6 * f_nominal.max())
    # mutation: the relaxed law at the nominal start carries other forces
    assert np.abs(normal_forces(relaxed.p, final.p.q_start) - f_nominal).max() > 10.0
    u_nominal = tr.equilibrium_torques(final.p, final.p.q_start, active)
    u_relaxed = tr.equilibrium_torques(relaxed.p, relaxed.p.q_start, active)
    np.testing.assert_allclose(u_relaxed, u_nominal, atol=0.02 * np.abs(u_nominal).max())  # the posture moved


@pytest.mark.parametrize("solver", ["ipopt", "ipm"])
def test_continuation_hands_over_along_the_law_path_and_stops_at_a_failure(monkeypatch, solver):
    calls = []

    def fake_run(runner, problem, x0, options, stage):
        calls.append((runner.solver, problem.layout.pseudo_static, float(problem.p.contact.kappa), dict(options)))
        fail = len(calls) == fail_at
        return _fake_result(problem, x0, "Restoration_Failed" if fail else "Solve_Succeeded", 10 + len(calls))

    monkeypatch.setattr(Runner, "run", fake_run)
    fail_at = 0
    kw = dict(N=10, settings=SolveSettings(N1=5, handover="continuation", continuation_steps=3, stage1_solver="casadi"))
    sol = solve("T1", "A,F+C,2S", solver=solver, **kw)
    laws = handover.law_path(ContactParams.relaxed(), ContactParams.nominal(), 3)
    assert [c[0] for c in calls] == ["casadi", "casadi"] + [solver] * 3
    assert [c[1] for c in calls] == [True] + [False] * 4
    np.testing.assert_allclose([c[2] for c in calls[1:]], [float(law.kappa) for law in laws])
    assert calls[1][3]["mu_init"] == handover.STAGE2_DEFAULTS["mu_init"]
    assert all(c[3]["mu_init"] == handover.CONTINUATION_OPTIONS["mu_init"] for c in calls[2:])
    # the relaxed-law solve and the laws before the nominal one are starts: the looser tolerance
    assert [c[3].get("tol") for c in calls] == [None] + [handover.INTERMEDIATE_OPTIONS["tol"]] * 3 + [None]
    assert [s.runs for s in sol.stages] == [(11,), (12,), (13, 14, 15)] and sol.success
    assert sol.stages[2].iterations == 13 + 14 + 15 and sol.stages[2].attempts == 3
    calls.clear()
    fail_at = 4  # the second law of stage 2, once: rerun from the same start with the cold barrier
    sol = solve("T1", "A,F+C,2S", solver=solver, **kw)
    assert len(calls) == 6 and sol.success and sol.stages[2].runs == (13, 14, 15, 16)
    assert calls[4][2] == calls[3][2] and calls[4][3]["mu_init"] == handover.DYNAMIC_FALLBACKS[0]["mu_init"]
    assert calls[5][3]["mu_init"] == handover.CONTINUATION_OPTIONS["mu_init"]  # the next law: the small barrier again
    calls.clear()
    fail_at = 0
    solve("T1", "A,F+C,2S", solver=solver, options={"tol": 1e-6}, **kw)  # a tol of the solve holds for every stage
    assert [c[3]["tol"] for c in calls] == [1e-6] * 5


@pytest.mark.parametrize("solver", ["ipopt", "ipm"])
def test_a_law_of_the_continuation_that_no_rerun_solves_ends_the_path_with_its_law(monkeypatch, solver):
    calls = []
    laws = handover.law_path(ContactParams.relaxed(), ContactParams.nominal(), 3)

    def fake_run(runner, problem, x0, options, stage):
        calls.append((np.asarray(x0).copy(), dict(options)))
        fail = float(problem.p.contact.kappa) == float(laws[2].kappa)  # the second law of stage 2
        return _fake_result(problem, x0 + 1.0, "Restoration_Failed" if fail else "Solve_Succeeded", 10 + len(calls))

    monkeypatch.setattr(Runner, "run", fake_run)
    kw = dict(N=10, settings=SolveSettings(N1=5, handover="continuation", continuation_steps=3))
    sol = solve("T1", "A,F+C,2S", solver=solver, **kw)
    reruns = len(handover.DYNAMIC_FALLBACKS)
    assert len(calls) == 4 + reruns and not sol.success
    assert sol.stages[2].status == "Restoration_Failed (law 2/3)" and sol.stages[2].runs == (13, 14, 15, 16)
    for k, rerun in enumerate(handover.DYNAMIC_FALLBACKS, start=4):
        np.testing.assert_array_equal(calls[k][0], calls[3][0])  # every rerun starts where the law's first run did
        assert {key: calls[k][1].get(key) for key in rerun} == rerun


@pytest.mark.parametrize("fails", [1, 2, 3])
def test_failed_relaxed_law_dynamic_solve_reruns_from_the_same_start_with_a_cold_barrier(monkeypatch, fails):
    """The relaxed-law dynamic solve that fails is rerun from stage 1's solution with each of
    ``DYNAMIC_FALLBACKS`` in turn (IPOPT's cold barrier, then with the adaptive update)
    until one succeeds; the continuation goes on after a success, and the stage fails with the last
    rerun's status when none does."""
    calls = []

    def fake_run(runner, problem, x0, options, stage):
        calls.append((problem.layout.pseudo_static, np.asarray(x0).copy(), dict(options)))
        fail = not problem.layout.pseudo_static and 2 <= len(calls) <= 1 + fails
        return _fake_result(
            problem, x0 if not fail else x0 + 1.0, "Infeasible_Problem_Detected" if fail else "Solve_Succeeded"
        )

    monkeypatch.setattr(Runner, "run", fake_run)
    sol = solve("T1", "A,F+C,2S", N=10, settings=SolveSettings(N1=5, continuation_steps=2))
    relaxed, runs = sol.stages[1], min(fails + 1, 3)
    assert relaxed.runs == (10,) * runs and relaxed.attempts == runs
    assert calls[1][2]["mu_init"] == handover.STAGE2_DEFAULTS["mu_init"]
    for k, rerun in enumerate(handover.DYNAMIC_FALLBACKS[: runs - 1], start=2):
        np.testing.assert_array_equal(calls[k][1], calls[1][1])  # every rerun starts where the first run did
        assert {key: calls[k][2].get(key) for key in rerun} == rerun
    assert calls[2][2].get("mu_strategy") != "adaptive"  # the cold monotone rerun comes first
    assert (calls[3][2].get("mu_strategy") == "adaptive") == (fails >= 2)
    if fails < 3:
        assert relaxed.success and sol.success and len(calls) == runs + 3  # + the two laws of stage 2
    else:
        assert not relaxed.success and relaxed.status == "Infeasible_Problem_Detected" and len(calls) == 4
        assert not sol.success and len(sol.stages) == 2


def test_bad_handover_settings_are_rejected_before_any_work():
    with pytest.raises(ValueError, match="handover"):
        SolveSettings(handover="homotopy")
    with pytest.raises(ValueError, match="continuation_steps"):
        SolveSettings(handover="continuation", continuation_steps=0)
    with pytest.raises(ValueError, match="stage1_solver"):
        SolveSettings(stage1_solver="snopt")


def test_relaxed_stage_problem_steps_towards_the_nominal_law_where_the_relaxed_law_unseats_the_start(monkeypatch):
    """A perturbed T1 problem (the robustness study's draw 23): its foot carries little load, and
    the start re-seated for the relaxed law puts the centre of pressure off the sole, so the
    relaxed-law stages could not satisfy (5) on their frozen first interval. The first law of the
    path that keeps (5) at rest is step 1; the nominal T1 keeps the relaxed law itself."""
    law = ContactParams(kappa=88060.02386350394, f0=205.1929554480116, xhat=0.02860028135564743, mu=1.467176751666706)
    start = np.array([3.282345, -0.248731, -0.324172, -4.519695, -1.372923])
    final = build_problem(dataclasses.replace(get_task("T1"), start=start), "A,F+C,2S", N=10, T=5.0, contact=law)
    relaxed = ContactParams.relaxed()

    def rows(law_j):
        q = handover.with_law(final, law_j).p.q_start
        return rest_foot_rows(final.model, final.p.foot, law_j, q, final.layout.active)[0]

    got, step = handover.relaxed_stage_problem(final, relaxed, 4)
    path = handover.law_path(relaxed, law, 4)
    assert step == 1 and got.p.contact == path[1] and got.nlp is final.nlp
    np.testing.assert_array_equal(got.p.q_start, handover.with_law(final, path[1]).p.q_start)
    assert rows(relaxed).min() < -10.0 and rows(path[1]).min() >= 0.0  # the check can fail: the relaxed law breaks (5)
    nominal = build_problem(get_task("T1"), "A,F+C,2S", N=10, T=5.0)
    seated, step = handover.relaxed_stage_problem(nominal, relaxed, 4)
    assert step == 0 and seated.p.contact == relaxed
    kappas, starts = [], []

    def fake_run(runner, problem, x0, options, stage):
        kappas.append(float(problem.p.contact.kappa))
        starts.append(np.asarray(problem.p.q_start))
        return _fake_result(problem, x0)

    monkeypatch.setattr(Runner, "run", fake_run)
    task = dataclasses.replace(get_task("T1"), start=start)
    with pytest.warns(UserWarning, match="relaxed-law stages use law 1/4"):
        sol = solve(task, "A,F+C,2S", N=10, contact=law, settings=SolveSettings(N1=5, continuation_steps=4))
    assert sol.stages[0].law_step == 1 and [s.law_step for s in sol.stages[1:]] == [0, 0]
    np.testing.assert_allclose(kappas, [path[1].kappa] + [float(g.kappa) for g in handover.law_path(path[1], law, 4)])
    # stage 1 and the relaxed-law dynamic solve start from the one posture seated for law 1
    np.testing.assert_array_equal(starts[0], starts[1])
    np.testing.assert_allclose(starts[0], got.p.q_start, atol=1e-5)  # solve seats the start first (5e-7 rad)


def test_stage_two_start_takes_velocities_from_the_interpolated_positions():
    final = build_problem("T1", "A,F+C,2S", N=20)
    first = stage_one.stage_one_problem("T1", "A,F+C,2S", final, 8)
    sl = final.layout.stage_slices()
    # a stage-1 point whose node velocities alternate about the motion's, as (6a) allows in (8)
    Z1 = np.array(first.full(first.bounds.x0))
    t1 = np.linspace(0.0, float(final.p.T), 9)
    Z1[:, sl["q"]] = np.sin(t1)[:, None] * np.arange(1.0, 6.0)
    Z1[1:, sl["qd"]] = np.cos(t1[1:])[:, None] * np.arange(1.0, 6.0) + 3.0 * (-1.0) ** np.arange(8)[:, None]
    x0, Zf = handover.stage_two_start(Z1, final)
    plain = handover.interpolate_full(Z1, float(final.p.T), final.layout)
    h = float(final.p.T) / 20
    q = Zf[:, sl["q"]]
    assert np.array_equal(q, plain[:, sl["q"]]) and np.array_equal(Zf[:, sl["u"]], plain[:, sl["u"]])
    np.testing.assert_allclose(Zf[1:-1, sl["qd"]], (q[2:] - q[:-2]) / (2 * h), atol=1e-12)
    # the alternation is gone: the start's velocities stay within the motion's range
    assert np.max(np.abs(Zf[:, sl["qd"]])) < np.max(np.abs(plain[:, sl["qd"]])) - 2.0
    assert np.all(x0 >= final.bounds.xl) and np.all(x0 <= final.bounds.xu)
    assert np.array_equal(x0, np.clip(tr.free_from_full(final.layout, Zf), final.bounds.xl, final.bounds.xu))


def test_precompile_compiles_the_nlp_the_run_solves():
    """``Runner.precompile`` starts compiling the NLP that ``Runner.run`` will solve: the problem's
    own under ``scaling="none"``, its scaled twin under ``"physical"``; CasADi compiles nothing."""
    from jaxhumanoid.ocp.scaling import scaled_nlp

    problem = build_problem(get_task("T4"), "A,F+C,2S", N=6)
    Runner("casadi").precompile(problem, {})
    assert not any(k[0] == "precompile" for k in problem.nlp.cache if isinstance(k, tuple))
    Runner("ipopt", scaling="physical").precompile(problem, {})
    scaled = scaled_nlp(problem.nlp)
    (future,) = [v for k, v in scaled.cache.items() if isinstance(k, tuple) and k[0] == "precompile"]
    future.result()
    assert not any(k[0] == "precompile" for k in problem.nlp.cache if isinstance(k, tuple))
    Runner("ipopt").precompile(problem, {})
    (own,) = [v for k, v in problem.nlp.cache.items() if isinstance(k, tuple) and k[0] == "precompile"]
    own.result()


@pytest.mark.parametrize("lower", ["inverse_dynamics", "static_path"])
def test_stage_one_from_both_guesses_hands_over_the_lower_objective_and_counts_every_run(monkeypatch, lower):
    calls = []

    def fake_run(runner, problem, x0, options, stage):
        calls.append((problem, np.array(x0), stage))
        res = _fake_result(problem, x0, iterations=10 * len(calls))
        if not problem.layout.pseudo_static:
            return res
        from_sp = "static path" in stage
        return dataclasses.replace(res, objective=1.0 if from_sp == (lower == "static_path") else 2.0)

    monkeypatch.setattr(Runner, "run", fake_run)
    both = SolveSettings(N1=10, guess="both", handover="direct")
    sol = solve("T3", "A,F+C,2S", N=20, settings=both)
    (id_run, id_x0, _), (sp_run, sp_x0, sp_name), (final, x2, _) = calls
    assert sp_name == "stage 1 (pseudo-static) from the static path guess"
    np.testing.assert_array_equal(id_x0, with_guess(id_run, "inverse_dynamics").bounds.x0)
    np.testing.assert_array_equal(sp_x0, with_guess(id_run, "static_path").bounds.x0)
    assert np.max(np.abs(sp_x0 - id_x0)) > 1e-3  # T3 has a static path on this grid
    first = sol.stages[0]
    assert first.guess == lower and first.objective == 1.0 and first.success
    assert first.attempts == 2 and first.runs == (10, 20) and first.iterations == 30
    # stage 2 starts from the chosen run's solution (the fake solves return their start)
    chosen = sp_x0 if lower == "static_path" else id_x0
    np.testing.assert_array_equal(x2, handover.stage_two_start(id_run.full(chosen), final)[0])


def test_stage_one_from_both_guesses_prefers_a_success_and_skips_a_second_run_from_the_same_start(monkeypatch):
    calls = []

    def fake_run(runner, problem, x0, options, stage):
        calls.append(stage)
        fail = stage == "stage 1 (pseudo-static)"  # the first run from the inverse dynamics, lower objective
        res = _fake_result(problem, x0, "Infeasible_Problem_Detected" if fail else "Solve_Succeeded", 5)
        return dataclasses.replace(res, objective=0.5 if fail else 3.0)

    monkeypatch.setattr(Runner, "run", fake_run)
    both = SolveSettings(N1=10, guess="both", handover="direct")
    sol = solve("T3", "A,F+C,2S", N=20, settings=both)
    # the inverse-dynamics start's fallback succeeds at 3.0, the static path's first run too: a tie keeps the first
    assert calls[:3] == ["stage 1 (pseudo-static)", "stage 1 (pseudo-static), attempt 2", calls[2]]
    assert sol.stages[0].guess == "inverse_dynamics" and sol.stages[0].attempts == 3 and sol.stages[0].success
    # T4 has no static path on this grid: its guess is the inverse-dynamics one, and stage 1 runs once
    calls.clear()
    monkeypatch.setattr(Runner, "run", lambda *a: _fake_result(a[1], a[2]))
    sol = solve("T4", "A,F+C,2S", N=20, settings=both)
    assert sol.stages[0].attempts == 1 and sol.stages[0].guess == "inverse_dynamics"


@pytest.mark.parametrize(
    "fraction, status, runs",
    [
        (0.05, "Solve_Succeeded", ["static path"]),  # stage 1 left the path: one run
        (0.2, "Solve_Succeeded", ["static path", "inverse dynamics"]),  # it kept the path's detour
        (0.05, "Infeasible_Problem_Detected", ["static path", "inverse dynamics"]),  # it failed
    ],
)
def test_auto_guess_runs_the_inverse_dynamics_guess_only_where_the_static_path_was_kept(
    monkeypatch, fraction, status, runs
):
    """``guess="auto"``: stage 1 from the static path; from the inverse-dynamics guess as well
    where that run ends above ``STAGE1_PATH_KEPT`` of its start's objective, or fails (the static
    path's fallbacks are cut here to one run, so that its failure is its first run's)."""
    calls = []
    monkeypatch.setattr(stage_one, "STAGE1_FALLBACKS", ())

    def fake_run(runner, problem, x0, options, stage):
        res = _fake_result(problem, x0, iterations=7)
        if not problem.layout.pseudo_static:
            return res
        from_id = "inverse dynamics" in stage
        calls.append("inverse dynamics" if from_id else "static path")
        if from_id:
            return dataclasses.replace(res, objective=0.0)  # the lower one
        f0 = float(problem.nlp.jitted().f(np.asarray(x0), problem.p))
        return dataclasses.replace(_fake_result(problem, x0, status, 7), objective=fraction * f0)

    monkeypatch.setattr(Runner, "run", fake_run)
    sol = solve("T3", "A,F+C,2S", N=20, settings=SolveSettings(N1=10, handover="direct"))
    assert calls == runs
    first = sol.stages[0]
    assert first.guess == ("static_path" if len(runs) == 1 else "inverse_dynamics")
    assert first.iterations == 7 * len(runs) and first.success
    assert SolveSettings().guess == "auto"


def test_better_stage_one_run_is_the_successful_one_then_the_lower_objective():
    problem = build_problem("T1", "A,F+C,2S", N=5, pseudo_static=True, guess="linear")

    def runs(status, objective):
        res = dataclasses.replace(_fake_result(problem, problem.bounds.x0, status), objective=objective)
        return stage_one._Runs("linear", problem, (res,), stage_one.Fallback({}))

    ok, low, failed = runs("Solve_Succeeded", 2.0), runs("Solve_Succeeded", 1.0), runs("Error", 0.5)
    assert stage_one._better(ok, low) is low and stage_one._better(low, ok) is low
    assert stage_one._better(failed, ok) is ok and stage_one._better(ok, failed) is ok
    same = runs("Solve_Succeeded", 2.0)
    assert stage_one._better(ok, same) is ok


def test_stage_one_from_both_guesses_is_the_run_of_lower_objective_of_the_two_alone():
    final = build_problem("T3", "A,F+C,2S", N=20, guess="linear")
    relaxed, _ = handover.relaxed_stage_problem(final, ContactParams.relaxed(), 2)
    alone = {}
    for guess in ("inverse_dynamics", "static_path"):
        alone[guess] = stage_one.stage_one(relaxed, SolveSettings(N1=10, guess=guess), None, Runner("ipopt"))
    stats, Z1 = stage_one.stage_one(relaxed, SolveSettings(N1=10, guess="both"), None, Runner("ipopt"))
    assert all(s.success for s, _ in alone.values()) and stats.success
    assert alone["inverse_dynamics"][0].objective != alone["static_path"][0].objective
    lower = min(alone, key=lambda g: alone[g][0].objective)
    assert stats.guess == lower and stats.objective == alone[lower][0].objective
    np.testing.assert_array_equal(Z1, alone[lower][1])
    assert stats.iterations == sum(s.iterations for s, _ in alone.values())
