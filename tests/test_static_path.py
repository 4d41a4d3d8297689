"""The static-path guess: postures the body can hold, its join, its fall-back, and stage 1 from it."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from jaxhumanoid.ocp import static_path as sp
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy import problem as pm
from jaxhumanoid.strategy import solve as solve_module
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.stage_one import STAGE1_DEFAULTS, stage_one_problem

N1 = 30


@functools.cache
def stage_one(task: str, guess: str):
    final = pm.build_problem(task, "A,F+C,1S", N=100)
    return stage_one_problem(task, "A,F+C,1S", final, N1, guess=guess)


def path_inputs(problem):
    lay, p = problem.layout, problem.p
    Z0 = tr.initial_guess_full(lay, np.asarray(p.q_start), np.asarray(problem.task.goal), float(p.T))
    lo, hi = pm._bounds_full(problem.task, lay, p)
    return lay, p, Z0, lo, hi, problem.task.force_box(p.model)


def nonlinear_violation(problem) -> float:
    """Largest violation at the start point of the rows (8), the force rows, (5) and clearance (N, N m, m):
    every row but the linear (6a)."""
    g = np.asarray(problem.nlp.g(problem.bounds.x0, problem.p)).reshape(problem.layout.N, -1)
    kinds = problem.layout.constraint_kinds()
    v = np.where(kinds == 0, np.abs(g), np.maximum(-g, 0.0))
    return float(v[:, problem.layout.n_links :].max())


def test_the_path_holds_every_row_of_stage_one_but_the_linear_kinematic_ones():
    weight = float(stage_one("T1", "static_path").model.total_mass) * 9.81
    held = nonlinear_violation(stage_one("T1", "static_path"))
    linear = nonlinear_violation(stage_one("T1", "inverse_dynamics"))
    assert held <= sp.TOL * weight  # the path's worst row, in body weights at most TOL
    assert linear > 100.0  # the same check fails on the straight motion: the foot rows by hundreds of newtons


def test_the_join_is_the_least_violating_one():
    lay, p, Z0, lo, hi, f_max = path_inputs(stage_one("T4", "inverse_dynamics"))
    sl = lay.stage_slices()
    F, B = sp._sweeps(lay, p, f_max, np.array(Z0[:, sl["q"]]), lo[:, sl["q"]], hi[:, sl["q"]])
    Q, worst = sp._join(lay, p, f_max, F, B)
    rows = sp._compiled(lay, f_max)[0]

    def path_worst(Q):
        return float(-np.min(np.asarray(rows(p, Q[:-1], Q[1:]))))

    brute = min(path_worst(np.concatenate([F[: m + 1], B[m + 1 :]])) for m in range(1, lay.N))
    assert worst == pytest.approx(brute, rel=1e-12) and path_worst(Q) == pytest.approx(worst, rel=1e-12)
    assert worst > sp.TOL  # lying down: neither sweep gets past the hands' landing (the fall-back case)


def test_no_path_falls_back_to_the_inverse_dynamics_guess_bitwise():
    lay, p, Z0, lo, hi, f_max = path_inputs(stage_one("T4", "inverse_dynamics"))
    Z, worst = sp.static_path_guess(lay, Z0, p, lo, hi, f_max)
    assert worst > sp.TOL
    assert np.array_equal(Z, np.asarray(tr.inverse_dynamics_guess(lay, Z0, p)))
    assert np.array_equal(stage_one("T4", "static_path").bounds.x0, stage_one("T4", "inverse_dynamics").bounds.x0)


def test_an_admissible_target_is_kept_and_an_inadmissible_one_moved_onto_the_rows():
    lay, p, Z0, lo, hi, f_max = path_inputs(stage_one("T1", "inverse_dynamics"))
    _, rows, _, d_b = sp._compiled(lay, f_max)
    q = lay.stage_slices()["q"]
    q_a = Z0[1, q]
    c = functools.partial(rows, p, q_a)
    dc = functools.partial(d_b, p, q_a)
    assert np.array_equal(sp._nearest(c, dc, q_a, lo[2, q], hi[2, q]), q_a)  # the start holds itself
    target = Z0[N1 // 2, q]  # halfway up, straight: the foot and the strengths do not hold it
    assert np.min(np.asarray(c(target))) < -0.1
    moved = sp._nearest(c, dc, target, lo[2, q], hi[2, q])
    assert np.min(np.asarray(c(moved))) >= -1e-8


def test_stage_one_converges_from_the_path():
    problem = stage_one("T3", "static_path")
    assert nonlinear_violation(problem) <= sp.TOL * float(problem.model.total_mass) * 9.81
    result = solve_ipopt(problem.nlp, problem.p, problem.bounds, options=STAGE1_DEFAULTS)
    assert result.success, result.status


def test_two_stage_solves_compute_the_path_for_stage_one_only(monkeypatch):
    grids = []
    original = sp.static_path_guess
    monkeypatch.setattr(
        sp, "static_path_guess", lambda layout, *a, **k: grids.append(layout.N) or original(layout, *a, **k)
    )

    def stage_one_only(relaxed, settings, options, runner):
        N1 = settings.stage1_grid(relaxed.layout.N)
        stage_one_problem(relaxed.task, relaxed.scheme, relaxed, N1, guess=settings.guess)
        raise StopIteration

    monkeypatch.setattr(solve_module, "stage_one", stage_one_only)
    with pytest.raises(StopIteration):
        solve_module.solve("T1", "A,F+C,2S", N=40, settings=SolveSettings(guess="static_path"))
    assert grids == [N1]  # the final grid's problem starts from stage 1's solution: no path for it
