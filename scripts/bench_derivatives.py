"""Benchmark: f, g, grad, sparse Jacobian and sparse Hessian of the NLP at N = 100, per scheme, and
the Jacobian and Hessian swept jointly (one colouring of all midpoint variables, the default)
against group by group (``stagewise_nlp(sweeps="grouped")``), timed in alternation.

python scripts/bench_derivatives.py [--N 100] [--repeats 50] [--out results/bench_derivatives.json]

The grouped values are checked against the joint ones (largest difference relative to the
largest entry) at the initial guess with random multipliers.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

import jax
import numpy as np

import jaxhumanoid  # noqa: F401
from jaxhumanoid.strategy.problem import build_problem, with_sweeps
from jaxhumanoid.studies.bench import alternate, time_fn, write_record

SCHEMES = ("E,F,1S", "A,F,1S", "A,F+C,1S")


def _rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b))))


def sweeps_compared(pr, repeats: int) -> dict:
    """J and H, joint against grouped, in alternation at the guess; the values' agreement; colours."""
    joint, grouped = pr.nlp, with_sweeps(pr, "grouped").nlp
    x, p = pr.bounds.x0, pr.p
    lam = np.random.default_rng(0).normal(size=joint.m)
    jit = {k: (jax.jit(v.jac_values), jax.jit(v.hess_values)) for k, v in (("joint", joint), ("grouped", grouped))}
    fns = {}
    for k, (J, H) in jit.items():
        fns[f"J {k}"] = lambda J=J: J(x, p)
        fns[f"H {k}"] = lambda H=H: H(x, lam, 1.0, p)
        fns[f"J+H {k}"] = lambda J=J, H=H: (J(x, p), H(x, lam, 1.0, p))
    times = alternate(fns, repeats)
    return {
        "times": times,
        "ratio_grouped_over_joint": {
            t: times[f"{t} grouped"]["median_ms"] / times[f"{t} joint"]["median_ms"] for t in ("J", "H", "J+H")
        },
        "max_rel_diff": {
            "J": _rel(jit["grouped"][0](x, p), jit["joint"][0](x, p)),
            "H": _rel(jit["grouped"][1](x, lam, 1.0, p), jit["joint"][1](x, lam, 1.0, p)),
        },
    }


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
    problems = {scheme: build_problem("T1", scheme, N=args.N) for scheme in SCHEMES}
    for scheme, pr in problems.items():
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
    print(
        "\n| scheme | J joint | J grouped | H joint | H grouped | J+H joint | J+H grouped | J+H ratio | max rel. diff J, H |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for scheme, pr in problems.items():
        c = sweeps_compared(pr, args.repeats)
        results[scheme]["sweeps"] = c
        t = {k: v["median_ms"] for k, v in c["times"].items()}
        print(
            f"| {scheme} | "
            + " | ".join(f"{t[f'{a} {b}']:.2f}" for a in ("J", "H", "J+H") for b in ("joint", "grouped"))
            + f" | {c['ratio_grouped_over_joint']['J+H']:.2f} | {c['max_rel_diff']['J']:.0e}, {c['max_rel_diff']['H']:.0e} |"
        )
    write_record({"N": args.N, "task": "T1", "results": results}, args.out)


if __name__ == "__main__":
    main()
