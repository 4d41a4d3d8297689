"""What every NLP solver returns."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

IterationCallback = Callable[[int, float, float], None]
"""What a solver calls after every iteration: (iteration, objective, primal infeasibility)."""


@dataclasses.dataclass
class NLPResult:
    """Outcome of one NLP solve.

    x: primal solution (n,); lam_g: constraint multipliers (m,); z_l, z_u: bound multipliers (n,)
    status: solver's own status text (IPOPT's, e.g. "Solve_Succeeded"); success: converged to the
    requested tolerance (or IPOPT's acceptable level); iterations: iteration count;
    solve_time_s: wall time of the iterations, compilation excluded; compile_time_s: one-off
    tracing/compilation time; objective: f(x); max_constraint_violation: max over g bounds and x
    bounds of the violation at x (unscaled); history: per-iteration records (dict of arrays) when
    the solver keeps them; log: the iteration log text when captured.
    """

    x: np.ndarray
    lam_g: np.ndarray
    z_l: np.ndarray
    z_u: np.ndarray
    status: str
    success: bool
    iterations: int
    solve_time_s: float
    compile_time_s: float
    objective: float
    max_constraint_violation: float
    history: dict[str, Any] | None = None
    log: str | None = None


def constraint_violation(g_val, x, gl, gu, xl, xu) -> float:
    """max(0, gl - g, g - gu, xl - x, x - xu); infinite bounds never count as violated."""
    parts = [
        np.asarray(gl) - np.asarray(g_val),
        np.asarray(g_val) - np.asarray(gu),
        np.asarray(xl) - np.asarray(x),
        np.asarray(x) - np.asarray(xu),
    ]
    worst = 0.0
    for v in parts:
        v = v[np.isfinite(v)]
        if v.size:
            worst = max(worst, float(v.max()))
    return worst
