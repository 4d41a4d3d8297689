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


def unscaled(res: NLPResult, s, max_constraint_violation: float) -> NLPResult:
    """``res`` of the scaled problem of ``ocp.scaling`` (factors ``s``: obj, x, g) in the original
    variables: x = x~ / Dx, lam = Dg lam~ / sf, z = Dx z~ / sf, f = f~ / sf;
    ``max_constraint_violation`` is the original problem's at x (the caller evaluates g there)."""
    sx, sg, sf = np.asarray(s.x), np.asarray(s.g), float(s.obj)
    history = dict(res.history or {})
    if "objective" in history:
        history["objective"] = np.asarray(history["objective"]) / sf
    return dataclasses.replace(
        res,
        x=np.asarray(res.x) / sx,
        lam_g=sg * np.asarray(res.lam_g) / sf,
        z_l=sx * np.asarray(res.z_l) / sf,
        z_u=sx * np.asarray(res.z_u) / sf,
        objective=float(res.objective) / sf,
        max_constraint_violation=float(max_constraint_violation),
        history=history if res.history is not None else None,
    )


def unscaled_progress(progress: IterationCallback | None, sf: float) -> IterationCallback | None:
    """``progress`` fed by a solver of the scaled problem: the objective back in its own units
    (the infeasibility stays in the solver's, the scaled rows')."""
    if progress is None:
        return None
    return lambda it, obj, inf: progress(it, obj / sf, inf)
