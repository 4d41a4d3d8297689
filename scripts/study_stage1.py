"""Study: how chaotic is stage 1 of 2S? The same stage-1 NLP from nearby starting points.

    python scripts/study_stage1.py [--tasks T1 T3 | examples/paper/T1.toml ...] [--starts 6] [--sigma 1e-4]
        [--solvers ipopt ipm casadi] [--guesses linear inverse_dynamics] [--mu-strategies monotone adaptive]
        [--out results/study_stage1.json] [--md results/study_stage1.md] [--quiet]

Stage 1 of 2S (the pseudo-static problem (8) on N1 intervals under the relaxed law, from the start
posture re-seated for it, exactly as ``solve`` builds it: ``stage_one_problem``) is solved from each
initial guess (``strategy.problem.GUESSES``) and from ``--starts - 1`` copies of it with every entry
moved by ``--sigma`` times a standard normal draw (seeds 1, 2, ...), by every solver and barrier
update. If the problem had one basin reachable from the guess, every run would end at one
objective; the table shows how many distinct optima (objectives more than 1e-6 relative apart) the
runs reach, how many fail, and which optima more than one solver reaches.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import json
import pathlib

import numpy as np
from _bench import show_table

import jaxhumanoid as jh
from jaxhumanoid.progress import Progress
from jaxhumanoid.strategy.problem import Problem, build_problem
from jaxhumanoid.strategy.solve import STAGE1_DEFAULTS, STAGE1_N, _run_solver, stage_one_problem


def stage_one(task: str, guess: str) -> Problem:
    """Stage 1 of 2S for a task key (A,F+C,2S, N = 100) or a task file (its scheme, grid and body)."""
    if task.endswith(".toml"):
        kw = jh.load_task_file(task).as_solve_kwargs()
    else:
        kw = {"task": task, "scheme": "A,F+C,2S", "N": 100}
    t = jh.get_task(kw["task"])
    final = build_problem(
        t,
        kw["scheme"],
        N=kw["N"],
        T=kw.get("T", 5.0),
        weights=kw.get("weights"),
        model=kw.get("model"),
        foot=kw.get("foot"),
        contact=kw.get("contact"),
    )
    N1 = kw.get("N1") or min(STAGE1_N, kw["N"])
    return stage_one_problem(t, kw["scheme"], final, N1, kw.get("contact_stage1"), guess)


def distinct(values: list[float], rtol: float = 1e-6) -> list[float]:
    """The distinct values, two being the same when within ``rtol`` relative."""
    out: list[float] = []
    for v in sorted(values):
        if not out or abs(v - out[-1]) > rtol * max(abs(out[-1]), 1e-300):
            out.append(v)
    return out


def run(task: str, args, progress: Progress) -> list[dict]:
    runs = []
    for guess in args.guesses:
        pb = stage_one(task, guess)
        b = pb.bounds
        for i in range(args.starts):
            noise = np.random.default_rng(i).standard_normal(b.x0.size)
            x0 = b.x0 if i == 0 else np.clip(b.x0 + args.sigma * noise, b.xl, b.xu)
            for solver in args.solvers:
                for strategy in args.mu_strategies:
                    progress.start(f"{task} {guess} start {i} {solver} {strategy}")
                    r = _run_solver(solver, pb, x0, {**STAGE1_DEFAULTS, "mu_strategy": strategy}, False)
                    runs.append(
                        {
                            "task": task,
                            "guess": guess,
                            "start": i,
                            "solver": solver,
                            "mu_strategy": strategy,
                            "status": r.status,
                            "success": bool(r.success),
                            "iterations": int(r.iterations),
                            "objective": float(r.objective),
                            "solve_time_s": float(r.solve_time_s),
                        }
                    )
                    progress.finish(f"{r.status}, {r.iterations} iterations, objective {r.objective:.6g}")
    return runs


def table(runs: list[dict]) -> str:
    lines = [
        "| task | guess | solver | succeeded | distinct optima | lowest objective (runs reaching it) "
        "| iterations, median (range) |",
        "|---|---|---|---|---|---|---|",
    ]
    keys = dict.fromkeys((r["task"], r["guess"], r["solver"]) for r in runs)
    for task, guess, solver in keys:
        rs = [r for r in runs if (r["task"], r["guess"], r["solver"]) == (task, guess, solver)]
        ok = [r["objective"] for r in rs if r["success"]]
        its = [r["iterations"] for r in rs]
        best = min(ok) if ok else None
        at_best = sum(abs(v - best) <= 1e-6 * abs(best) for v in ok) if ok else 0
        best_text = f"{best:.6g} ({at_best})" if ok else "-"
        lines.append(
            f"| {pathlib.Path(task).stem if task.endswith('.toml') else task} | {guess} | {solver} | "
            f"{len(ok)}/{len(rs)} | {len(distinct(ok))} | {best_text} | {int(np.median(its))} ({min(its)}-{max(its)}) |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="*", default=["T1", "T3"])
    ap.add_argument("--starts", type=int, default=6)
    ap.add_argument("--sigma", type=float, default=1e-4)
    ap.add_argument("--solvers", nargs="*", default=["ipopt", "ipm", "casadi"])
    ap.add_argument("--guesses", nargs="*", default=["linear", "inverse_dynamics"])
    ap.add_argument("--mu-strategies", nargs="*", default=["monotone"])
    ap.add_argument("--out", default="results/study_stage1.json")
    ap.add_argument("--md", default=None)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args()
    n = len(args.tasks) * len(args.guesses) * args.starts * len(args.solvers) * len(args.mu_strategies)
    progress = Progress(n, quiet=args.quiet)
    runs = [r for t in args.tasks for r in run(t, args, progress)]
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"args": vars(args), "runs": runs}, indent=2) + "\n")
    show_table(table(runs), args.md)


if __name__ == "__main__":
    main()
