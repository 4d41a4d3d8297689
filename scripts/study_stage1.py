"""Study: how chaotic is stage 1 of 2S? The same stage-1 NLP from nearby starting points.

    python scripts/study_stage1.py [--tasks T1 T3] [--starts 6] [--sigma 1e-4] [--solvers ipopt ipm]
        [--out results/study_stage1.json]

Stage 1 of A,F+C,2S (the pseudo-static problem (8) on N1 = 30 intervals under the relaxed law,
from the start posture re-seated for it, exactly as ``solve`` builds it) is solved from the
linear initial guess and from ``--starts - 1`` copies of it with every entry moved by
``--sigma`` times a standard normal draw, under the monotone and the adaptive barrier update.
If the problem had one basin reachable from the guess, every run would end at one objective;
the table shows how many distinct optima (objectives more than 1e-6 apart) the runs reach, and
how many runs fail.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np

import jaxhumanoid as jh
from jaxhumanoid.solvers.ipm import solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.problem import Problem, build_problem
from jaxhumanoid.strategy.solve import STAGE1_DEFAULTS, STAGE1_N, stage_one_problem


def stage_one(task: str, N: int = 100) -> Problem:
    """Stage 1 of A,F+C,2S for ``task`` as ``solve`` poses it."""
    final = build_problem(task, "A,F+C,2S", N=N)
    return stage_one_problem(jh.get_task(task), "A,F+C,2S", final, STAGE1_N)


def distinct(values: list[float], rtol: float = 1e-6) -> int:
    """Number of distinct values, two being the same when within ``rtol`` relative."""
    out: list[float] = []
    for v in sorted(values):
        if not out or abs(v - out[-1]) > rtol * max(abs(out[-1]), 1e-300):
            out.append(v)
    return len(out)


def run(task: str, starts: int, sigma: float, solvers: list[str], seed: int) -> dict:
    pb = stage_one(task)
    b = pb.bounds
    rng = np.random.default_rng(seed)
    runs = []
    for i in range(starts):
        x0 = b.x0 if i == 0 else np.clip(b.x0 + sigma * rng.standard_normal(b.x0.size), b.xl, b.xu)
        for solver in solvers:
            for strategy in ("monotone", "adaptive"):
                opts = {**STAGE1_DEFAULTS, "mu_strategy": strategy}
                fn = solve_ipopt if solver == "ipopt" else solve_ipm
                r = fn(pb.nlp, pb.p, b, x0=x0, options=opts)
                runs.append(
                    {
                        "start": i,
                        "solver": solver,
                        "mu_strategy": strategy,
                        "status": r.status,
                        "success": bool(r.success),
                        "iterations": int(r.iterations),
                        "objective": float(r.objective),
                    }
                )
                print(f"{task} start {i} {solver} {strategy}: {r.status} {r.iterations} {r.objective:.6g}", flush=True)
    return {"task": task, "starts": starts, "sigma": sigma, "runs": runs}


def table(results: list[dict]) -> str:
    lines = [
        "| task | solver | mu_strategy | succeeded | distinct optima | objectives of the successes | iterations |",
        "|---|---|---|---|---|---|---|",
    ]
    for res in results:
        keys = sorted({(r["solver"], r["mu_strategy"]) for r in res["runs"]})
        for solver, strategy in keys:
            rs = [r for r in res["runs"] if r["solver"] == solver and r["mu_strategy"] == strategy]
            ok = [r["objective"] for r in rs if r["success"]]
            its = [r["iterations"] for r in rs]
            objs = ", ".join(f"{v:.4g}" for v in sorted(ok)) or "-"
            lines.append(
                f"| {res['task']} | {solver} | {strategy} | {len(ok)}/{len(rs)} | {distinct(ok)} | {objs} | "
                f"{int(np.median(its))} ({min(its)}-{max(its)}) |"
            )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="*", default=["T1", "T3"])
    ap.add_argument("--starts", type=int, default=6)
    ap.add_argument("--sigma", type=float, default=1e-4)
    ap.add_argument("--solvers", nargs="*", default=["ipopt", "ipm"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/study_stage1.json")
    args = ap.parse_args()
    results = [run(t, args.starts, args.sigma, args.solvers, args.seed) for t in args.tasks]
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(table(results))


if __name__ == "__main__":
    main()
