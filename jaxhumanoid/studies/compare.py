"""Do the solvers reach the same optimum? Pairwise agreement of the solves of one problem.

``agreement`` compares outcomes (success, objective, trajectory q) of several solvers on one
problem; ``problem_agreement`` applies it to the rows of a sweep whose cases solve the same
perturbed problem (the same ``problem`` id) with different solvers, reading each trajectory
from its saved ``solution.npz``.
"""

from __future__ import annotations

import itertools
import pathlib
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

import numpy as np

OBJ_RTOL = 1e-6
Q_ATOL = 1e-4  # rad


class Outcome(NamedTuple):
    """What the comparison of solvers needs from one solve: success, objective, q (N+1, n) or None."""

    success: bool
    objective: float
    q: np.ndarray | None


def agreement(outcomes: Mapping[str, Outcome], obj_rtol: float = OBJ_RTOL, q_atol: float = Q_ATOL) -> dict[str, Any]:
    """Pairwise comparison of the solvers on one problem: relative objective difference
    |J_a - J_b| / max(|J_a|, |J_b|) and max |q_a - q_b| (rad) per pair. ``agrees``: every solver
    succeeded and every pair is within both thresholds (with one solver: it succeeded)."""
    pairs = []
    agrees = all(o.success for o in outcomes.values())
    for (a, oa), (b, ob) in itertools.combinations(outcomes.items(), 2):
        if oa.q is None or ob.q is None or np.shape(oa.q) != np.shape(ob.q):
            rel, dq = None, None
        else:
            scale = max(abs(oa.objective), abs(ob.objective), 1e-300)
            rel = float(abs(oa.objective - ob.objective) / scale)
            dq = float(np.max(np.abs(oa.q - ob.q)))
        within = rel is not None and dq is not None and bool(rel <= obj_rtol and dq <= q_atol)
        agrees = agrees and within
        pairs.append({"a": a, "b": b, "rel_objective": rel, "max_dq": dq, "within": within})
    return {"pairs": pairs, "agrees": bool(agrees), "obj_rtol": obj_rtol, "q_atol": q_atol}


def outcome_of(row: Mapping[str, Any]) -> Outcome:
    """A sweep row's outcome; q from ``path/solution.npz`` when the case saved its solution."""
    path = pathlib.Path(str(row.get("path") or "")) / "solution.npz"
    q = np.load(path)["q"] if row.get("path") and path.is_file() else None
    objective = row.get("objective")
    return Outcome(bool(row.get("success")), float(objective) if objective is not None else float("nan"), q)


def problem_agreement(
    rows: Iterable[Mapping[str, Any]], obj_rtol: float = OBJ_RTOL, q_atol: float = Q_ATOL
) -> dict[str, Any]:
    """Per task: the problems solved by more than one solver, how many of them every solver solved
    to the same optimum (``agreement``), and per pair of solvers ("a-b") how many both solved to
    the same optimum, which tells the solver that parts from the others."""
    problems: dict[str, dict[str, Mapping[str, Any]]] = {}
    for r in rows:
        problems.setdefault(str(r["problem"]), {})[str(r["solver"])] = r
    out: dict[str, Any] = {}
    for solves in problems.values():
        if len(solves) < 2:
            continue
        task = str(next(iter(solves.values()))["task"])
        outcomes = {s: outcome_of(r) for s, r in solves.items()}
        result = agreement(outcomes, obj_rtol, q_atol)
        entry = out.setdefault(task, {"problems": 0, "agree": 0, "pairs": {}})
        entry["problems"] += 1
        entry["agree"] += int(result["agrees"])
        for pair in result["pairs"]:
            both = outcomes[pair["a"]].success and outcomes[pair["b"]].success
            counts = entry["pairs"].setdefault(f"{pair['a']}-{pair['b']}", {"problems": 0, "agree": 0})
            counts["problems"] += 1
            counts["agree"] += int(both and pair["within"])
    for entry in out.values():
        entry["agree_fraction"] = entry["agree"] / entry["problems"]
    return out
