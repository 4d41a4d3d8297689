"""Benchmark: JAX against CasADi on the same NLP, side by side in one run.

    python scripts/bench_backends.py [--N 100] [--tasks T1 T2 T3 T4] [--skip-solves] [--out results/bench_backends.json]

Per-evaluation time (median of repeats) of f, g, the sparse Jacobian and the sparse Lagrangian
Hessian in JAX (jit) and in CasADi (SX Functions, virtual machine), their compile/build times,
and the whole A,F+C,2S solve of each task with IPOPT in both pipelines.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import time

import casadi as ca
import jax
import numpy as np

import jaxhumanoid  # noqa: F401
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.studies.bench import bench_task, time_fn, write_record
from jaxhumanoid.validation.casadi_backend import build_casadi_nlp


def _time_casadi(fn, args, repeats):
    t0 = time.perf_counter()
    fn(*args)
    first = (time.perf_counter() - t0) * 1e3
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        samples.append((time.perf_counter() - t0) * 1e3)
    return {
        "median_ms": float(np.median(samples)),
        "min_ms": float(np.min(samples)),
        "compile_ms": first,
        "repeats": repeats,
    }


def evaluations(N: int, repeats: int) -> dict:
    pr = build_problem("T1", "A,F+C,1S", N=N)
    nlp, p, x = pr.nlp, pr.p, pr.bounds.x0
    lam = np.random.default_rng(0).normal(size=nlp.m)
    jax_res = {
        "f": time_fn(jax.jit(nlp.f), x, p, repeats=repeats),
        "g": time_fn(jax.jit(nlp.g), x, p, repeats=repeats),
        "jacobian": time_fn(jax.jit(nlp.jac_values), x, p, repeats=repeats),
        "hessian": time_fn(jax.jit(nlp.hess_values), x, lam, 1.0, p, repeats=repeats),
    }
    t0 = time.perf_counter()
    cn = build_casadi_nlp(pr)
    lam_s, sig = ca.SX.sym("lam", nlp.m), ca.SX.sym("sigma")
    fns = {
        "f": ca.Function("f", [cn.x], [cn.f]),
        "g": ca.Function("g", [cn.x], [cn.g]),
        "jacobian": ca.Function("jacobian_g", [cn.x], [ca.jacobian(cn.g, cn.x)]),
        "hessian": ca.Function(
            "hessian_lagrangian", [cn.x, lam_s, sig], [ca.tril(ca.hessian(sig * cn.f + ca.dot(lam_s, cn.g), cn.x)[0])]
        ),
    }
    build_s = time.perf_counter() - t0
    cas_res = {k: _time_casadi(fn, (x, lam, 1.0) if k == "hessian" else (x,), repeats) for k, fn in fns.items()}
    return {"jax": jax_res, "casadi": cas_res, "casadi_build_s": build_s}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--N", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--skip-solves", action="store_true")
    ap.add_argument("--out", default="results/bench_backends.json")
    args = ap.parse_args()
    ev = evaluations(args.N, args.repeats)
    print(f"{'evaluation (T1 A,F+C, N=' + str(args.N) + ')':32s} {'JAX ms':>9s} {'CasADi ms':>10s} {'ratio':>7s}")
    for k in ("f", "g", "jacobian", "hessian"):
        j, c = ev["jax"][k]["median_ms"], ev["casadi"][k]["median_ms"]
        print(f"{k:32s} {j:9.3f} {c:10.3f} {j / c:7.2f}")
    jh = ev["jax"]["jacobian"]["median_ms"] + ev["jax"]["hessian"]["median_ms"]
    ch = ev["casadi"]["jacobian"]["median_ms"] + ev["casadi"]["hessian"]["median_ms"]
    print(f"{'J + H':32s} {jh:9.3f} {ch:10.3f} {jh / ch:7.2f}")
    solves = {}
    if not args.skip_solves:
        print(f"\n{'2S solve':8s} {'JAX its':>9s} {'JAX s':>7s} {'CasADi its':>11s} {'CasADi s':>9s} {'ratio':>6s}")
        for task in args.tasks:
            rec = {}
            for solver in ("ipopt", "casadi"):
                sol = solve(bench_task(task), "A,F+C,2S", solver=solver, N=args.N)
                rec[solver] = {
                    "success": sol.success,
                    "iterations": [s.iterations for s in sol.stages],
                    "solve_time_s": [s.solve_time_s for s in sol.stages],
                    "compile_time_s": [s.compile_time_s for s in sol.stages],
                    "objective": sol.objective,
                }
            tj, tc = sum(rec["ipopt"]["solve_time_s"]), sum(rec["casadi"]["solve_time_s"])
            print(
                f"{task:8s} {'+'.join(map(str, rec['ipopt']['iterations'])):>9s} {tj:7.2f} {'+'.join(map(str, rec['casadi']['iterations'])):>11s} {tc:9.2f} {tj / tc:6.2f}"
            )
            solves[task] = rec
    write_record({"N": args.N, "evaluations": ev, "solves_2S": solves}, args.out)


if __name__ == "__main__":
    main()
