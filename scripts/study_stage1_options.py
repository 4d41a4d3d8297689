"""Study: stage 1 of 2S on the robustness study's perturbed problems, under barrier and scaling variants.

    OMP_NUM_THREADS=1 python scripts/study_stage1_options.py [--spec examples/studies/robustness.toml]
        [--tasks T1 T2 T3 T4] [--draws 40] [--variants default adaptive ...]
        [--workers 2] [--out results/study_stage1_options.json] [--md results/study_stage1_options.md] [--quiet]

Each problem is a draw of the study spec (weights, start posture, N, T drawn exactly as ``jaxhumanoid
sweep`` draws them: ``studies.run.solve_case``), and only its stage 1 runs: the pseudo-static problem
(8) under the relaxed law, by IPOPT (the default stage-1 solver), with the stage-1 fallbacks of
``solve``. A variant changes the stage-1 options or the scaling:

    default             solve's defaults (monotone barrier update, mu_init = 1e-2, no scaling)
    adaptive            mu_strategy = "adaptive" (every fallback too)
    physical            scaling = "physical" (``ocp.scaling``)
    adaptive+physical   both
    warm                stage 2's barrier settings: mu_init = 1e-3, bound_push = bound_frac = 1e-6, which
                        keep a start that (nearly) satisfies the constraints, as the inverse-dynamics guess does
    strength x1.5, x2   the torque box of stage 1 only widened to 1.5 or 2 times the strengths (stage 1 is
                        a warm start: the final problem keeps the strengths)
    linear guess        the linear initial guess first instead of the inverse-dynamics one (the fallbacks
                        then try the inverse-dynamics guess)
    static path         the static-path guess (``ocp.static_path``): postures the body can hold at rest
    mu_init 0.1         IPOPT's default initial barrier parameter instead of 1e-2
    barrier_tol_factor 1000, mu_linear_decrease_factor 0.05
                        leave each barrier subproblem earlier, or cut mu faster (IPOPT: 10, 0.2)
    watchdog_shortened_iter_trigger 3
                        IPOPT's watchdog after 3 shortened steps instead of 10
    bound_mult_init_method mu-based
                        bound multipliers mu / slack at the start instead of 1
    bound_push 0.1      bound_push = bound_frac = 0.1: the start pushed further inside its bounds (1e-2)
    alpha_for_y full    full steps in the equality multipliers (IPOPT: the primal step)

Per variant: the largest constraint violation of stage 1's start, the first run's success and
iterations, the stage's success after the fallbacks and its iterations over all runs (what the
study counts), the objective, and per problem whether the variant ends at the default's optimum
(objectives within ``compare.OBJ_RTOL``). The median of the
default's all-runs iterations is the study's "iterations of stage 1".
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import concurrent.futures as cf
import dataclasses
import functools
import pathlib
import tempfile
from typing import NamedTuple

import numpy as np
from _bench import show_table, write

import jaxhumanoid  # noqa: F401  (x64)
from jaxhumanoid.progress import Progress
from jaxhumanoid.strategy import solve as strat
from jaxhumanoid.studies import run
from jaxhumanoid.studies.compare import OBJ_RTOL
from jaxhumanoid.studies.spec import load_spec


class Variant(NamedTuple):
    """Stage-1 options, scaling, factor on the strengths u_max in stage 1, and initial guess."""

    options: dict = {}
    scaling: str = "none"
    strength: float = 1.0
    guess: str = strat.DEFAULT_GUESS


VARIANTS = {
    "default": Variant(),
    "adaptive": Variant(options={"mu_strategy": "adaptive"}),
    "physical": Variant(scaling="physical"),
    "adaptive+physical": Variant(options={"mu_strategy": "adaptive"}, scaling="physical"),
    "warm": Variant(options={"mu_init": 1e-3, "bound_push": 1e-6, "bound_frac": 1e-6}),
    "strength x1.5": Variant(strength=1.5),
    "strength x2": Variant(strength=2.0),
    "linear guess": Variant(guess="linear"),
    "static path": Variant(guess="static_path"),
    "mu_init 0.1": Variant(options={"mu_init": 0.1}),
    "barrier_tol_factor 1000": Variant(options={"barrier_tol_factor": 1000.0}),
    "mu_linear_decrease_factor 0.05": Variant(options={"mu_linear_decrease_factor": 0.05}),
    "watchdog_shortened_iter_trigger 3": Variant(options={"watchdog_shortened_iter_trigger": 3}),
    "bound_mult_init_method mu-based": Variant(options={"bound_mult_init_method": "mu-based"}),
    "bound_push 0.1": Variant(options={"bound_push": 0.1, "bound_frac": 0.1}),
    "alpha_for_y full": Variant(options={"alpha_for_y": "full"}),
}


class _StageOneDone(Exception):
    """Raised once stage 1 has run, to skip the later stages."""

    def __init__(self, stats):
        super().__init__("stage 1 done")
        self.stats = stats


def stage_one_record(case, variant: str) -> dict:
    """Stage 1 of ``case`` under ``variant``: its runs' iterations, status and objective. A fallback
    runs only after a failed run, so the first run succeeded exactly when there was one run and
    the stage succeeded."""
    options, scaling, strength, guess = VARIANTS[variant]
    stage_one, problem_one, solve = strat._stage_one, strat.stage_one_problem, run.solve

    def stronger_problem(task, scheme, final, N1, contact_stage1=None, guess="linear", factor=1.0):
        return problem_one(task, scheme, final, N1, contact_stage1, guess, strength * factor)

    def stopping_stage_one(*a, **k):
        raise _StageOneDone(stage_one(*a, **k)[0])

    strat._stage_one = stopping_stage_one
    if strength != 1.0:
        strat.stage_one_problem = stronger_problem
    run.solve = functools.partial(solve, stage1_options=options or None, scaling=scaling, guess=guess)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            run.solve_case(dataclasses.replace(case, save=False), pathlib.Path(tmp))
        raise RuntimeError("the case ran without a stage 1")
    except _StageOneDone as done:
        st = done.stats
        return {
            "task": case.task,
            "draw": case.draw,
            "variant": variant,
            "status": st.status,
            "first_success": bool(st.success and st.attempts == 1),
            "first_iterations": int(st.runs[0]),
            "runs": int(st.attempts),
            "success": bool(st.success),
            "iterations": int(st.iterations),
            "objective": float(st.objective),
            "start_violation": float(st.start_violation),
            "solve_time_s": float(st.solve_time_s),
        }
    finally:
        strat._stage_one, strat.stage_one_problem, run.solve = stage_one, problem_one, solve


def _same_objective(a: dict, b: dict) -> bool:
    """Both succeeded at objectives within ``compare.OBJ_RTOL`` (relative, as ``compare.agreement``;
    stage 1's trajectories are not kept, so the objective alone decides)."""
    scale = max(abs(a["objective"]), abs(b["objective"]), 1e-300)
    return a["success"] and b["success"] and abs(a["objective"] - b["objective"]) / scale <= OBJ_RTOL


def _counts(rs: list[dict]) -> dict:
    its = np.array([r["iterations"] for r in rs])
    return {
        "problems": len(rs),
        "first_run_succeeded": sum(r["first_success"] for r in rs),
        "succeeded": sum(r["success"] for r in rs),
        "iterations_median": float(np.median(its)),
        "iterations_range": [int(its.min()), int(its.max())],
    }


def summary(records: list[dict], variants: list[str]) -> dict:
    """Per variant: ``_counts`` over all problems and per task, the median iterations of a
    successful first run, solve time and start violation, and on how many problems that both
    solved the variant ends at the default's optimum."""
    by = {(r["task"], r["draw"], r["variant"]): r for r in records}
    problems = sorted({(r["task"], r["draw"]) for r in records})
    out = {}
    for v in variants:
        rs = [by[p + (v,)] for p in problems if p + (v,) in by]
        both = [(by[p + (v,)], by[p + ("default",)]) for p in problems if p + (v,) in by and p + ("default",) in by]
        solved = [(a, b) for a, b in both if a["success"] and b["success"]]
        first = [r["first_iterations"] for r in rs if r["first_success"]]
        out[v] = {
            **_counts(rs),
            "first_run_iterations_median": float(np.median(first)) if first else None,
            "same_optimum_as_default": f"{sum(_same_objective(a, b) for a, b in solved)}/{len(solved)}",
            "solve_time_s_median": float(np.median([r["solve_time_s"] for r in rs])),
            "start_violation_median": float(np.median([r["start_violation"] for r in rs])),
            "per_task": {t: _counts([r for r in rs if r["task"] == t]) for t in sorted({r["task"] for r in rs})},
        }
    return out


def table(s: dict) -> str:
    lines = [
        "| variant | problems | first run succeeded | succeeded after fallbacks | iterations, all runs: median (range) "
        "| iterations of a successful first run, median | same optimum as default | solve s, median |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for v, r in s.items():
        rng = r["iterations_range"]
        first = r["first_run_iterations_median"]
        lines.append(
            f"| {v} | {r['problems']} | {r['first_run_succeeded']} | {r['succeeded']} | "
            f"{r['iterations_median']:g} ({rng[0]}-{rng[1]}) | {'-' if first is None else f'{first:g}'} | "
            f"{r['same_optimum_as_default']} | {r['solve_time_s_median']:.2f} |"
        )
    tasks = sorted({t for r in s.values() for t in r["per_task"]})
    lines += [
        "",
        "| variant | " + " | ".join(f"{t}: first run / after fallbacks, median iterations" for t in tasks) + " |",
    ]
    lines.append("|---|" + "---|" * len(tasks))
    for v, r in s.items():
        cells = [
            f"{c['first_run_succeeded']}/{c['problems']} / {c['succeeded']}/{c['problems']}, {c['iterations_median']:g}"
            for c in (r["per_task"][t] for t in tasks)
        ]
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default="examples/studies/robustness.toml")
    ap.add_argument("--tasks", nargs="*", default=None)
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default="results/study_stage1_options.json")
    ap.add_argument("--md", default=None)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args()
    if "default" not in args.variants:
        raise SystemExit("--variants: must include 'default' (the reference of 'same optimum')")
    spec = load_spec(args.spec)
    cases = [
        c
        for c in spec.cases
        if c.solver == "ipopt" and (c.draw or 0) < args.draws and (args.tasks is None or c.task in args.tasks)
    ]
    if not cases:
        raise SystemExit(f"--tasks/--draws: no IPOPT case of {args.spec} matches")
    jobs = [(c, v) for c in cases for v in args.variants]
    progress = Progress(len(jobs), quiet=args.quiet)
    records = []
    with cf.ProcessPoolExecutor(max_workers=args.workers) as pool:
        futures = {pool.submit(stage_one_record, c, v): (c, v) for c, v in jobs}
        for fut in cf.as_completed(futures):
            c, v = futures[fut]
            r = fut.result()
            records.append(r)
            progress.completed(
                f"{c.task} draw {c.draw} {v}", f"{r['status']}, {r['runs']} run(s), {r['iterations']} its"
            )
    records.sort(key=lambda r: (r["task"], r["draw"], args.variants.index(r["variant"])))
    s = summary(records, args.variants)
    write({"spec": args.spec, "draws": args.draws, "summary": s, "records": records}, args.out)
    show_table(table(s), args.md)


if __name__ == "__main__":
    main()
