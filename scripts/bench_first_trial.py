"""Benchmark: the IPM's first inertia trial per iteration, delta_w = 0 (IPOPT's) against the last
iteration's delta_w decreased (``IPMOptions.inertia_first_trial = "last"``), in one run.

    python scripts/bench_first_trial.py [--tasks T1 T2 T3 T4] [--draws 4] [--seed 0]
                                        [--out results/bench_first_trial.json] [--md FILE]

On these non-convex NLPs the plain trial (delta_w = 0) fails on most iterations, so each
iteration factors K about twice. Per task, draw 0 is the task as posed and draws 1.. scale each of
the four cost terms of (7) by a factor log-uniform in [0.5, 2] (seeded). Each problem gives two
NLPs: stage 1 of 2S (pseudo-static (8), N1 = 30, relaxed law, from the initial guess) and the
dynamic stage 2 (N = 100, nominal law) from IPOPT's stage-1 solution, interpolated, as 2S does.
Both are solved by the IPM with each first trial: status, iterations, factorisations, solve time
(compile excluded), objective. The table gives per variant the successes, the medians of
factorisations per iteration and of the solve-time ratio (last / zero, same NLP), and on how many
NLPs both reach the same optimum (objectives within 1e-6 relative). Set OMP_NUM_THREADS=1.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import json
import pathlib

import numpy as np
from _bench import bench_task, write

import jaxhumanoid as jh
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.progress import Progress
from jaxhumanoid.solvers.ipm import solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy import solve as strat
from jaxhumanoid.strategy.problem import Problem, build_problem

VARIANTS = ("zero", "last")
SCHEME = "A,F+C,2S"


def weights_of(task: str, draw: int, seed: int) -> np.ndarray:
    """The task's n + 3 weights of (7); draw > 0: each term's weights scaled log-uniformly in [0.5, 2]."""
    t = jh.get_task(task)
    w = t.weights.as_array(t.n)
    if draw == 0:
        return w
    f = np.exp(np.random.default_rng([seed, draw, sum(map(ord, task))]).uniform(np.log(0.5), np.log(2.0), 4))
    w[: t.n] *= f[0]
    w[t.n :] *= f[1:]
    return w


def nlps(task: str, w: np.ndarray) -> list[tuple[str, Problem, np.ndarray]]:
    """(name, problem, start) of stage 1 and of stage 2 from IPOPT's stage-1 solution."""
    t = bench_task(task)
    final = build_problem(t, SCHEME, N=100, weights=w)
    first = strat.stage_one_problem(t, final.scheme, final, strat.STAGE1_N, guess=strat.DEFAULT_GUESS)
    r1 = solve_ipopt(first.nlp, first.p, first.bounds, options=strat.STAGE1_DEFAULTS)
    Zf = strat.interpolate_full(first.full(r1.x), float(final.p.T), final.layout)
    x2 = np.clip(np.asarray(tr.free_from_full(final.layout, Zf)), final.bounds.xl, final.bounds.xu)
    return [("stage 1", first, first.bounds.x0), ("stage 2", final, x2)]


def record(r) -> dict:
    """What the tables use of one solve's result."""
    return {
        "status": r.status,
        "success": bool(r.success),
        "iterations": int(r.iterations),
        "solve_s": float(r.solve_time_s),
        "objective": float(r.objective),
    }


def run_one(problem: Problem, x0, stage: str, variant: str) -> dict:
    base = strat.STAGE1_DEFAULTS if stage == "stage 1" else strat.STAGE2_DEFAULTS
    r = solve_ipm(problem.nlp, problem.p, problem.bounds, x0=x0, options={**base, "inertia_first_trial": variant})
    n_fact = int(np.sum(r.history["n_fact"])) if r.history else 0
    return {**record(r), "factorisations": n_fact}


def summarise(records: list[dict], variants: tuple[str, str] = VARIANTS) -> dict:
    """Per stage and variant: successes and medians (iterations, factorisations per iteration
    where the records have them, solve time, ms per iteration); the median ratios of the second
    variant over the first on the same NLP, and on how many NLPs both reach the same optimum."""
    a, b = variants
    out: dict = {}
    for stage in ("stage 1", "stage 2"):
        recs = [r for r in records if r["stage"] == stage]
        row: dict = {"nlps": len(recs)}
        for v in variants:
            rs = [r[v] for r in recs]
            row[v] = {
                "succeeded": sum(r["success"] for r in rs),
                "iterations_median": float(np.median([r["iterations"] for r in rs])),
                "solve_s_median": float(np.median([r["solve_s"] for r in rs])),
                "ms_per_iteration_median": float(np.median([1e3 * r["solve_s"] / max(r["iterations"], 1) for r in rs])),
            }
            if all("factorisations" in r for r in rs):
                row[v]["factorisations_per_iteration_median"] = float(
                    np.median([r["factorisations"] / max(r["iterations"], 1) for r in rs])
                )
        both = [r for r in recs if r[a]["success"] and r[b]["success"]]
        row["same_optimum"] = sum(
            abs(r[b]["objective"] - r[a]["objective"]) <= 1e-6 * abs(r[a]["objective"]) for r in both
        )
        row["both_succeeded"] = len(both)
        row[f"time_ratio_{b}_over_{a}_median"] = float(np.median([r[b]["solve_s"] / r[a]["solve_s"] for r in recs]))
        row["time_per_iteration_ratio_median"] = float(
            np.median(
                [
                    (r[b]["solve_s"] / max(r[b]["iterations"], 1)) / (r[a]["solve_s"] / max(r[a]["iterations"], 1))
                    for r in recs
                ]
            )
        )
        out[stage] = row
    return out


def table(summary: dict, variants: tuple[str, str] = VARIANTS, label: str = "first trial") -> str:
    a, b = variants
    fact = all("factorisations_per_iteration_median" in row[v] for row in summary.values() for v in variants)
    head = f"| NLP | {label} | succeeded | iterations (median) | " + ("factorisations / iteration | " if fact else "")
    lines = [head + "solve s (median) | ms / iteration (median) |", "|---" * (6 + fact) + "|"]
    for stage, row in summary.items():
        for v in variants:
            s = row[v]
            f = f"{s['factorisations_per_iteration_median']:.2f} | " if fact else ""
            lines.append(
                f"| {stage} | {v} | {s['succeeded']}/{row['nlps']} | {s['iterations_median']:.0f} | {f}"
                f"{s['solve_s_median']:.2f} | {s['ms_per_iteration_median']:.1f} |"
            )
    lines.append("")
    for stage, row in summary.items():
        lines.append(
            f"- {stage}: same optimum on {row['same_optimum']} of the {row['both_succeeded']} NLPs both solve; "
            f"median time ratio {b} / {a} {row[f'time_ratio_{b}_over_{a}_median']:.2f}, "
            f"per iteration {row['time_per_iteration_ratio_median']:.2f}."
        )
    return "\n".join(lines) + "\n"


def run_all(args, solve_nlp) -> list[dict]:
    """Every NLP of ``args.tasks`` x ``args.draws`` (stage 1 and stage 2 each) given to
    ``solve_nlp(problem, x0, stage)``, whose dict of results per variant joins the record; the
    arguments are checked first and a progress line follows the problems."""
    if args.draws < 1:
        raise SystemExit("--draws: expected an integer >= 1")
    for task in args.tasks:
        try:
            jh.get_task(task)  # a bad key fails here, before any solve
        except ValueError as err:
            raise SystemExit(f"--tasks: {err}") from None
    progress = Progress(len(args.tasks) * args.draws, quiet=args.quiet)
    records = []
    for task in args.tasks:
        for draw in range(args.draws):
            for stage, problem, x0 in nlps(task, weights_of(task, draw, args.seed)):
                records.append({"task": task, "draw": draw, "stage": stage, **solve_nlp(problem, x0, stage)})
            progress.completed(f"{task} draw {draw}", "")
    return records


def problem_args(ap: argparse.ArgumentParser, out: str) -> None:
    """The options of ``run_all`` (tasks, draws, seed, quiet) and the JSON output."""
    ap.add_argument("--tasks", nargs="+", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--draws", type=int, default=4, help="problems per task (draw 0: the task as posed)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=out)
    ap.add_argument("--quiet", action="store_true")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    problem_args(ap, "results/bench_first_trial.json")
    ap.add_argument("--md", default=None, help="also write the table as Markdown")
    args = ap.parse_args()
    records = run_all(args, lambda problem, x0, stage: {v: run_one(problem, x0, stage, v) for v in VARIANTS})
    summary = summarise(records)
    write({"summary": summary, "records": records}, args.out)
    text = table(summary)
    print(text)
    if args.md:
        pathlib.Path(args.md).write_text(text)
    print(json.dumps({"out": args.out}))


if __name__ == "__main__":
    main()
