"""From stage 1 of 2S to the dynamic stages (Sec. III-A.3): the start on the fine grid, the law path
and the dynamic solves along it.

Stage 1's primal solution, linearly interpolated onto the fine grid (``stage_two_start``),
warm-starts the full dynamic problem (6) with the nominal law. Only primal variables are passed on
(as in the paper); the barrier parameter of the dynamic stages is a solver option
(``STAGE2_DEFAULTS``, ``SolveSettings.stage2_options``).

The hand-over (``settings.HANDOVERS``) is either the paper's ``"direct"`` one, stage 2 solved once
under the nominal law, or ``"continuation"``: stage 2 solved under a path of laws from stage 1's
to the nominal one (``law_path``), each solve warm-started from the last, every law with its start
posture re-seated (``with_law``). The long first solve then runs under the relaxed law, and the
later ones are short, local corrections, whose end depends on the stage-1 point but not on the
backend (docs/results.md). Where the relaxed law cannot seat the start posture, the relaxed-law
stages take the first law of that path that can (``relaxed_stage_problem``).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.solvers.result import NLPResult
from jaxhumanoid.strategy.posture import reseat_for_contact, rest_foot_rows
from jaxhumanoid.strategy.problem import Problem
from jaxhumanoid.strategy.runner import ADAPTIVE, Runner, stage_stats
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solution import StageStats

# The barrier of the dynamic stages from stage 1's primal warm start (docs/decisions.md): a small
# initial barrier and a small bound push keep the warm start instead of pushing every variable
# back to the middle of its bounds.
STAGE2_DEFAULTS = {"mu_init": 1e-3, "bound_push": 1e-6, "bound_frac": 1e-6}
# Later laws of the continuation start next to their optimum: a small barrier keeps them there.
CONTINUATION_OPTIONS = {"mu_init": 1e-5}
# The relaxed-law dynamic solve and the continuation's laws before the nominal one are starts of
# the next solve, not results: they stop at a looser tolerance (beneath the stage's own options,
# so that a ``tol`` given for the solve holds for every stage). Over 40 perturbed problems that
# saves about 10 iterations a problem, at the same optimum (within 1e-6) on 31 and within 0.7 %
# on all but one (docs/decisions.md).
INTERMEDIATE_OPTIONS = {"tol": 1e-3}
# The relaxed-law dynamic solve starts from stage 1's quasi-static motion with stage 2's small
# barrier and bound push, which keep that start. Where the start is far from a dynamic motion, the
# barrier stays stuck at the bounds (a perturbed T1 problem stops at 3063 iterations with a
# violation of 226). The reruns, from the same start, push it inside the bounds as a cold start
# does (IPOPT's defaults; that T1 problem converges in 806), then add the adaptive barrier update
# (a perturbed T2 problem with N1 = 50, infeasible with the monotone one, converges in 450;
# docs/results.md). A later law of the continuation that fails gets the same reruns: IPOPT's law 3
# of a perturbed T4 problem with N1 = 50 stops at 3000 iterations, and its cold rerun converges in
# 795 (docs/modelling.md).
_COLD = {"mu_init": 1e-1, "bound_push": 1e-2, "bound_frac": 1e-2}
DYNAMIC_FALLBACKS: tuple[dict, ...] = (_COLD, {**_COLD, **ADAPTIVE})
_LAW_FIELDS = tuple(f.name for f in dataclasses.fields(ContactParams))


def dynamic_options(options: Mapping[str, Any] | None, settings: SolveSettings, two_stage: bool) -> dict:
    """The solver options of the dynamic stages (of the one stage of 1S): ``STAGE2_DEFAULTS`` after
    stage 1 of 2S, then ``solve``'s ``options``, then ``settings.stage2_options``."""
    return {**(STAGE2_DEFAULTS if two_stage else {}), **(options or {}), **(settings.stage2_options or {})}


def interpolate_full(Z_coarse: np.ndarray, T: float, layout_fine: tr.Layout) -> np.ndarray:
    """Linear interpolation of a coarse full layout onto a fine grid (same horizon).

    Node quantities (q, qd) are interpolated at nodes; interval quantities (u, f) at interval
    midpoints. Both layouts must carry the same per-stage variables.
    """
    Nc = Z_coarse.shape[0] - 1
    Nf = layout_fine.N
    tc, tf = np.linspace(0, T, Nc + 1), np.linspace(0, T, Nf + 1)
    mc, mf = 0.5 * (tc[:-1] + tc[1:]), 0.5 * (tf[:-1] + tf[1:])
    Z = np.zeros((Nf + 1, layout_fine.s))
    n_node = layout_fine.stage_slices()["qd"].stop  # q and qd lead every stage
    for j in range(n_node):
        Z[:, j] = np.interp(tf, tc, Z_coarse[:, j])
    for j in range(n_node, layout_fine.s):
        Z[:-1, j] = np.interp(mf, mc, Z_coarse[:-1, j])
    return Z


def stage_two_start(Z_coarse: np.ndarray, final: Problem) -> tuple[np.ndarray, np.ndarray]:
    """The start of the dynamic stages from stage 1's solution ``Z_coarse`` (N1 + 1, s): returns
    (x0 (n,), Zf (N + 1, s)) on ``final``'s grid.

    Positions, torques and forces are interpolated linearly (``interpolate_full``, Sec. III-A.3).
    The velocities are not: in the pseudo-static model (8), (6a) ties only the mean of two
    neighbouring node velocities to the positions, so stage 1's node velocities alternate from
    node to node (the acceleration cost damps, but does not remove, that mode), and their
    differences would read as large accelerations in (6b) and in the foot reaction of (5). They are
    taken from the interpolated positions instead, qd_k = (q_{k+1} - q_{k-1}) / (2h) (one-sided at
    the ends; x0 leaves out the fixed entries, qd_0 = 0 among them, and is clipped to ``final``'s
    bounds).
    """
    layout, T = final.layout, float(final.p.T)
    Zf = interpolate_full(Z_coarse, T, layout)
    sl = layout.stage_slices()
    Zf[:, sl["qd"]] = np.gradient(Zf[:, sl["q"]], T / layout.N, axis=0)
    x0 = np.clip(np.asarray(tr.free_from_full(layout, Zf)), final.bounds.xl, final.bounds.xu)
    return x0, Zf


def law_path(first: ContactParams, last: ContactParams, steps: int) -> tuple[ContactParams, ...]:
    """``steps + 1`` laws from ``first`` to ``last``: law_j = first^(1 - l) last^l per parameter
    (kappa, f0, xhat, mu), l = j / steps; geometric because kappa and f0 set the scale of forces."""

    def at(lam: float) -> ContactParams:
        mix = {k: float(getattr(first, k)) ** (1 - lam) * float(getattr(last, k)) ** lam for k in _LAW_FIELDS}
        return ContactParams(**mix)

    return tuple(at(j / steps) for j in range(steps)) + (last,)


def with_law(problem: Problem, law: ContactParams) -> Problem:
    """``problem`` under another contact law, its start posture re-seated so that the law carries
    the same contact forces there (``posture.reseat_for_contact``): the start stays a static
    equilibrium with the same torques and foot margins. The NLP is the same; only p changes."""
    if all(np.array_equal(getattr(law, k), getattr(problem.p.contact, k)) for k in _LAW_FIELDS):
        return problem
    q_start, _ = reseat_for_contact(problem.p, problem.p.q_start, problem.layout.active, law)
    return dataclasses.replace(problem, p=dataclasses.replace(problem.p, contact=law, q_start=jnp.asarray(q_start)))


def relaxed_stage_problem(final: Problem, first: ContactParams, steps: int) -> tuple[Problem, int]:
    """The final problem as 2S's relaxed-law stages pose it, and the step j of its law on
    ``law_path(first, nominal, steps)``: under the first law of that path for which the start,
    re-seated (``with_law``), keeps the foot's rows (5) at rest; ``first`` itself (j = 0) on
    every problem of the robustness study but one. There a lightly loaded foot puts the centre of
    pressure off the sole under the relaxed law whatever the re-seat does, so stage 1's frozen
    first interval and the relaxed-law dynamic solve are infeasible from every start; a step along
    the path seats it (docs/results.md). A step other than 0 is announced by a warning."""
    laws = law_path(first, final.p.contact, steps)  # laws[0] is ``first`` (first^1 last^0)
    step, problem = steps, final  # the nominal law, where no earlier law seats the start
    for j, law in enumerate(laws[:-1]):
        seated = with_law(final, law)
        rows, _ = rest_foot_rows(final.model, final.p.foot, law, seated.p.q_start, final.layout.active)
        if np.min(rows) >= 0.0:
            step, problem = j, seated
            break
    if step:
        warnings.warn(
            f"task {final.task.key}: the start posture breaks the foot's rows (5) at rest under the relaxed "
            f"contact law; the relaxed-law stages use law {step}/{steps} of the path to the nominal law",
            stacklevel=3,
        )
    return problem, step


def run_path(problems: Sequence[Problem], x0, options: Mapping[str, Any], runner: Runner, label: str):
    """Solve each problem of a law path in turn by ``runner``, each from the last one's solution
    (the first from x0, the later ones with ``CONTINUATION_OPTIONS``); every problem but the last
    with ``INTERMEDIATE_OPTIONS`` beneath. A failed solve is rerun from the same start with each of
    ``DYNAMIC_FALLBACKS`` while it fails, and the path stops at a law that none solves. Returns
    (every run, the number of laws solved)."""
    attempts: list[NLPResult] = []
    x = x0
    for j, problem in enumerate(problems):
        name = label if len(problems) == 1 else f"{label}, law {j + 1}/{len(problems)}"
        opts = options if j == 0 else {**options, **CONTINUATION_OPTIONS}
        if j < len(problems) - 1:
            opts = {**INTERMEDIATE_OPTIONS, **opts}
        for k, rerun in enumerate(({}, *DYNAMIC_FALLBACKS)):
            run = runner.run(problem, x, {**opts, **rerun}, name if k == 0 else f"{name}, rerun {k}")
            attempts.append(run)
            if run.success:
                break
        if not attempts[-1].success:
            return attempts, j
        x = attempts[-1].x
    return attempts, len(problems)


def continuation_stages(
    path: Sequence[Problem], x0, options: Mapping[str, Any], runners: tuple[Runner, Runner], setup_time_s: float
) -> tuple[list[StageStats], Any]:
    """The dynamic stages of a continuation hand-over along ``path``, the final problem under each
    law of the path: the first law (stage 1's) by ``runners[0]``, then the path to the nominal law
    by ``runners[1]`` (``run_path``, reruns included), from x0 with the dynamic stages' solver
    ``options``. Returns (stats of both, x); a failed solve ends the path, and its stage reports
    its status with the law it failed at. The first stage's compile time includes
    ``setup_time_s``."""
    stats: list[StageStats] = []
    x = x0
    for runner, part, name in (
        (runners[0], path[:1], "stage 1 (dynamic, relaxed law)"),
        (runners[1], path[1:], "stage 2 (dynamic)"),
    ):
        # the relaxed-law solve is a start as well, though the last (only) law of its part
        opts = {**INTERMEDIATE_OPTIONS, **options} if not stats else options
        attempts, solved = run_path(part, x, opts, runner, name)
        st = stage_stats(name, part[-1], attempts, setup_time_s if not stats else 0.0, x)
        if solved < len(part) and len(part) > 1:
            st = dataclasses.replace(st, status=f"{st.status} (law {solved + 1}/{len(part)})", success=False)
        stats.append(st)
        x = attempts[-1].x
        if not st.success:
            break
        options = {**options, **CONTINUATION_OPTIONS}
    return stats, x
