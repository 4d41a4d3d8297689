"""One-stage (1S) and two-stage (2S) strategies (Sec. III-A.3), producing a ``Solution``.

2S: stage 1 solves the pseudo-static problem (8) on a coarse grid (N1 = 30) with the relaxed
contact law; its primal solution, linearly interpolated onto the fine grid, warm-starts stage 2,
the full dynamic problem (6) with the nominal law. Only primal variables are passed on (as in the
paper); the barrier parameter of stage 2 is an IPOPT option (``stage2_options``).

The hand-over (``HANDOVERS``) is either the paper's ``"direct"`` one, stage 2 solved once under the
nominal law, or ``"continuation"``: stage 2 solved under a path of laws from stage 1's to the
nominal one (``law_path``), each solve warm-started from the last, every law with its start
posture re-seated (``with_law``). The long first solve then runs under the relaxed law, and the
later ones are short, local corrections, whose end depends on the stage-1 point but not on the
backend (docs/results.md). Where the relaxed law cannot seat the start posture, the relaxed-law
stages take the first law of that path that can (``relaxed_stage_problem``).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import time
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.scaling import as_jax, check_scaling, physical_scaling, scaled_bounds, scaled_nlp
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, Task, Weights, get_task, with_force_limit
from jaxhumanoid.solvers.ipm import solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.solvers.result import IterationCallback, NLPResult, constraint_violation, unscaled, unscaled_progress
from jaxhumanoid.strategy.posture import (
    check_start_margin,
    find_equilibrium,
    margins,
    reseat_for_contact,
    rest_foot_rows,
)
from jaxhumanoid.strategy.problem import DEFAULT_GUESS, GUESSES, Problem, build_problem, with_guess
from jaxhumanoid.strategy.solution import Solution, StageStats
from jaxhumanoid.validation.casadi_backend import solve_casadi

SOLVERS = ("ipopt", "ipm", "casadi")
STAGE1_N = 30
# Barrier settings of the two stages (docs/modelling.md; scripts/study_warm_start.py):
# stage 1 with mu_init = 1e-2 succeeds in one more first run of 40 perturbed problems than IPOPT's
# 0.1, in fewer iterations at the median. Stage 2 from the primal warm start: a small initial barrier
# and a small bound push keep the warm start instead of pushing every variable back to the middle of
# its bounds.
STAGE1_DEFAULTS = {"mu_init": 1e-2}
STAGE2_DEFAULTS = {"mu_init": 1e-3, "bound_push": 1e-6, "bound_frac": 1e-6}
# Stage 1 poses the body with twice its torque box (the cost keeps the task's weights; the
# dynamic stages keep the body's box): a quasi-static motion, without inertia to carry the body
# through, needs more torque than a dynamic one (getting up prone quasi-statically takes about 1.7
# times an adult's strength), and within the body's own box stage 1 of the built-in T1 ends
# infeasible. Twice the box: 12 of 12 perturbed problems solve and the whole 2S takes 414
# iterations at the median, against 11 of 12 and 470 (docs/results.md).
STAGE1_STRENGTH = 2.0
# Stage 1 can still end "infeasible" from its initial guess: its landscape is chaotic, and starts
# 1e-4 apart end in different optima or fail. Each failed run is followed by the next fallback, in
# order, by every solver. The two guesses fail on different problems, so every fallback is tried
# from both. The final problem's bounds can make stage 1 infeasible from every start (perturbed T3
# under its contact-force limit), so the last fallbacks relax stage 1's bounds, first without the
# task's contact-force limit, then with twice stage 1's torque box too; the dynamic stages keep the
# task's bounds and bring the motion back within them. The iterations and times of every run add
# up.
STAGE1_RESTART_SIGMA = 1e-4


@dataclasses.dataclass(frozen=True)
class Fallback:
    """One more run of a failed stage 1: solver ``options`` on top of the stage's; from the other
    guess of ``GUESSES`` when ``other_guess``; with ``seed``, every entry of the guess moved by
    ``STAGE1_RESTART_SIGMA`` times a standard normal draw of that fixed seed; without the task's
    contact-force limit when ``lift_force_limit`` (skipped for a task that has none, unless the
    strength changes too); with stage 1's torque box ``STAGE1_STRENGTH`` u_max scaled by
    ``strength``."""

    options: dict
    seed: int | None = None
    other_guess: bool = False
    lift_force_limit: bool = False
    strength: float = 1.0

    def lifts_limit(self, task: Task) -> bool:
        """Whether the run drops a contact-force limit that ``task`` has."""
        return self.lift_force_limit and task.contact_force_limit is not None

    def relaxations(self, task: Task) -> tuple[str, ...]:
        """How the run relaxes ``task``'s bounds, in words (empty when it does not)."""
        return ((f"stage 1's torque box x{self.strength:g}",) if self.strength != 1.0 else ()) + (
            ("no contact-force limit",) if self.lifts_limit(task) else ()
        )


_ADAPTIVE = {"mu_strategy": "adaptive"}
STAGE1_FALLBACKS: tuple[Fallback, ...] = (
    Fallback({}, None, True),
    Fallback(_ADAPTIVE, None, False),
    Fallback(_ADAPTIVE, None, True),
    Fallback({}, 1, False),
    Fallback({}, 1, True),
    Fallback(_ADAPTIVE, 1, False),
    Fallback(_ADAPTIVE, 1, True),
    Fallback({}, None, False, lift_force_limit=True),
    Fallback({}, None, True, lift_force_limit=True),
    Fallback({}, None, False, lift_force_limit=True, strength=2.0),
    Fallback({}, None, True, lift_force_limit=True, strength=2.0),
)


HANDOVERS = ("direct", "continuation")
# Two steps from the relaxed to the nominal law: on 12 perturbed problems they reach the optima of
# four steps (the same on 7, lower on 2, at most 3e-3 higher on 3) with a median continuation of 55
# iterations against 79; one step reaches higher optima, up to 8 % (docs/decisions.md).
CONTINUATION_STEPS = 2
# The defaults of ``solve`` (docs/results.md measures the alternatives): the inverse-dynamics
# guess (``problem.DEFAULT_GUESS``), the continuation hand-over, and IPOPT for the relaxed-law
# stages, so that the far-start globalisation is one backend's and ``solver`` decides the
# continuation to the nominal law, where every backend reaches the same optimum.
DEFAULT_HANDOVER = "continuation"
DEFAULT_STAGE1_SOLVER = "ipopt"
# Later laws of the continuation start next to their optimum: a small barrier keeps them there.
CONTINUATION_OPTIONS = {"mu_init": 1e-5}
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
DYNAMIC_FALLBACKS: tuple[dict, ...] = (_COLD, {**_COLD, **_ADAPTIVE})
_LAW_FIELDS = tuple(f.name for f in dataclasses.fields(ContactParams))


StageProgress = Callable[[str, int, float, float], None]
"""What ``solve`` reports after every iteration: (stage name, iteration, objective, primal infeasibility)."""


def _run_solver(
    solver: str,
    problem: Problem,
    x0,
    options,
    verbose,
    progress: IterationCallback | None = None,
    scaling: str = "none",
) -> NLPResult:
    """One solve of ``problem`` from x0 by ``solver``; with ``scaling="physical"`` the solver runs
    the scaled problem (``ocp.scaling``) and the result comes back in the problem's own units."""
    if solver not in SOLVERS:
        raise ValueError(f"solver: {solver!r} not in {SOLVERS}")
    s = None if scaling == "none" else physical_scaling(problem.layout, float(problem.p.T))
    run = progress if s is None else unscaled_progress(progress, s.obj)
    if solver == "casadi":
        return solve_casadi(problem, x0=x0, options=options, verbose=verbose, progress=run, scaling=s)
    nlp, bounds, y0 = problem.nlp, problem.bounds, np.asarray(x0)
    p: Any = problem.p
    if s is not None:
        nlp, p, bounds, y0 = scaled_nlp(nlp), (p, as_jax(s)), scaled_bounds(bounds, s), y0 * s.x
    if solver == "ipopt":
        res = solve_ipopt(nlp, p, bounds, x0=y0, options=options, verbose=verbose, progress=run)
    else:
        res = solve_ipm(nlp, p, bounds, x0=y0, options=options, progress=run)
    if s is None:
        return res
    return unscaled(res, s, violation_at(problem, np.asarray(res.x) / s.x))


def _for_stage(progress: StageProgress | None, stage: str) -> IterationCallback | None:
    return None if progress is None else functools.partial(progress, stage)


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


def violation_at(problem: Problem, x) -> float:
    """The largest constraint or bound violation of ``problem`` at x (n,), in its own units."""
    x = np.asarray(x, dtype=float)
    g = problem.nlp.jitted().g(x, problem.p)
    b = problem.bounds
    return constraint_violation(np.asarray(g), x, b.gl, b.gu, b.xl, b.xu)


def _stage_stats(name: str, problem: Problem, attempts: list[NLPResult], setup_time_s: float, x0) -> StageStats:
    """Statistics of one stage from its solver runs (more than one when a fallback was needed) from
    the start point x0: status and objective of the last run, iterations and times summed over all
    of them. ``compile_time_s`` counts the one-off work: problem set-up (pattern detection,
    colouring) and tracing/compilation of the evaluators."""
    res = attempts[-1]
    return StageStats(
        name=name,
        status=res.status,
        success=bool(res.success),
        iterations=sum(int(r.iterations) for r in attempts),
        solve_time_s=sum(float(r.solve_time_s) for r in attempts),
        compile_time_s=sum(float(r.compile_time_s) for r in attempts) + setup_time_s,
        objective=float(res.objective),
        max_constraint_violation=float(res.max_constraint_violation),
        n_variables=int(problem.nlp.n),
        n_constraints=int(problem.nlp.m),
        attempts=len(attempts),
        start_violation=violation_at(problem, x0),
        runs=tuple(int(r.iterations) for r in attempts),
    )


def make_solution(problem: Problem, x, stages, solver: str, warm_start=None) -> Solution:
    """Trajectory arrays and derived quantities (forces, gaps, foot reaction) of a solution x."""
    layout, p = problem.layout, problem.p
    Z = problem.full(x)
    sl = layout.stage_slices()
    N, h = layout.N, float(p.T) / layout.N
    q, qd, u = Z[:, sl["q"]], Z[:, sl["qd"]], Z[:-1, sl["u"]]
    qbar, qdbar = 0.5 * (q[:-1] + q[1:]), 0.5 * (qd[:-1] + qd[1:])
    if layout.pseudo_static:
        qdbar = np.diff(q, axis=0) / h
    idx = np.asarray(layout.active, dtype=int) - 1
    qdd = np.zeros_like(qbar) if layout.pseudo_static else np.diff(qd, axis=0) / h
    qd_used = np.zeros_like(qbar) if layout.pseudo_static else qdbar
    forces, f_c0, margins, gaps, terms = jax.tree_util.tree_map(
        np.asarray, _derived(layout, p, jnp.asarray(Z), qbar, qdbar, qd_used, qdd)
    )
    f_contact = np.zeros((N, layout.n_links, 2))
    f_contact[:, idx] = forces
    terms = {k: float(terms[k]) for k in tr.OBJECTIVE_TERMS}  # in (7)'s order (a jitted dict comes back sorted)
    return Solution(
        task=problem.task.key,
        scheme=str(problem.scheme),
        solver=solver,
        t=np.linspace(0.0, float(p.T), N + 1),
        q=q,
        qd=qd,
        u=u,
        f_contact=f_contact,
        gaps=gaps,
        foot_reaction=f_c0,
        foot_margins=margins,
        objective=float(sum(terms.values())),
        objective_terms=terms,
        stages=stages,
        active=tuple(layout.active),
        geometry={
            "a": np.asarray(p.model.a),
            "names": tuple(p.model.names),
            "ankle_height": float(p.foot.ankle_height),
            "a0f": float(p.foot.a0f),
            "a0b": float(p.foot.a0b),
            "mu": float(p.contact.mu),
            "m": np.asarray(p.model.m),
            "g": float(p.model.g),
            "c": np.asarray(p.model.c),
            "inertia": np.asarray(p.model.inertia),
            "u_max": np.asarray(p.model.u_max),
            "kappa": float(p.contact.kappa),
            "f0": float(p.contact.f0),
            "xhat": float(p.contact.xhat),
            "goal": np.asarray(problem.task.goal),
            "goal_tolerance": float(problem.task.goal_tolerance),
            **{f"margin_{k}": float(getattr(p.foot_margin, k)) for k in ft.MARGIN_FIELDS},
        },
        warm_start=warm_start,
    )


@functools.partial(jax.jit, static_argnums=0)
def _derived(layout: tr.Layout, p, Z, qbar, qdbar, qd_used, qdd):
    """``make_solution``'s contact forces (N, k, 2), foot reaction, rows (5), gaps and the terms of
    (7) as one program: evaluated op by op, each of their operations compiles on its own."""
    N = layout.N
    if layout.augmented:
        forces = Z[:-1, layout.stage_slices()["f"]].reshape(N, -1, 2)
    else:
        forces = jax.vmap(lambda a, b: ct.contact_forces(p.model, p.foot, p.contact, a, b, layout.active))(qbar, qdbar)
    f_c0 = jax.vmap(lambda a, b, c, f: ft.foot_reaction(p.model, a, b, c, f))(qbar, qd_used, qdd, forces)
    u1 = Z[:-1, layout.stage_slices()["u"]][:, 0]
    margins = jax.vmap(lambda f, u: ft.foot_constraints(p.foot, p.contact.mu, f, u))(f_c0, u1)
    gaps = jax.vmap(lambda qq: kin.contact_gaps(p.model, p.foot, qq))(Z[:, layout.stage_slices()["q"]])
    return forces, f_c0, margins, gaps, tr.objective_terms(layout, Z, p)


def restart_point(problem: Problem, seed: int | None) -> np.ndarray:
    """The problem's initial guess (n,), or with ``seed`` every entry moved by
    ``STAGE1_RESTART_SIGMA`` times a standard normal draw of that seed (clipped to the bounds)."""
    b = problem.bounds
    if seed is None:
        return b.x0
    noise = np.random.default_rng(seed).standard_normal(b.x0.size)
    return np.clip(b.x0 + STAGE1_RESTART_SIGMA * noise, b.xl, b.xu)


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


def stage_one_problem(
    task,
    scheme,
    final: Problem,
    N1: int,
    contact_stage1=None,
    guess: str = "linear",
    strength: float = STAGE1_STRENGTH,
) -> Problem:
    """Stage 1 of 2S for the final problem ``final``: the pseudo-static problem (8) on N1 intervals
    under ``contact_stage1`` (default ``ContactParams.relaxed()``), from the start posture re-seated
    for that law (``with_law``; none when ``final`` is already posed under it, as
    ``relaxed_stage_problem`` poses it), with the final problem's horizon, weights, body and foot,
    and initial ``guess``; ``strength`` scales the body's torque box u_max (the cost keeps the
    task's weights)."""
    law = ContactParams.relaxed() if contact_stage1 is None else contact_stage1
    q_start1 = with_law(final, law).p.q_start  # ``final`` itself when it is posed under ``law``
    body = final.model
    if strength != 1.0:
        body = dataclasses.replace(body, u_max=strength * np.asarray(body.u_max))
    return build_problem(
        task,
        scheme,
        N=N1,
        T=float(final.p.T),
        pseudo_static=True,
        contact=law,
        q_start=q_start1,
        weights=np.asarray(final.p.weights),
        model=body,
        foot=final.p.foot,
        guess=guess,
        foot_margin=final.p.foot_margin,
    )


def _stage_one(
    task, scheme, solver, final: Problem, N1: int, options, contact_stage1, guess, verbose, progress, scaling
):
    """Stage 1 of 2S (``stage_one_problem``) with the stage-1 fallbacks. Returns (stats, Z1)."""
    t0 = time.perf_counter()
    first = stage_one_problem(task, scheme, final, N1, contact_stage1, guess)
    setup_first = time.perf_counter() - t0
    starts = {(False, 1.0, False): first}  # (lift_force_limit, strength, other_guess) -> the problem a run starts

    def start(lift: bool, strength: float, other: bool) -> Problem:
        if (lift, strength, other) not in starts:
            if other:
                base = start(lift, strength, False)
                starts[lift, strength, other] = with_guess(base, next(g for g in GUESSES if g != guess))
            else:
                posed = with_force_limit(task, NO_FORCE_LIMIT) if lift else task
                problem = stage_one_problem(posed, scheme, final, N1, contact_stage1, guess, STAGE1_STRENGTH * strength)
                starts[lift, strength, other] = problem
        return starts[lift, strength, other]

    name = "stage 1 (pseudo-static)"
    attempts = [_run_solver(solver, first, first.bounds.x0, options, verbose, _for_stage(progress, name), scaling)]
    last = Fallback({})  # the run that produced attempts[-1]: the first, which relaxes nothing
    for fb in STAGE1_FALLBACKS:
        if attempts[-1].success:
            break
        relaxed = fb.relaxations(task)
        if fb.lift_force_limit and not relaxed:
            continue  # the task has no limit: the same problem as an earlier run
        problem = start(fb.lift_force_limit, fb.strength, False)
        label = f"{name}, attempt {len(attempts) + 1}" + (" with " + ", ".join(relaxed) if relaxed else "")
        x0 = restart_point(start(fb.lift_force_limit, fb.strength, fb.other_guess), fb.seed)
        run = _run_solver(solver, problem, x0, {**options, **fb.options}, verbose, _for_stage(progress, label), scaling)
        attempts.append(run)
        last = fb
    stats = _stage_stats(name, first, attempts, setup_first, first.bounds.x0)
    relaxed = last.relaxations(task)
    if attempts[-1].success and relaxed:
        stats = dataclasses.replace(stats, force_limit_lifted=last.lifts_limit(task), strength_factor=last.strength)
        warnings.warn(
            f"task {task.key}: stage 1 failed under its bounds and was solved with "
            f"{', '.join(relaxed)}; the dynamic stages keep the task's bounds",
            stacklevel=3,
        )
    return stats, first.full(attempts[-1].x)


def _is_count(value, low: int) -> bool:
    """Whether ``value`` is an integer (not a bool) >= low."""
    return bool(not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= low)


def check_arguments(**kwargs) -> None:
    """``solve``'s keyword arguments checked as ``solve`` checks them before any work: a ValueError
    names the field and the values it allows (the command line's status 2)."""
    bound = inspect.signature(solve).bind(**kwargs)
    bound.apply_defaults()
    _check_arguments(bound.arguments)


def _check_arguments(a: dict) -> None:
    """Every argument of ``solve`` (``a``: name -> value) checked before any work, each error
    naming its field."""
    get_task(a["task"])
    parse_scheme(a["scheme"])
    for name, allowed in (
        ("solver", SOLVERS),
        ("stage1_solver", (*SOLVERS, "same", None)),
        ("guess", GUESSES),
        ("handover", HANDOVERS),
    ):
        if a[name] not in allowed:
            raise ValueError(f"{name}: {a[name]!r} not in {allowed}")
    check_scaling(a["scaling"])
    if not _is_count(a["continuation_steps"], 1):
        raise ValueError(f"continuation_steps: expected an integer >= 1, got {a['continuation_steps']!r}")
    for name in ("N", "N1"):
        if a[name] is not None and not _is_count(a[name], 3):
            raise ValueError(f"{name}: expected an integer number of intervals >= 3, got {a[name]!r}")
    T = a["T"]
    if isinstance(T, bool) or not isinstance(T, (int, float, np.integer, np.floating)) or not np.isfinite(T) or T <= 0:
        raise ValueError(f"T: expected a positive horizon in seconds (a number), got {T!r}")
    types = {"model": PlanarChain, "contact": ContactParams, "foot": FootParams, "contact_stage1": ContactParams}
    for name, cls in types.items():
        if a[name] is not None and not isinstance(a[name], cls):
            raise ValueError(f"{name}: expected a {cls.__name__} or None, got {type(a[name]).__name__}")
    for name in ("options", "stage1_options", "stage2_options"):
        if a[name] is not None and not isinstance(a[name], dict):
            raise ValueError(f"{name}: expected a dict of solver options or None, got {type(a[name]).__name__}")


def _weights_array(weights, n: int):
    """``weights`` as the (n + 3,) array of (7): a ``Weights``, an array or None (the task's)."""
    if weights is None:
        return None
    if isinstance(weights, Weights):
        return weights.as_array(n)
    w = np.asarray(weights, dtype=float) if not isinstance(weights, str) else np.array([np.nan])
    if w.shape != (n + 3,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(
            f"weights: expected a Weights or {n + 3} finite weights >= 0 (w_u1..w_u{n}, w_qd, w_dqd, "
            f"w_du), got {weights!r}"
        )
    return w


def _seated_task(task: Task, model, contact, foot) -> Task:
    """The task with its start posture moved to the nearest static equilibrium that keeps the
    foot steady with margin under the given body and law, when it does not already."""
    if model is None and contact is None and foot is None:
        return task
    body = PlanarChain.humanoid() if model is None else model
    if body.n != task.n:
        raise ValueError(f"model: task {task.key} is posed for {task.n} joints, the chain has {body.n} links")
    if margins(body, task.start, task.active, contact=contact, foot=foot).ok:
        return task
    q_min, q_max = task.joint_ranges(body)
    eq = find_equilibrium(body, task.start, task.active, contact=contact, foot=foot, q_min=q_min, q_max=q_max)
    warnings.warn(
        f"task {task.key}: start posture moved by up to {eq.moved:.1e} rad to the nearest static "
        "equilibrium that keeps the foot steady under the given body and contact law",
        stacklevel=3,
    )
    return dataclasses.replace(task, start=eq.q)


def solve(
    task="T1",
    scheme="A,F+C,2S",
    solver: str = "ipopt",
    N: int = 100,
    T: float = 5.0,
    N1: int | None = None,
    options: dict | None = None,
    stage1_options: dict | None = None,
    stage2_options: dict | None = None,
    verbose: bool = False,
    weights=None,
    model: PlanarChain | None = None,
    contact: ContactParams | None = None,
    foot: FootParams | None = None,
    contact_stage1: ContactParams | None = None,
    guess: str = DEFAULT_GUESS,
    handover: str = DEFAULT_HANDOVER,
    continuation_steps: int = CONTINUATION_STEPS,
    stage1_solver: str | None = DEFAULT_STAGE1_SOLVER,
    progress: StageProgress | None = None,
    foot_margin: ft.FootMargin | None = None,
    scaling: str = "none",
) -> Solution:
    """Solve one task with one strategy.

    ``task``: a key (``T1``..``T4``), a readable name or a ``Task``. ``N``: intervals of the
    (final) grid; ``N1``: those of stage 1 of 2S (default min(30, N): never finer than the final
    grid). ``options`` apply to every stage; ``stage1_options`` and ``stage2_options`` override
    them per stage (2S). ``weights``: a ``Weights`` or the n + 3 cost weights of (7) (default the
    task's), used by both stages. ``model`` (default ``PlanarChain.humanoid()``) and ``foot``
    (default ``FootParams.paper()``) apply to both stages; ``contact`` (default nominal) is the law
    of the dynamic stage, ``contact_stage1`` (default ``ContactParams.relaxed()``) that of the
    pseudo-static stage 1 (a step towards ``contact`` where it cannot seat the start:
    ``relaxed_stage_problem``). ``guess`` is the initial guess of the first stage (``GUESSES``): the
    paper's linear one, or ``"inverse_dynamics"`` (default), the same motion with torques and
    forces that satisfy its dynamics (``transcription.inverse_dynamics_guess``). ``handover``
    (``HANDOVERS``) is how 2S passes from stage 1 to stage 2: ``"direct"`` (the paper's) or
    ``"continuation"`` (default) in the contact law over ``continuation_steps`` steps (module
    docstring). ``stage1_solver`` runs the relaxed-law stages of 2S (default IPOPT; ``"same"`` or
    None: ``solver``). When the body, the foot or the law is given and the task's start posture
    does not keep the foot steady under them, it
    is moved to the nearest posture that does (``posture.find_equilibrium``; a warning says so),
    or a ValueError says none was found. ``progress`` (e.g. ``jaxhumanoid.progress.IterationLine``)
    is called after every solver iteration with (stage name, iteration, objective, primal
    infeasibility). ``foot_margin`` (``model.foot.FootMargin``, default none) keeps the foot that
    far inside the edges of (5) in both stages. ``scaling`` (``ocp.scaling.SCALINGS``): ``"physical"``
    has every backend solve the NLPs in units of O(1) (torques in 10 N m, forces in 100 N, the
    objective in 100), ``"none"`` as posed. Every argument is checked before any work starts."""
    _check_arguments(dict(locals()))  # solve's arguments, before anything else is bound
    task, scheme = get_task(task), parse_scheme(scheme)
    stage1_solver = None if stage1_solver == "same" else stage1_solver
    T = float(T)
    N1 = min(STAGE1_N, int(N)) if N1 is None else int(N1)
    weights = _weights_array(weights, task.n if model is None else model.n)
    foot_margin = ft.check_foot_margin(foot_margin, FootParams.paper() if foot is None else foot)
    task = _seated_task(task, model, contact, foot)
    if not foot_margin.is_zero:
        check_start_margin(task, PlanarChain.humanoid() if model is None else model, foot_margin, contact, foot)
    t0 = time.perf_counter()
    final = build_problem(
        task,
        scheme,
        N=N,
        T=T,
        weights=weights,
        model=model,
        contact=contact,
        foot=foot,
        guess=guess if scheme.stages == 1 else "linear",  # 2S: the dynamic stages start from stage 1's solution
        foot_margin=foot_margin,
    )
    dynamic = {solver, stage1_solver or solver} if handover == "continuation" else {solver}
    if scheme.stages == 2 and "ipopt" in dynamic:  # IPOPT's dynamic stages compile while stage 1 runs
        final.nlp.precompile(final.bounds.x0, final.p)
    setup_final = time.perf_counter() - t0
    stages, warm = [], None
    x0 = final.bounds.x0
    if scheme.stages == 2:
        stage1 = {**STAGE1_DEFAULTS, **(options or {}), **(stage1_options or {})}
        first = stage1_solver or solver
        law1 = ContactParams.relaxed() if contact_stage1 is None else contact_stage1
        relaxed, law_step = relaxed_stage_problem(final, law1, continuation_steps)  # its law: law1 or a step on
        stats1, Z1 = _stage_one(
            task, scheme, first, relaxed, N1, stage1, relaxed.p.contact, guess, verbose, progress, scaling
        )
        stages.append(dataclasses.replace(stats1, law_step=law_step))
        x0, Zf = stage_two_start(Z1, final)
        warm = {"t": np.linspace(0.0, T, N + 1), "q": Zf[:, final.layout.stage_slices()["q"]]}
    stage2 = {**(STAGE2_DEFAULTS if scheme.stages == 2 else {}), **(options or {}), **(stage2_options or {})}
    if scheme.stages == 2 and handover == "continuation":
        later = law_path(relaxed.p.contact, final.p.contact, continuation_steps)[1:]
        path = [relaxed, *(with_law(final, law) for law in later)]
        solvers = (stage1_solver or solver, solver)
        more, x = _continuation_stages(solvers, path, x0, stage2, setup_final, verbose, progress, scaling)
        stages.extend(more)
        return make_solution(final, x, stages, solver, warm_start=warm)
    name = "stage 2 (dynamic)" if scheme.stages == 2 else "single stage"
    res = _run_solver(solver, final, x0, stage2, verbose, _for_stage(progress, name), scaling)
    stages.append(_stage_stats(name, final, [res], setup_final, x0))
    return make_solution(final, res.x, stages, solver, warm_start=warm)


def _run_path(
    solver, problems: list[Problem], x0, options, verbose, progress, label: str, scaling: str
) -> tuple[list[NLPResult], int]:
    """Solve each problem of a law path in turn, each from the last one's solution (the first from
    x0, the later ones with ``CONTINUATION_OPTIONS``). A failed solve is rerun from the same start
    with each of ``DYNAMIC_FALLBACKS`` while it fails, and the path stops at a law that none solves.
    Returns (every run, the number of laws solved)."""
    attempts: list[NLPResult] = []
    x = x0
    for j, problem in enumerate(problems):
        name = label if len(problems) == 1 else f"{label}, law {j + 1}/{len(problems)}"
        opts = options if j == 0 else {**options, **CONTINUATION_OPTIONS}
        for k, rerun in enumerate(({}, *DYNAMIC_FALLBACKS)):
            run_name = name if k == 0 else f"{name}, rerun {k}"
            run = _run_solver(solver, problem, x, {**opts, **rerun}, verbose, _for_stage(progress, run_name), scaling)
            attempts.append(run)
            if run.success:
                break
        if not attempts[-1].success:
            return attempts, j
        x = attempts[-1].x
    return attempts, len(problems)


def _continuation_stages(solvers, problems: list[Problem], x0, options, setup_time_s, verbose, progress, scaling):
    """The dynamic stages of a continuation hand-over along ``problems``, the final problem under
    each law of the path: the first law (stage 1's) by ``solvers[0]``, then the path to the nominal
    law by ``solvers[1]`` (``_run_path``, reruns included). Returns (stats of both, x); a failed
    solve ends the path, and its stage reports its status with the law it failed at."""
    stats: list[StageStats] = []
    x = x0
    for solver, part, name in (
        (solvers[0], problems[:1], "stage 1 (dynamic, relaxed law)"),
        (solvers[1], problems[1:], "stage 2 (dynamic)"),
    ):
        attempts, solved = _run_path(solver, part, x, options, verbose, progress, name, scaling)
        st = _stage_stats(name, part[-1], attempts, setup_time_s if not stats else 0.0, x)
        if solved < len(part) and len(part) > 1:
            st = dataclasses.replace(st, status=f"{st.status} (law {solved + 1}/{len(part)})", success=False)
        stats.append(st)
        x = attempts[-1].x
        if not st.success:
            break
        options = {**options, **CONTINUATION_OPTIONS}
    return stats, x
