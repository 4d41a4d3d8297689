"""Benchmark: the IPM's two KKT solves (``IPMOptions.kkt_method``), block LDL^T against condensed,
on the same matrices and the same NLPs, in one run.

    OMP_NUM_THREADS=1 python scripts/bench_kkt_methods.py [--repeats 20] [--runs 3] [--iters 40]
                     [--tasks T1 T2 T3 T4] [--data /tmp/bench_kkt_data.npz]
                     [--out results/bench_kkt_methods.json] [--skip-ipm]

1. KKT level, on the humanoid KKT matrices of ``bench_kkt.py`` (T1's stage 2 at N = 100, near
   IPOPT's iterates 3, 30 and its solution, and one with synthetic barrier diagonals), each with
   (delta_w, delta_c) = (0, 0) and (1e-4, 1e-9): the inertia of both (equal or not), the normwise
   backward error of the refined solves in the Ruiz-equilibrated system, and the median time of
   factor, and of factor + refined solve, of each method, called in alternation (one call of
   each per round) so that the machine's load affects both alike, and of the condensed
   factorisation's two steps (local elimination, recursion over K_U). Also the sizes: the block of
   the LDL^T (nb), and the condensed interior (nI) and kept (nU) blocks.
2. IPM level: stage 2 of 2S (the dynamic N = 100 NLP of each task from IPOPT's interpolated
   stage-1 solution, the 2S stage-2 options): ``--iters`` iterations with each method and with
   IPOPT (ms per iteration, median of ``--runs``), then the whole solve with each method
   (status, iterations, objective): an exact KKT solve does not change the iterates beyond
   rounding, so the two should take the same steps.
Writes JSON (``--out``) and prints the tables.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.runtime import enable_compilation_cache
from jaxhumanoid.solvers.ipm import kkt, solve_ipm
from jaxhumanoid.solvers.ipm.kkt import condensed, elimination
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.handover import STAGE2_DEFAULTS
from jaxhumanoid.studies.bench import stage2_warm_start, write_record
from jaxhumanoid.studies.kkt_data import backward_error, make_data, ruiz, sparse_kkt

METHODS = ("block_ldl", "condensed")


def alternate(fns: dict, repeats: int) -> dict:
    """Median ms of each zero-argument function, called in alternation after one warm-up call."""
    for f in fns.values():
        jax.block_until_ready(f())
    ms: dict = {k: [] for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f())
            ms[k].append((time.perf_counter() - t0) * 1e3)
    return {k: float(np.median(v)) for k, v in ms.items()}


def kkt_level(D: dict, repeats: int) -> dict:
    n, m = int(D["n"]), int(D["m"])
    pat = [D[k] for k in ("var_stage", "con_stage", "hess_rows", "hess_cols", "jac_rows", "jac_cols")]
    cst = kkt.build_condensed(n, m, *pat)
    st = cst.st
    fac = {
        "block_ldl": jax.jit(lambda A, B: kkt.factor(st, A, B)),
        "condensed": jax.jit(lambda A, B: condensed.factor(cst, A, B)),
    }
    sol = {
        "block_ldl": lambda f, A, B, rx, rc: kkt.solve(st, f, A, B, rx, rc),
        "condensed": lambda f, A, B, rx, rc: condensed.solve(cst, f, A, B, rx, rc),
    }
    rng = np.random.default_rng(0)
    rows = []
    for label in ("it3", "it30", "final", "synth"):
        hv, jv, dx, dc = (D[f"{label}_{k}"] for k in ("hess", "jac", "dx", "dc"))
        for dw, dcr in ((0.0, 0.0), (1e-4, 1e-9)):
            dxx, dcc = dx + dw, dc - dcr
            A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dxx), jnp.asarray(dcc))
            K = sparse_kkt(D, hv, jv, dxx, dcc)
            s = ruiz(K)
            Ks = (K.multiply(s[:, None]).multiply(s[None, :])).tocsr()
            r = rng.standard_normal(n + m)
            rx, rc = jnp.asarray(r[:n]), jnp.asarray(r[n:])
            row: dict = {"matrix": label, "delta_w": dw, "delta_c": dcr}
            for name in METHODS:
                f = fac[name](A, B)
                u = np.concatenate(sol[name](f, A, B, rx, rc))
                row[name] = {
                    "inertia": [int(f.npos), int(f.nneg), int(f.nzero)],
                    "backward_error": backward_error(Ks, s, u, r),
                }
            t_f = alternate({k: (lambda k=k: fac[k](A, B)) for k in METHODS}, repeats)
            t_fs = alternate({k: (lambda k=k: sol[k](fac[k](A, B), A, B, rx, rc)) for k in METHODS}, repeats)
            for name in METHODS:
                row[name]["factor_ms"], row[name]["factor_solve_ms"] = t_f[name], t_fs[name]
            # the condensed factorisation's two steps, and the block LDL^T's recursion alone
            loc = condensed.eliminate_local(cst, A, B)
            parts = alternate(
                {
                    "local": lambda: condensed.eliminate_local(cst, A, B),
                    "reduced": lambda: elimination.factor(cst.red, loc.A_red, loc.B_red),
                },
                repeats,
            )
            row["condensed"]["local_elimination_ms"], row["condensed"]["reduced_recursion_ms"] = (
                parts["local"],
                parts["reduced"],
            )
            row["same_inertia"] = row["block_ldl"]["inertia"] == row["condensed"]["inertia"]
            rows.append(row)
    return {"nb": st.nb, "nI": cst.nI, "nU": cst.nU, "S": st.S, "cases": rows}


def ipm_level(task: str, runs: int, iters: int) -> dict:
    prob, x0 = stage2_warm_start(task)
    short = {**STAGE2_DEFAULTS, "max_iter": iters}
    out: dict = {}
    solve_ipopt(prob.nlp, prob.p, prob.bounds, x0=x0, options=short)  # jit its evaluators
    for name in (*METHODS, "ipopt"):
        ms = []
        for _ in range(runs):
            if name == "ipopt":
                r = solve_ipopt(prob.nlp, prob.p, prob.bounds, x0=x0, options=short)
            else:
                r = solve_ipm(prob.nlp, prob.p, prob.bounds, x0=x0, options={**short, "kkt_method": name})
            ms.append(r.solve_time_s / max(r.iterations, 1) * 1e3)
        out[name] = {"ms_per_iteration": float(np.median(ms)), "samples_ms": ms}
    for name in METHODS:
        r = solve_ipm(prob.nlp, prob.p, prob.bounds, x0=x0, options={**STAGE2_DEFAULTS, "kkt_method": name})
        out[name].update(
            status=r.status, iterations=int(r.iterations), objective=float(r.objective), solve_s=r.solve_time_s
        )
    a, b = out["block_ldl"], out["condensed"]
    out["objective_rel_diff"] = abs(a["objective"] - b["objective"]) / max(abs(a["objective"]), 1e-12)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--iters", type=int, default=40)
    ap.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--data", default="/tmp/bench_kkt_data.npz")
    ap.add_argument("--out", default="results/bench_kkt_methods.json")
    ap.add_argument("--skip-ipm", action="store_true")
    args = ap.parse_args()
    enable_compilation_cache()
    res: dict = {"omp_num_threads": os.environ.get("OMP_NUM_THREADS")}
    res["kkt"] = k = kkt_level(make_data(args.data), args.repeats)
    print(
        f"T1 stage 2, N = 100: S = {k['S']} blocks of nb = {k['nb']}; condensed: interior nI = {k['nI']}, kept nU = {k['nU']}"
    )
    print(
        f"{'matrix':7s} {'dw':>6s} | {'inertia LDL':>16s} {'condensed':>16s} | {'berr LDL':>8s} {'cond':>8s} | {'factor ms LDL':>13s} {'cond':>6s} {'(local + recursion)':>19s} | {'f+solve LDL':>11s} {'cond':>6s}"
    )
    for r in k["cases"]:
        a, b = r["block_ldl"], r["condensed"]
        print(
            f"{r['matrix']:7s} {r['delta_w']:6.0e} | {str(a['inertia']):>16s} {str(b['inertia']):>16s} | "
            f"{a['backward_error']:8.1e} {b['backward_error']:8.1e} | {a['factor_ms']:13.2f} {b['factor_ms']:6.2f} "
            f"({b['local_elimination_ms']:5.2f} + {b['reduced_recursion_ms']:5.2f}) | "
            f"{a['factor_solve_ms']:11.2f} {b['factor_solve_ms']:6.2f}"
        )
    if not args.skip_ipm:
        res["ipm"] = {}
        print(
            f"{'task':5s} | {'ms/it LDL':>9s} {'cond':>6s} {'IPOPT':>6s} | {'stage 2 LDL: status, its':>30s} | {'condensed':>30s} | {'rel obj':>8s}"
        )
        for task in args.tasks:
            r = res["ipm"][task] = ipm_level(task, args.runs, args.iters)
            a, b, c = r["block_ldl"], r["condensed"], r["ipopt"]
            print(
                f"{task:5s} | {a['ms_per_iteration']:9.1f} {b['ms_per_iteration']:6.1f} {c['ms_per_iteration']:6.1f} | "
                f"{a['status'][:24]:>24s} {a['iterations']:5d} | {b['status'][:24]:>24s} {b['iterations']:5d} | {r['objective_rel_diff']:8.1e}"
            )
    write_record(res, args.out)


if __name__ == "__main__":
    main()
