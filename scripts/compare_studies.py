"""Two solve studies of the same perturbed problems side by side: success, agreement, loads, iterations.

    python scripts/compare_studies.py BASE OTHER [--labels "no limit" "limit 2 M g"] [--draws K]
        [--out results/compare_studies.json] [--md results/compare_studies.md]

BASE and OTHER are sweep folders (``cases.csv``, and each case's ``report.json`` and
``solution.npz`` where the case saved them) of studies whose draws pose the same problems with one
setting changed (the contact-force limit, the guess, N1): a problem is matched by (task, draw),
since the changed setting changes the case ids. Only problems and solvers in both studies count
(``--draws K``: draws < K). Per study: how many problems each solver solved in every stage, on
how many all its solvers reached the same optimum (``studies.compare.agreement``: objectives
within 1e-6 relative, joint trajectories within 1e-4 rad), how many of IPOPT's optima keep every
contact force at most 2 M g (to 1e-6 M g: an optimum pinned at a limit of 2 M g meets it), the
median iterations of each stage and of all stages and the median objective (IPOPT); and, of the
problems IPOPT solved in both, on how many OTHER ends lower, at the same objective or higher.
"""

from __future__ import annotations

import argparse
import json
import pathlib
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from jaxhumanoid.studies.bench import show_table, write_record
from jaxhumanoid.studies.compare import OBJ_RTOL, agreement, outcome_of
from jaxhumanoid.studies.table import latest_rows, read_table

PEAK_M_G = 2.0
PEAK_TOL = 1e-6  # M g: an optimum pinned at a limit of PEAK_M_G meets it to the solver's tolerance


def problems(folder: str, draws: int | None) -> dict[tuple[str, int], dict[str, Mapping[str, Any]]]:
    """(task, draw) -> solver -> the latest row of that case."""
    out: dict[tuple[str, int], dict[str, Mapping[str, Any]]] = {}
    for row in latest_rows(read_table(pathlib.Path(folder) / "cases.csv")).values():
        if row.get("draw") is None or (draws is not None and int(row["draw"]) >= draws):
            continue
        out.setdefault((str(row["task"]), int(row["draw"])), {})[str(row["solver"])] = row
    return out


def stage_iterations(row: Mapping[str, Any]) -> list[tuple[str, int]]:
    """(stage name, iterations) of a case, from its saved report; [] when it saved none."""
    path = pathlib.Path(str(row.get("path") or "")) / "report.json"
    if not row.get("path") or not path.is_file():
        return []
    return [(s["name"], int(s["iterations"])) for s in json.loads(path.read_text())["stages"]]


def study_summary(cases: Mapping[tuple[str, int], Mapping[str, Mapping[str, Any]]]) -> dict[str, Any]:
    """The per-study figures of the module docstring over ``cases``."""
    solvers = sorted({s for solves in cases.values() for s in solves})
    ipopt = [solves["ipopt"] for solves in cases.values() if "ipopt" in solves]
    solved = [r for r in ipopt if r["success"]]
    stages: dict[str, list[int]] = {}
    for r in ipopt:
        for name, its in stage_iterations(r):
            stages.setdefault(name, []).append(its)
    peaks = [float(r["peak_contact_force_body_weights"]) for r in solved]
    return {
        "problems": len(cases),
        "succeeded": {s: sum(bool(v[s]["success"]) for v in cases.values() if s in v) for s in solvers},
        "agree": sum(
            agreement({s: outcome_of(r) for s, r in solves.items()})["agrees"]
            for solves in cases.values()
            if len(solves) == len(solvers) > 1
        ),
        "peak_at_most": sum(p <= PEAK_M_G + PEAK_TOL for p in peaks),
        "peak_max": max(peaks) if peaks else None,
        "stage_iterations_median": {k: float(np.median(v)) for k, v in stages.items()},
        "iterations_median": float(np.median([r["iterations_total"] for r in ipopt])) if ipopt else None,
        "objective_median": float(np.median([r["objective"] for r in solved])) if solved else None,
        "solved_by_ipopt": len(solved),
    }


def versus(base, other) -> dict[str, int]:
    """Of the problems IPOPT solved in both: OTHER lower, the same (``OBJ_RTOL``), higher."""
    counts = {"lower": 0, "same": 0, "higher": 0}
    for key in base.keys() & other.keys():
        a, b = base[key].get("ipopt"), other[key].get("ipopt")
        if not (a and b and a["success"] and b["success"]):
            continue
        ja, jb = float(a["objective"]), float(b["objective"])
        if abs(ja - jb) <= OBJ_RTOL * max(abs(ja), abs(jb)):
            counts["same"] += 1
        else:
            counts["lower" if jb < ja else "higher"] += 1
    return counts


def table(labels: Sequence[str], summaries: Sequence[Mapping[str, Any]], vs: Mapping[str, int]) -> str:
    n = summaries[0]["problems"]
    solvers = list(summaries[0]["succeeded"])
    stage_names = list(summaries[0]["stage_iterations_median"])

    def cell(s, what):
        if what == "succeeded":
            return " / ".join(f"{s['succeeded'].get(v, 0)}/{n}" for v in solvers)
        if what == "agree" and len(solvers) < 2:
            return "-"
        if what == "peak":
            return f"{s['peak_at_most']}/{s['solved_by_ipopt']} (largest {s['peak_max']:.2f} M g)"
        if what == "stages":
            return " + ".join(f"{s['stage_iterations_median'].get(k, float('nan')):g}" for k in stage_names)
        return f"{s[what]:g}"

    rows = [
        (f"every stage succeeded, {' / '.join(solvers)}", "succeeded"),
        (f"{' and '.join(solvers)} at the same optimum", "agree"),
        (f"peak contact force at most {PEAK_M_G:g} M g, of the solved (ipopt)", "peak"),
        (f"iterations per stage, median (ipopt): {' + '.join(stage_names)}", "stages"),
        ("iterations of all stages, median (ipopt)", "iterations_median"),
        ("objective, median (ipopt)", "objective_median"),
    ]
    lines = [f"| {n} problems | {' | '.join(labels)} |", "|---|" + "---|" * len(labels)]
    for title, what in rows:
        lines.append(f"| {title} | " + " | ".join(cell(s, what) for s in summaries) + " |")
    lines.append("")
    lines.append(
        f"{labels[1]} against {labels[0]} (ipopt, both solved): lower on {vs['lower']}, the same objective on {vs['same']}, higher on {vs['higher']}"
    )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base")
    ap.add_argument("other")
    ap.add_argument("--labels", nargs=2, default=["base", "other"])
    ap.add_argument("--draws", type=int, default=None)
    ap.add_argument("--out", default="results/compare_studies.json")
    ap.add_argument("--md", default=None)
    args = ap.parse_args()
    base, other = problems(args.base, args.draws), problems(args.other, args.draws)
    common = base.keys() & other.keys()
    if not common:
        raise SystemExit(f"{args.base}, {args.other}: no (task, draw) in both studies")
    solvers = {s for v in base.values() for s in v} & {s for v in other.values() for s in v}
    base = {k: {s: r for s, r in base[k].items() if s in solvers} for k in common}
    other = {k: {s: r for s, r in other[k].items() if s in solvers} for k in common}
    summaries = [study_summary(base), study_summary(other)]
    vs = versus(base, other)
    write_record(
        {
            "base": args.base,
            "other": args.other,
            "labels": args.labels,
            "draws": args.draws,
            "summaries": dict(zip(args.labels, summaries)),
            "other_vs_base": vs,
        },
        args.out,
    )
    show_table(table(args.labels, summaries, vs), args.md)


if __name__ == "__main__":
    main()
