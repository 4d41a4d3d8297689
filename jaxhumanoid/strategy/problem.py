"""One NLP instance: task + scheme + grid + body -> (NLP, bounds, parameters, layout)."""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives.stagewise import DEFAULT_SWEEPS, stagewise_nlp
from jaxhumanoid.model.foot import FootMargin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import static_path
from jaxhumanoid.ocp import tasks as tasks_mod
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.nlp import NLP, Bounds
from jaxhumanoid.ocp.scheme import Scheme, parse_scheme

GUESSES = ("linear", "inverse_dynamics", "static_path")
# The default guess of an NLP posed on its own: with u and f from the inverse dynamics, stage 1 and
# coarse 1S solves of the strength-limited tasks converge where the linear guess ends infeasible
# (docs/results.md).
DEFAULT_GUESS = "inverse_dynamics"
# What a strategy's first stage may start from (``stage_one.stage_one``): one of ``GUESSES``;
# ``BOTH``, stage 1 of 2S run from each of ``BOTH_GUESSES`` and the solution of lower objective
# handed over; ``AUTO`` (the strategy's default), stage 1 from the static path, and from the
# inverse-dynamics guess as well only where that run kept the path's detour. An NLP posed on its
# own (1S) takes the first of ``BOTH_GUESSES``.
BOTH = "both"
AUTO = "auto"
BOTH_GUESSES = ("inverse_dynamics", "static_path")
STRATEGY_GUESSES = (*GUESSES, BOTH, AUTO)
DEFAULT_STRATEGY_GUESS = AUTO


def nlp_guess(guess: str) -> str:
    """The initial guess (``GUESSES``) of an NLP posed on its own for a strategy's ``guess``
    (``STRATEGY_GUESSES``)."""
    return BOTH_GUESSES[0] if guess in (BOTH, AUTO) else guess


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    task: tasks_mod.Task
    scheme: Scheme
    layout: tr.Layout
    nlp: NLP
    bounds: Bounds
    p: tr.OCPParams

    @property
    def model(self) -> PlanarChain:
        """The body the problem moves."""
        return self.p.model

    def joint_ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """(q_min, q_max), (n,) each: the joint ranges in the bounds (the task's, else the body's)."""
        return self.task.joint_ranges(self.model)

    def full(self, x) -> np.ndarray:
        """The (N+1, s) full layout of an NLP vector."""
        return np.asarray(tr.full_from_free(self.layout, x, self.p))


def pattern_params(n_links: int) -> tr.OCPParams:
    """Parameters at which the sparsity patterns of an ``n_links`` transcription are detected.

    The patterns depend on the layout only, and the NLP of a layout serves every body with that
    many links, so they are detected for a chain with distinct, generic values: no derivative entry
    vanishes through a coincidence of numbers (a COM exactly at a joint, a zero weight).
    """
    i = np.arange(n_links)
    a = 0.5 - 0.03 * i
    m = 10.0 + 3.0 * i
    model = PlanarChain(a=a, c=0.4 * a, m=m, inertia=m * a**2 / 12.0)
    return tr.OCPParams(
        model=model,
        foot=FootParams.paper(),
        contact=ContactParams.nominal(),
        weights=jnp.asarray(np.linspace(1.0, 2.0, n_links + 3)),
        T=jnp.asarray(5.0),
        q_start=jnp.zeros(n_links),
    )


@functools.lru_cache(maxsize=64)
def _cached_nlp(layout: tr.Layout, sweeps: str) -> NLP:
    return stagewise_nlp(layout, pattern_params(layout.n_links), name=f"N={layout.N}", sweeps=sweeps)


def clear_nlp_cache() -> None:
    """Forget the NLPs built so far (and the compiled programs they own), and the static-path
    guess's compiled rows."""
    _cached_nlp.cache_clear()
    static_path._compiled.cache_clear()


def build_problem(
    task="T1",
    scheme="A,F+C,1S",
    N: int = 100,
    T: float = 5.0,
    pseudo_static: bool = False,
    contact: ContactParams | None = None,
    weights=None,
    q_start=None,
    model: PlanarChain | None = None,
    foot: FootParams | None = None,
    guess: str = DEFAULT_GUESS,
    foot_margin: FootMargin | None = None,
) -> Problem:
    """The NLP (7) of one task under one scheme on an N-interval grid (one stage of a strategy).

    ``pseudo_static`` selects model (8) instead of (6b); ``contact`` defaults to the nominal law;
    ``model`` (the body, default ``PlanarChain.humanoid()``) must have as many links as the task has
    joints; ``foot`` defaults to ``FootParams.paper()``; ``q_start`` overrides the task's start
    posture (used by the 2S stage 1 re-seating). ``guess`` is the initial guess (``GUESSES``):
    ``"linear"``, Sec. II-G's q linear from start to goal with u and f zero; ``"inverse_dynamics"``
    (default), the same motion with u and f that satisfy its dynamics and force rows
    (``transcription.inverse_dynamics_guess``); ``"static_path"``, that motion's postures moved to
    ones the body can hold at rest (``ocp.static_path``), else the inverse-dynamics guess.
    ``foot_margin`` tightens the steady-foot rows (5) (``model.foot.FootMargin``; default none).
    """
    task = tasks_mod.get_task(task)
    scheme = parse_scheme(scheme)
    if guess not in GUESSES:
        raise ValueError(f"guess: {guess!r} not in {GUESSES}")
    if not isinstance(N, (int, np.integer)) or N < 3:
        raise ValueError(f"N: expected an integer number of intervals >= 3, got {N!r}")
    if not np.isfinite(T) or T <= 0:
        raise ValueError(f"T: expected a positive horizon in seconds, got {T!r}")
    p = tr.default_params(task, contact=contact, T=T, weights=weights, model=model, foot=foot, foot_margin=foot_margin)
    n = p.model.n
    layout = tr.Layout(
        N=int(N),
        active=scheme.active_set(task.active, n),
        augmented=scheme.augmented,
        clearance=scheme.clearance,
        pseudo_static=bool(pseudo_static),
        n_links=n,
        force_rows=task.contact_force_limit is not None and not scheme.augmented,
    )
    if q_start is not None:
        q_start = np.asarray(q_start, dtype=float)
        if q_start.shape != (n,):
            raise ValueError(f"q_start: expected shape ({n},), got {q_start.shape}")
        p = dataclasses.replace(p, q_start=q_start)
    nlp = _cached_nlp(layout, DEFAULT_SWEEPS)
    lo, hi = _bounds_full(task, layout, p)
    free = layout.free_mask()
    kinds = np.tile(layout.constraint_kinds(), layout.N)
    xl, xu = lo[free], hi[free]
    bounds = Bounds(
        x0=np.clip(initial_guess(layout, p, task, guess, (lo, hi)), xl, xu),
        xl=xl,
        xu=xu,
        gl=np.where(kinds == 2, -np.inf, 0.0),
        gu=np.select([kinds == 0, kinds == 2], [0.0, task.force_box(p.model)], np.inf),
    )
    return Problem(task, scheme, layout, nlp, bounds, p)


def _bounds_full(task: tasks_mod.Task, layout: tr.Layout, p: tr.OCPParams):
    """The task's bounds in the full layout (``transcription.bounds_full``) for the body of p."""
    q_min, q_max = task.joint_ranges(p.model)
    return tr.bounds_full(
        layout, task.goal, q_min, q_max, np.asarray(p.model.u_max), task.goal_tolerance, task.force_box(p.model)
    )


def initial_guess(layout: tr.Layout, p: tr.OCPParams, task: tasks_mod.Task, guess: str, bounds_full) -> np.ndarray:
    """The NLP vector of ``guess`` (``GUESSES``) from p's start posture to the task's goal over p.T,
    before clipping to the bounds; ``bounds_full``: the (lo, hi) of ``_bounds_full``, which the
    static path keeps to."""
    Z0 = tr.initial_guess_full(layout, np.asarray(p.q_start), np.asarray(task.goal), float(p.T))
    if guess == "inverse_dynamics":
        Z0 = np.asarray(tr.inverse_dynamics_guess(layout, Z0, p))
    elif guess == "static_path":
        lo, hi = bounds_full
        Z0 = static_path.static_path_guess(layout, Z0, p, lo, hi, task.force_box(p.model))[0]
    return np.asarray(Z0)[layout.free_mask()]


def with_guess(problem: Problem, guess: str) -> Problem:
    """``problem`` started from another initial guess (``GUESSES``); the NLP is the same."""
    full = _bounds_full(problem.task, problem.layout, problem.p)
    x0 = np.clip(
        initial_guess(problem.layout, problem.p, problem.task, guess, full), problem.bounds.xl, problem.bounds.xu
    )
    return dataclasses.replace(problem, bounds=dataclasses.replace(problem.bounds, x0=x0))


def with_sweeps(problem: Problem, sweeps: str) -> Problem:
    """``problem`` with its derivatives swept as ``sweeps`` says (``derivatives.stagewise.SWEEPS``:
    ``"grouped"``, the default, or ``"joint"``, the same values to round-off in more operations);
    ``stagewise_nlp`` rejects other names before any work."""
    return dataclasses.replace(problem, nlp=_cached_nlp(problem.layout, sweeps))


def stage_problem(
    task, scheme, N: int, pseudo_static: bool, model: PlanarChain | None = None, foot: FootParams | None = None
) -> Problem:
    """The NLP of one stage: the dynamic problem (6) with the nominal contact law, or the
    pseudo-static problem (8) of stage 1 with the relaxed law (``ContactParams.relaxed``)."""
    contact = ContactParams.relaxed() if pseudo_static else None
    return build_problem(task, scheme, N=N, pseudo_static=pseudo_static, contact=contact, model=model, foot=foot)


def problem_from_settings(kwargs: dict, scheme: str, N: int) -> Problem:
    """The problem of a task's ``solve`` keyword arguments (a task file's ``as_solve_kwargs``, a
    study case's) on ``scheme`` and ``N`` intervals: their task, body, laws, weights, horizon, and
    their ``settings``' initial guess (``nlp_guess``) and foot margin (the solver settings are not part of the
    problem)."""
    settings = kwargs.get("settings")  # a SolveSettings or None (the defaults)
    return build_problem(
        kwargs["task"],
        scheme,
        N=N,
        T=float(kwargs.get("T") or 5.0),
        model=kwargs.get("model"),
        foot=kwargs.get("foot"),
        contact=kwargs.get("contact"),
        weights=kwargs.get("weights"),
        guess=DEFAULT_GUESS if settings is None else nlp_guess(settings.guess),
        foot_margin=None if settings is None else settings.foot_margin,
    )
