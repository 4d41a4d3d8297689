"""The default tasks solved by every backend, side by side in one run: one answer to one problem?

    python scripts/compare_solvers.py [--tasks T1 T2 T3 T4 | examples/paper/T1.toml ...] [--solvers ipopt ipm casadi] [--N 100]
        [--scheme A,F+C,2S] [--guess G] [--handover direct|continuation] [--stage1-solver ipopt|ipm|casadi|same]
        [--out results/compare_solvers.json] [--md results/compare_solvers.md]

A task is a key or a task file (solved with the file's scheme, grid and options);
``--guess``, ``--handover`` and ``--stage1-solver`` override the task file's or the default. Per task and solver: the status, iterations, solve time and objective of each stage, the peak
loads (``Solution.peaks``) and the four objective terms; per task and pair of solvers: the
relative objective difference and the largest joint-angle difference (rad) over the trajectory
(``jaxhumanoid.studies.compare.agreement``: the same optimum when objectives are within ``--obj-tol``
relative and joint trajectories within ``--q-tol`` rad); the ratio of the IPM's 2S solve time to the CasADi backend's,
over all stages and over stage 2 alone (the stages each backend runs itself when the relaxed-law
stages run on IPOPT).
Run it with and without ``OMP_NUM_THREADS=1``: the environment is recorded with the results.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import json
import os
import pathlib
import platform
import time

import numpy as np

import jaxhumanoid as jh
from jaxhumanoid.strategy.taskfile import solve_kwargs
from jaxhumanoid.studies.bench import show_table
from jaxhumanoid.studies.compare import Outcome, agreement


def run_one(task: str, solver: str, scheme: str, N: int, overrides: dict) -> tuple[dict, Outcome]:
    """One solve of a task key (scheme and N as given) or of a task file (its own settings), with
    ``overrides`` of its ``SolveSettings``."""
    t0 = time.perf_counter()
    grid = {} if task.endswith(".toml") else {"scheme": scheme, "N": N}
    kw = solve_kwargs(task)
    settings = (kw.pop("settings", None) or jh.SolveSettings()).replace(**overrides)
    sol = jh.solve(**{**kw, **grid, "settings": settings, "solver": solver})
    rec = sol.report()
    rec["wall_s"] = time.perf_counter() - t0
    return rec, Outcome(bool(sol.success), float(sol.objective), np.asarray(sol.q))


def _stage2_time(rec: dict) -> float:
    """Solve time of the stage-2 solves: those the backend runs itself under the default
    ``stage1_solver`` (the relaxed-law stages, named "stage 1 ...", run on IPOPT)."""
    return sum(s["solve_time_s"] for s in rec["stages"] if s["name"].startswith("stage 2"))


def ratios(results: dict) -> str:
    """One line per task: the IPM's solve time over the CasADi backend's, all stages and stage 2."""
    return "\n".join(
        f"- {task}: IPM / CasADi solve time {r['ipm_over_casadi_solve_time']:.2f} (all stages), "
        f"{r['ipm_over_casadi_stage2_time']:.2f} (stage 2)"
        for task, r in results["tasks"].items()
        if "ipm_over_casadi_stage2_time" in r
    )


def table(results: dict) -> str:
    solvers = results["solvers"]
    head = "| task | " + " | ".join(f"{s}: iterations, solve s, objective" for s in solvers) + " | same optimum |"
    lines = [head, "|" + "---|" * (len(solvers) + 2)]
    for task, r in results["tasks"].items():
        cells = []
        for s in solvers:
            rec = r["solves"][s]
            its = "+".join(str(i) for i in rec["iterations"])
            failed = [st["status"] for st in rec["stages"] if not st["success"]]
            ok = f" **{failed[0]}**" if failed else ""
            cells.append(f"{its}, {sum(rec['solve_time_s']):.1f}, {rec['objective']:.6g}{ok}")
        pairs = ", ".join(
            f"{p['a']}-{p['b']}: {'yes' if p['within'] else 'no'} ({p['rel_objective']:.0e}, {p['max_dq']:.0e} rad)"
            for p in r["agreement"]["pairs"]
        )
        lines.append(f"| {task} | " + " | ".join(cells) + f" | {pairs} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--solvers", nargs="*", default=["ipopt", "ipm", "casadi"])
    ap.add_argument("--scheme", default="A,F+C,2S")
    ap.add_argument("--N", type=int, default=100)
    ap.add_argument("--guess", choices=["inverse_dynamics", "linear"], default=None)
    ap.add_argument("--handover", choices=["direct", "continuation"], default=None)
    ap.add_argument(
        "--stage1-solver", choices=["ipopt", "ipm", "casadi", "same"], default=None, help="same: each solver"
    )
    ap.add_argument("--obj-tol", type=float, default=1e-6)
    ap.add_argument("--q-tol", type=float, default=1e-4)
    ap.add_argument("--out", default="results/compare_solvers.json")
    ap.add_argument("--md", default=None)
    args = ap.parse_args()
    chosen = (("guess", args.guess), ("handover", args.handover), ("stage1_solver", args.stage1_solver))
    overrides = {k: v for k, v in chosen if v}
    results: dict = {
        "scheme": args.scheme,
        "N": args.N,
        "solvers": args.solvers,
        "overrides": overrides,
        "environment": {"OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"), "machine": platform.machine()},
        "tasks": {},
    }
    for task in args.tasks:
        solves = {s: run_one(task, s, args.scheme, args.N, overrides) for s in args.solvers}
        agree = agreement({s: out for s, (_, out) in solves.items()}, args.obj_tol, args.q_tol)
        entry: dict = {"solves": {s: rec for s, (rec, _) in solves.items()}, "agreement": agree}
        if "ipm" in solves and "casadi" in solves:
            ipm, cas = solves["ipm"][0], solves["casadi"][0]
            entry["ipm_over_casadi_solve_time"] = sum(ipm["solve_time_s"]) / sum(cas["solve_time_s"])
            entry["ipm_over_casadi_stage2_time"] = _stage2_time(ipm) / _stage2_time(cas)
        results["tasks"][task] = entry
        print(f"{task}: all solvers at one optimum: {agree['agrees']}", flush=True)
        out = pathlib.Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(results, indent=2) + "\n")
    show_table(table(results) + "\n\n" + ratios(results), args.md)


if __name__ == "__main__":
    main()
