"""Stage 1 of 2S (Sec. III-A.3): the pseudo-static problem (8) on the coarse grid N1 under the
relaxed contact law, and the fallbacks that rerun it when a run fails."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import time
import warnings
from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, Task, with_force_limit
from jaxhumanoid.solvers.result import NLPResult
from jaxhumanoid.strategy.handover import with_law
from jaxhumanoid.strategy.problem import AUTO, BOTH, BOTH_GUESSES, GUESSES, Problem, build_problem, with_guess
from jaxhumanoid.strategy.runner import ADAPTIVE, Runner, stage_stats
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solution import StageStats

# The barrier of stage 1 (docs/decisions.md): over the whole 2S of 40 perturbed problems,
# mu_init = 1e-3 solves all 40 and takes a quarter fewer iterations in all than 1e-2 (39 of 40;
# IPOPT's 0.1 did no better than 1e-2 on stage 1 alone); on the built-in tasks 2S then takes
# less time than 1S with each backend.
STAGE1_DEFAULTS = {"mu_init": 1e-3}
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
# The default guess (``problem.AUTO``) runs stage 1 from the static path first. Most such runs end
# below 6 % of the objective at their start: stage 1 left the path for a smooth motion. Some end at
# a fifth to a third of it, having kept the path's detour (perturbed T3, getting up from supine);
# from there the dynamic stages take thousands of iterations to optima up to 18 times higher. Above
# this fraction, stage 1 runs from the inverse-dynamics guess as well and the lower objective is
# handed over, as ``BOTH`` does (docs/decisions.md).
STAGE1_PATH_KEPT = 0.1
STAGE1_NAME = "stage 1 (pseudo-static)"


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


STAGE1_FALLBACKS: tuple[Fallback, ...] = (
    Fallback({}, None, True),
    Fallback(ADAPTIVE, None, False),
    Fallback(ADAPTIVE, None, True),
    Fallback({}, 1, False),
    Fallback({}, 1, True),
    Fallback(ADAPTIVE, 1, False),
    Fallback(ADAPTIVE, 1, True),
    Fallback({}, None, False, lift_force_limit=True),
    Fallback({}, None, True, lift_force_limit=True),
    Fallback({}, None, False, lift_force_limit=True, strength=2.0),
    Fallback({}, None, True, lift_force_limit=True, strength=2.0),
)


def stage_one_options(options: Mapping[str, Any] | None, settings: SolveSettings) -> dict:
    """The solver options of stage 1: ``STAGE1_DEFAULTS``, then ``solve``'s ``options``, then
    ``settings.stage1_options``."""
    return {**STAGE1_DEFAULTS, **(options or {}), **(settings.stage1_options or {})}


def restart_point(problem: Problem, seed: int | None) -> np.ndarray:
    """The problem's initial guess (n,), or with ``seed`` every entry moved by
    ``STAGE1_RESTART_SIGMA`` times a standard normal draw of that seed (clipped to the bounds)."""
    b = problem.bounds
    if seed is None:
        return b.x0
    noise = np.random.default_rng(seed).standard_normal(b.x0.size)
    return np.clip(b.x0 + STAGE1_RESTART_SIGMA * noise, b.xl, b.xu)


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


@dataclasses.dataclass(frozen=True)
class _Runs:
    """The runs of stage 1 from one guess: the problem of its first run, every run in order, and
    the fallback that produced the last one (``Fallback({})``: the first run)."""

    guess: str
    first: Problem
    attempts: tuple[NLPResult, ...]
    last: Fallback

    @property
    def result(self) -> NLPResult:
        return self.attempts[-1]


def _runs_from(first: Problem, guess: str, relaxed: Problem, N1: int, opts: dict, runner: Runner, name: str) -> _Runs:
    """Stage 1 from ``first`` (its problem from ``guess``), then ``STAGE1_FALLBACKS`` in turn while
    a run fails; runs are reported as ``name``."""
    task, scheme, law = relaxed.task, relaxed.scheme, relaxed.p.contact
    starts = {(False, 1.0, False): first}  # (lift_force_limit, strength, other_guess) -> the problem a run starts

    def start(lift: bool, strength: float, other: bool) -> Problem:
        if (lift, strength, other) not in starts:
            if other:
                base = start(lift, strength, False)
                starts[lift, strength, other] = with_guess(base, next(g for g in GUESSES if g != guess))
            else:
                posed = with_force_limit(task, NO_FORCE_LIMIT) if lift else task
                problem = stage_one_problem(posed, scheme, relaxed, N1, law, guess, STAGE1_STRENGTH * strength)
                starts[lift, strength, other] = problem
        return starts[lift, strength, other]

    attempts = [runner.run(first, first.bounds.x0, opts, name)]
    last = Fallback({})
    for fb in STAGE1_FALLBACKS:
        if attempts[-1].success:
            break
        relaxations = fb.relaxations(task)
        if fb.lift_force_limit and not relaxations:
            continue  # the task has no limit: the same problem as an earlier run
        problem = start(fb.lift_force_limit, fb.strength, False)
        label = f"{name}, attempt {len(attempts) + 1}" + (" with " + ", ".join(relaxations) if relaxations else "")
        x0 = restart_point(start(fb.lift_force_limit, fb.strength, fb.other_guess), fb.seed)
        attempts.append(runner.run(problem, x0, {**opts, **fb.options}, label))
        last = fb
    return _Runs(guess, first, tuple(attempts), last)


def _better(a: _Runs, b: _Runs) -> _Runs:
    """The runs whose last one hands over: the successful one, else the lower objective (``a`` on
    a tie)."""
    ka = (not a.result.success, float(a.result.objective))
    kb = (not b.result.success, float(b.result.objective))
    return b if kb < ka else a


def start_objective(problem: Problem) -> float:
    """The objective of ``problem`` at its initial guess."""
    return float(problem.nlp.jitted().f(problem.bounds.x0, problem.p))


def path_kept(runs: _Runs) -> bool:
    """Whether stage 1 from the static path kept its detour (``STAGE1_PATH_KEPT``), or failed."""
    res = runs.result
    return not res.success or float(res.objective) > STAGE1_PATH_KEPT * start_objective(runs.first)


def stage_one(
    relaxed: Problem, settings: SolveSettings, options: Mapping[str, Any] | None, runner: Runner
) -> tuple[StageStats, np.ndarray]:
    """Stage 1 of 2S for ``relaxed``, the final problem as the relaxed-law stages pose it
    (``handover.relaxed_stage_problem``): ``stage_one_problem`` on ``settings.N1`` intervals under
    ``relaxed``'s law from ``settings.guess``, run by ``runner`` with ``stage_one_options``, then
    ``STAGE1_FALLBACKS`` in turn while a run fails. With ``settings.guess == "both"`` this runs
    from each of ``BOTH_GUESSES`` (the second skipped where its start is the first's, as where no
    static path is found) and hands over the solution of lower objective, the successful one where
    one fails: the two guesses end in different stage-1 optima, and over perturbed problems the
    lower one leads the dynamic stages to lower optima more often than to higher ones
    (docs/results.md). With ``"auto"`` it runs from the static path, and from the inverse-dynamics
    guess as well only where the first runs kept the path (``path_kept``); the lower objective is
    handed over as with ``"both"``. A success that needed relaxed bounds is announced by a warning.
    Returns (stats of every run, of every guess, with the handed-over run's status and objective;
    Z1 (N1 + 1, s) of that run)."""
    task, N1 = relaxed.task, settings.stage1_grid(relaxed.layout.N)
    guesses = {BOTH: BOTH_GUESSES, AUTO: BOTH_GUESSES[::-1]}.get(settings.guess, (settings.guess,))
    opts = stage_one_options(options, settings)
    t0 = time.perf_counter()
    first = stage_one_problem(task, relaxed.scheme, relaxed, N1, relaxed.p.contact, guesses[0])
    setup = time.perf_counter() - t0
    auto = settings.guess == AUTO
    with concurrent.futures.ThreadPoolExecutor(1) as pool:
        # "both": the other guess is made in a background thread while the first one's runs solve
        # (the static path compiles its own programs and runs its sweeps, which would otherwise
        # wait); "auto": only where the first runs kept the path, and then at once (the static path
        # has evaluated the same inverse dynamics already)
        ahead = {} if auto else {g: pool.submit(with_guess, first, g) for g in guesses[1:]}
        runs = [_runs_from(first, guesses[0], relaxed, N1, opts, runner, STAGE1_NAME)]
        t0 = time.perf_counter()
        wanted = guesses[1:] if not auto or path_kept(runs[0]) else ()
        others_made = [(g, ahead[g].result() if g in ahead else with_guess(first, g)) for g in wanted]
        setup += time.perf_counter() - t0  # the wait for them, where the first runs were quicker
    for guess, other in others_made:
        if not np.array_equal(other.bounds.x0, first.bounds.x0):
            name = f"{STAGE1_NAME} from the {guess.replace('_', ' ')} guess"
            runs.append(_runs_from(other, guess, relaxed, N1, opts, runner, name))
    chosen = functools.reduce(_better, runs)
    every = [a for r in runs for a in r.attempts]
    stats = stage_stats(STAGE1_NAME, chosen.first, every, setup, chosen.first.bounds.x0)
    res = chosen.result
    stats = dataclasses.replace(
        stats,
        status=res.status,
        success=bool(res.success),
        objective=float(res.objective),
        max_constraint_violation=float(res.max_constraint_violation),
        guess=chosen.guess,
    )
    relaxations = chosen.last.relaxations(task)
    if res.success and relaxations:
        stats = dataclasses.replace(
            stats, force_limit_lifted=chosen.last.lifts_limit(task), strength_factor=chosen.last.strength
        )
        warnings.warn(
            f"task {task.key}: stage 1 failed under its bounds and was solved with "
            f"{', '.join(relaxations)}; the dynamic stages keep the task's bounds",
            stacklevel=3,
        )
    return stats, chosen.first.full(res.x)
