"""Benchmark: IPOPT through its C interface (ours) against cyipopt's binding, same IPOPT build.

    OMP_NUM_THREADS=1 python scripts/bench_ipopt_binding.py [--task T4] [--iters 60] [--runs 3]
                                                            [--out results/bench_ipopt_binding.json]

Both run the same number of IPOPT iterations from the same start on the N = 100 problem
(A,F+C), alternating, so the ratio is measured under the same machine load. Their iterates agree
to round-off (checked here), so the difference is the cost of the binding alone: cyipopt copies
each of the ~30k Jacobian and ~19k Hessian values with a Python-level indexing loop and calls the
JAX functions separately; ours fuses f+g and grad+J and copies with memcpy.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

import numpy as np
from _bench import write

import jaxhumanoid  # noqa: F401
from jaxhumanoid.solvers.ipopt import solve_cyipopt_reference, solve_ipopt
from jaxhumanoid.strategy.problem import build_problem


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--task", default="T4")
    ap.add_argument("--iters", type=int, default=60)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default="results/bench_ipopt_binding.json")
    args = ap.parse_args()
    pr = build_problem(args.task, "A,F+C,1S", N=100)
    opts = {"max_iter": args.iters}
    ours, ref, diff = [], [], []
    for _ in range(args.runs):
        r = solve_ipopt(pr.nlp, pr.p, pr.bounds, options=opts)
        x_ref, _, t_ref = solve_cyipopt_reference(pr.nlp, pr.p, pr.bounds, options=opts)
        ours.append(r.solve_time_s / args.iters * 1e3)
        ref.append(t_ref / args.iters * 1e3)
        diff.append(float(np.max(np.abs(r.x - x_ref))))
    res = {
        "task": args.task,
        "N": 100,
        "iterations": args.iters,
        "runs": args.runs,
        "ms_per_iteration_capi": ours,
        "ms_per_iteration_cyipopt": ref,
        "median_capi": float(np.median(ours)),
        "median_cyipopt": float(np.median(ref)),
        "ratio_median": float(np.median(np.asarray(ours) / np.asarray(ref))),
        "max_abs_x_difference": max(diff),
    }
    print(f"{'binding':10s} {'ms/iteration (median)':>22s}")
    print(f"{'C API':10s} {res['median_capi']:22.1f}")
    print(f"{'cyipopt':10s} {res['median_cyipopt']:22.1f}")
    print(f"ratio (per run, median) {res['ratio_median']:.2f}; max |x difference| {res['max_abs_x_difference']:.1e}")
    write(res, args.out)


if __name__ == "__main__":
    main()
