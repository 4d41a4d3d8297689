"""Benchmark: the 2S solve of each task with IPOPT (several runs; medians), compile time apart.

    python scripts/bench_solve.py [--tasks T1 T2 T3 T4] [--runs 3] [--out results/bench_solve.json]

Per-iteration time of the dynamic stage is split into JAX evaluation (our callbacks, measured
around each call) and IPOPT's linear algebra (``StdAugSystemSolverMultiSolve`` in IPOPT's timing
statistics: MUMPS factorisations, inertia corrections and back-solves); the rest is IPOPT's own
bookkeeping. IPOPT runs with MUMPS, mu_strategy=monotone; set OMP_NUM_THREADS to fix
BLAS threading when comparing iteration counts across machines.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import os
import re

import numpy as np

import jaxhumanoid  # noqa: F401
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.studies.bench import bench_task, write_record


def _timing(log: str, key: str) -> float:
    """Wall seconds of one entry of IPOPT's ``print_timing_statistics`` table."""
    match = re.search(re.escape(key) + r"\.*:\s+[\d.]+ \(sys:\s+[\d.]+ wall:\s+([\d.]+)\)", log)
    return float(match.group(1)) if match else float("nan")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default="results/bench_solve.json")
    args = ap.parse_args()
    results = {}
    print(
        f"{'task':5s} {'its 1+2':>10s} {'stage1 s':>9s} {'stage2 s':>9s} {'total s':>8s} {'ms/it (2)':>10s} {'eval share':>10s} {'linalg share':>12s}"
    )
    for task in args.tasks:
        runs = []
        for _ in range(args.runs):
            sol = solve(bench_task(task), "A,F+C,2S")
            runs.append(sol)
        # per-iteration cost and derivative share of the dynamic stage, from one more IPOPT run
        final = build_problem(bench_task(task), parse_scheme("A,F+C,2S"), N=100)
        its = [s.iterations for s in runs[-1].stages]
        t1 = float(np.median([s.stages[0].solve_time_s for s in runs]))
        t2 = float(np.median([s.stages[1].solve_time_s for s in runs]))
        res2 = solve_ipopt(final.nlp, final.p, final.bounds, options={"max_iter": 50, "print_timing_statistics": "yes"})
        per_it = res2.solve_time_s / max(res2.iterations, 1) * 1e3
        share = res2.history["eval_time_s"] / res2.solve_time_s
        linalg = _timing(res2.log, "StdAugSystemSolverMultiSolve") / res2.solve_time_s
        results[task] = {
            "success": all(s.success for s in runs),
            "iterations": its,
            "stage1_s_median": t1,
            "stage2_s_median": t2,
            "total_s_median": t1 + t2,
            "compile_s": runs[0].stages[0].compile_time_s + runs[0].stages[1].compile_time_s,
            "ms_per_iteration_dynamic": per_it,
            "derivative_share_dynamic": share,
            "linear_algebra_share_dynamic": linalg,
            "runs": args.runs,
            "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        }
        print(
            f"{task:5s} {its[0]:4d}+{its[1]:<5d} {t1:9.2f} {t2:9.2f} {t1 + t2:8.2f} {per_it:10.1f} {share:10.0%} {linalg:12.0%}"
        )
    write_record({"scheme": "A,F+C,2S", "N": 100, "results": results}, args.out)


if __name__ == "__main__":
    main()
