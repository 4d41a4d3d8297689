"""One NLP instance: task + scheme + grid -> (NLP, bounds, parameters, layout)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from jaxhumanoid.derivatives.stagewise import stagewise_nlp
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import tasks as tasks_mod
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.nlp import NLP, Bounds
from jaxhumanoid.ocp.scheme import Scheme, parse_scheme


@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    task: tasks_mod.Task
    scheme: Scheme
    layout: tr.Layout
    nlp: NLP
    bounds: Bounds
    p: tr.OCPParams

    def full(self, x) -> np.ndarray:
        """The (N+1, s) full layout of an NLP vector."""
        return np.asarray(tr.full_from_free(self.layout, x, self.p))


@functools.lru_cache(maxsize=64)
def _cached_nlp(layout: tr.Layout) -> NLP:
    # Patterns depend on the layout only; detect them at a representative parameter set.
    return stagewise_nlp(layout, tr.default_params("T1"), name=f"N={layout.N}")


def build_problem(
    task="T1",
    scheme="A,F+C,1S",
    N: int = 100,
    T: float = 5.0,
    pseudo_static: bool = False,
    contact: ContactParams | None = None,
    weights=None,
    q_start=None,
) -> Problem:
    """The NLP (7) of one task under one scheme on an N-interval grid (one stage of a strategy).

    ``pseudo_static`` selects model (8) instead of (6b); ``contact`` defaults to the nominal law;
    ``q_start`` overrides the task's start posture (used by the 2S stage 1 re-seating).
    """
    task = tasks_mod.get_task(task)
    scheme = parse_scheme(scheme)
    if not isinstance(N, (int, np.integer)) or N < 3:
        raise ValueError(f"N: expected an integer number of intervals >= 3, got {N!r}")
    if not np.isfinite(T) or T <= 0:
        raise ValueError(f"T: expected a positive horizon in seconds, got {T!r}")
    layout = tr.Layout(int(N), scheme.active_set(task.active), scheme.augmented, scheme.clearance, bool(pseudo_static))
    p = tr.default_params(task, contact=contact, T=T, weights=weights)
    if q_start is not None:
        p = dataclasses.replace(p, q_start=np.asarray(q_start, dtype=float))
    nlp = _cached_nlp(layout)
    lo, hi = tr.bounds_full(layout, task.goal)
    free = layout.free_mask()
    kinds = np.tile(layout.constraint_kinds(), layout.N)
    Z0 = tr.initial_guess_full(layout, np.asarray(p.q_start), task.goal, T)
    x0 = Z0[free]
    xl, xu = lo[free], hi[free]
    bounds = Bounds(
        x0=np.clip(x0, xl, xu),
        xl=xl,
        xu=xu,
        gl=np.zeros(nlp.m),
        gu=np.where(kinds == 0, 0.0, np.inf),
    )
    return Problem(task, scheme, layout, nlp, bounds, p)


def stage_problem(task, scheme, N: int, pseudo_static: bool) -> Problem:
    """The NLP of one stage: the dynamic problem (6) with the nominal contact law, or the
    pseudo-static problem (8) of stage 1 with the relaxed law (``ContactParams.relaxed``)."""
    contact = ContactParams.relaxed() if pseudo_static else None
    return build_problem(task, scheme, N=N, pseudo_static=pseudo_static, contact=contact)
