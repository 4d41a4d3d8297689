"""Benchmark: f, g, grad, sparse Jacobian and sparse Hessian of the NLP at N = 100, per scheme.

python scripts/bench_derivatives.py [--N 100] [--out results/bench_derivatives.json]
"""

from __future__ import annotations

import argparse

import jax
import numpy as np
from _bench import time_fn, write

import jaxhumanoid  # noqa: F401
from jaxhumanoid.strategy.problem import build_problem


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--N", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--out", default="results/bench_derivatives.json")
    args = ap.parse_args()
    results = {}
    print(
        f"{'scheme':10s} {'n':>5s} {'m':>5s} {'nnz J':>7s} {'nnz H':>7s} {'f':>8s} {'g':>8s} {'grad':>8s} {'J':>8s} {'H':>8s} {'J cpu':>8s} {'H cpu':>8s}  (median ms)"
    )
    for scheme in ("E,F,1S", "A,F,1S", "A,F+C,1S"):
        pr = build_problem("T1", scheme, N=args.N)
        nlp, p, x = pr.nlp, pr.p, pr.bounds.x0
        lam = np.random.default_rng(0).normal(size=nlp.m)
        row = {
            "f": time_fn(jax.jit(nlp.f), x, p, repeats=args.repeats),
            "g": time_fn(jax.jit(nlp.g), x, p, repeats=args.repeats),
            "grad": time_fn(jax.jit(nlp.grad), x, p, repeats=args.repeats),
            "jacobian": time_fn(jax.jit(nlp.jac_values), x, p, repeats=args.repeats),
            "hessian": time_fn(jax.jit(nlp.hess_values), x, lam, 1.0, p, repeats=args.repeats),
        }
        results[scheme] = {"n": nlp.n, "m": nlp.m, "nnz_jac": nlp.nnz_jac, "nnz_hess": nlp.nnz_hess, **row}
        print(
            f"{scheme:10s} {nlp.n:5d} {nlp.m:5d} {nlp.nnz_jac:7d} {nlp.nnz_hess:7d} "
            + " ".join(f"{row[k]['median_ms']:8.3f}" for k in ("f", "g", "grad", "jacobian", "hessian"))
            + f" {row['jacobian']['cpu_median_ms']:8.3f} {row['hessian']['cpu_median_ms']:8.3f}"
        )
    write({"N": args.N, "task": "T1", "results": results}, args.out)


if __name__ == "__main__":
    main()
