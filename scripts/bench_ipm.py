"""Benchmark: the own interior-point method (IPM) against IPOPT on the same NLPs, in one run.

    python scripts/bench_ipm.py [--tasks T1 T2 T3 T4] [--runs 3] [--batch 32] [--iters 40]
                                [--out results/bench_ipm.json] [--skip-compile] [--skip-batch]
                                [--skip-per-iteration] [--skip-spread] [--compile-only RUNS]
                                [--compile-sweeps joint grouped]

1. Per-iteration time at N = 100 (T1's dynamic stage-2 NLP from the 2S warm start, ``--iters``
   iterations, medians of ``--runs``): IPM and IPOPT, and their ratio.
2. The whole 2S solve (A,F+C,2S) per task with each solver: stage statuses and iterations, solve
   time (compile excluded), objective relative difference and max |q_ipm - q_ipopt|; then stage 2
   alone from the same start (IPOPT's stage-1 solution) for both, to compare optima and
   iteration counts on the same problem; then stage 1 with IPOPT under options that change only
   the rounding of its linear solves (``ROUNDING_VARIANTS``) next to the IPM: IPOPT's own spread
   of iteration counts and optima on these chaotic NLPs (``--skip-spread`` skips it).
3. IPM compile time of the N = 100 NLP in fresh processes: cold (empty persistent JAX cache) and
   warm (the cache the cold run filled). ``--compile-only RUNS`` measures only this, RUNS times,
   for the solve as one program and as the command line runs it (with a progress line), with
   each of ``--compile-sweeps`` (the derivatives' sweeps, ``stagewise_nlp``).
4. Throughput of a ``vmap`` batch of ``--batch`` stage-1 (pseudo-static, N1 = 30) problems of T1
   with perturbed cost weights (``batch_solve_ipm``), against the same problems one after another.
Set OMP_NUM_THREADS=1 when comparing with other runs.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxhumanoid  # noqa: F401
from jaxhumanoid.derivatives.stagewise import SWEEPS
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.runtime import enable_compilation_cache
from jaxhumanoid.solvers.ipm import batch_solve_ipm, solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy import solve as strat
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.studies.bench import bench_task, write_record

SCHEME = "A,F+C,2S"


def stage1_problem(task: str, N1: int = strat.STAGE1_N):
    """Stage 1 of 2S (pseudo-static, relaxed contact law, re-seated start) and the stage-2 problem."""
    t = bench_task(task)
    final = build_problem(t, parse_scheme(SCHEME), N=100)
    relaxed = ContactParams.relaxed()
    q1, _ = strat.reseat_for_contact(final.p, final.p.q_start, final.layout.active, relaxed)
    first = build_problem(t, parse_scheme(SCHEME), N=N1, pseudo_static=True, contact=relaxed, q_start=q1)
    return first, final


def stage2_warm_start(task: str):
    """The stage-2 problem and its 2S warm start from IPOPT's stage-1 solution (interpolated)."""
    first, prob = stage1_problem(task)
    r1 = solve_ipopt(first.nlp, first.p, first.bounds, options=strat.STAGE1_DEFAULTS)
    Zf = strat.interpolate_full(first.full(r1.x), float(prob.p.T), prob.layout)
    return prob, np.clip(np.asarray(tr.free_from_full(prob.layout, Zf)), prob.bounds.xl, prob.bounds.xu)


def rel_diff(a: float, b: float) -> float:
    """|a - b| / |b| (b the IPOPT reference)."""
    return abs(a - b) / max(abs(b), 1e-12)


def per_iteration(runs: int, iters: int) -> dict:
    """Both solvers on T1's stage-2 NLP from the same warm start (IPOPT's stage-1 solution,
    interpolated, as 2S does) with the 2S stage-2 options: the iterations that 2S spends."""
    prob, x0 = stage2_warm_start("T1")
    opts = {**strat.STAGE2_DEFAULTS, "max_iter": iters}
    out = {}
    for name, fn in (("ipm", solve_ipm), ("ipopt", solve_ipopt)):
        if name == "ipopt":  # jit the evaluators (the IPM reports compile apart)
            fn(prob.nlp, prob.p, prob.bounds, x0=x0, options=opts)
        ms = []
        for _ in range(runs):
            r = fn(prob.nlp, prob.p, prob.bounds, x0=x0, options=opts)
            ms.append(r.solve_time_s / max(r.iterations, 1) * 1e3)
        out[name] = {"ms_per_iteration_median": float(np.median(ms)), "samples_ms": ms, "iterations": int(r.iterations)}
    out["ratio_ipm_over_ipopt"] = out["ipm"]["ms_per_iteration_median"] / out["ipopt"]["ms_per_iteration_median"]
    return out


def stage2_same_start(task: str) -> dict:
    """Stage 2 of 2S (the dynamic N = 100 NLP) from the same warm start for both solvers (IPOPT's
    stage-1 solution, interpolated, as 2S does): does the IPM reach IPOPT's optimum on the same
    problem, and in how many iterations?"""
    prob, x0 = stage2_warm_start(task)
    out = {}
    for name, fn in (("ipm", solve_ipm), ("ipopt", solve_ipopt)):
        r = fn(prob.nlp, prob.p, prob.bounds, x0=x0, options=strat.STAGE2_DEFAULTS)
        out[name] = {
            "status": r.status,
            "iterations": int(r.iterations),
            "objective": float(r.objective),
            "solve_s": r.solve_time_s,
            "ms_per_iteration": r.solve_time_s / max(r.iterations, 1) * 1e3,
            "q": np.asarray(prob.full(r.x))[:, 0:5],
        }
    a, b = out["ipm"], out["ipopt"]
    out["objective_rel_diff"] = rel_diff(a["objective"], b["objective"])
    out["max_abs_dq_rad"] = float(np.max(np.abs(a.pop("q") - b.pop("q"))))
    out["iteration_ratio_ipm_over_ipopt"] = a["iterations"] / max(b["iterations"], 1)
    return out


# IPOPT options that change only how MUMPS scales and pivots, i.e. the rounding of every step
ROUNDING_VARIANTS = ({}, {"mumps_scaling": 0}, {"mumps_pivtol": 1e-5}, {"mumps_permuting_scaling": 0})


def rounding_spread(task: str) -> dict:
    """Stage 1 of 2S (the same NLP and start for all) with IPOPT under ``ROUNDING_VARIANTS`` and
    with the IPM: the spread of IPOPT's own iteration counts and optima when only the rounding of
    its linear solves changes, the yardstick for the IPM's count on these chaotic NLPs."""
    first, _ = stage1_problem(task)
    runs = []
    for extra in ROUNDING_VARIANTS:
        r = solve_ipopt(first.nlp, first.p, first.bounds, options={**strat.STAGE1_DEFAULTS, **extra})
        runs.append(
            {"options": extra, "status": r.status, "iterations": int(r.iterations), "objective": float(r.objective)}
        )
    r = solve_ipm(first.nlp, first.p, first.bounds, options=strat.STAGE1_DEFAULTS)
    its = [v["iterations"] for v in runs]
    objs = sorted({round(v["objective"], 6) for v in runs})
    return {
        "ipopt": runs,
        "ipopt_iterations_min": min(its),
        "ipopt_iterations_max": max(its),
        "ipopt_distinct_optima": objs,
        "ipm": {"status": r.status, "iterations": int(r.iterations), "objective": float(r.objective)},
        "ipm_over_ipopt_max": int(r.iterations) / max(its),
    }


def whole_2s(task: str, runs: int) -> dict:
    res = {}
    sols = {}
    for solver in ("ipm", "ipopt"):
        times, compile_s, sol = [], None, None
        for _ in range(runs):
            sol = strat.solve(bench_task(task), SCHEME, solver=solver)
            times.append(sum(s.solve_time_s for s in sol.stages))
            compile_s = sum(s.compile_time_s for s in sol.stages) if compile_s is None else compile_s
        sols[solver] = sol
        res[solver] = {
            "status": [s.status for s in sol.stages],
            "iterations": [s.iterations for s in sol.stages],
            "solve_s_median": float(np.median(times)),
            "setup_and_compile_s_first_run": compile_s,
            "objective": sol.objective,
        }
    a, b = sols["ipm"], sols["ipopt"]
    res["objective_rel_diff"] = rel_diff(a.objective, b.objective)
    res["max_abs_dq_rad"] = float(np.max(np.abs(a.q - b.q)))
    return res


_CHILD = r"""
import json, sys
import jaxhumanoid
from jaxhumanoid.runtime import enable_compilation_cache
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.solvers.ipm import solve_ipm
from jaxhumanoid.strategy.problem import build_problem, with_sweeps
enable_compilation_cache(sys.argv[1])
prob = with_sweeps(build_problem("T1", parse_scheme("A,F+C,2S"), N=100), sys.argv[3])
progress = (lambda k, f, inf: None) if sys.argv[2] == "stepped" else None
r = solve_ipm(prob.nlp, prob.p, prob.bounds, options={"max_iter": 1}, progress=progress)
print(json.dumps({"compile_s": r.compile_time_s}))
"""


def compile_times(mode: str = "whole", sweeps: str = "joint") -> dict:
    """IPM compile time in two fresh processes sharing a new persistent cache: cold, then warm.
    ``mode`` "whole": the solve as one program; "stepped": with a progress callback, as the
    command line runs it (start, one iteration and finish compiled apart). ``sweeps``: the
    derivatives' sweeps (``with_sweeps``)."""
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        for label in ("cold", "warm"):
            t0 = time.perf_counter()
            p = subprocess.run(
                [sys.executable, "-c", _CHILD, cache, mode, sweeps], capture_output=True, text=True, check=True
            )
            out[f"{label}_compile_s"] = json.loads(p.stdout.strip().splitlines()[-1])["compile_s"]
            out[f"{label}_process_s"] = time.perf_counter() - t0
    return out


def compile_spread(runs: int, sweeps: tuple[str, ...] = ("joint",)) -> dict:
    """``compile_times`` of both modes and each of ``sweeps``, alternating, ``runs`` times: every
    run and the medians, keyed "whole", "stepped" (joint sweeps) and "whole grouped", ...."""
    cases = {(m if sw == "joint" else f"{m} {sw}"): (m, sw) for sw in sweeps for m in ("whole", "stepped")}
    rows: dict[str, list[dict]] = {label: [] for label in cases}
    for _ in range(runs):
        for label, r in rows.items():
            r.append(compile_times(*cases[label]))
    return {
        label: {
            "runs": r,
            **{f"{k}_median": float(np.median([x[k] for x in r])) for k in r[0]},
        }
        for label, r in rows.items()
    }


def batch_throughput(batch: int) -> dict:
    """A vmap batch of stage-1 problems of T1 with log-normally perturbed weights (sigma = 0.2)."""
    prob, _ = stage1_problem("T1")
    rng = np.random.default_rng(0)
    weights = np.asarray(prob.p.weights)[None] * np.exp(0.2 * rng.standard_normal((batch, np.size(prob.p.weights))))
    p_batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + jnp.shape(a)), prob.p)
    p_batch = dataclasses.replace(p_batch, weights=jnp.asarray(weights))
    opts = dict(strat.STAGE1_DEFAULTS)
    batch_solve_ipm(prob.nlp, jax.tree.map(lambda a: a[:batch], p_batch), prob.bounds, options=opts)  # compile
    t0 = time.perf_counter()
    res_b = batch_solve_ipm(prob.nlp, p_batch, prob.bounds, options=opts)
    t_batch = time.perf_counter() - t0
    p_one = jax.tree.map(lambda a: a[0], p_batch)
    solve_ipm(prob.nlp, p_one, prob.bounds, options=opts)  # compile
    t0 = time.perf_counter()
    res_s = [
        solve_ipm(prob.nlp, jax.tree.map(lambda a: a[i], p_batch), prob.bounds, options=opts) for i in range(batch)
    ]
    t_seq = time.perf_counter() - t0
    return {
        "problem": f"T1 stage 1 (pseudo-static, N={strat.STAGE1_N}), weights x exp(0.2 N(0,1))",
        "batch": batch,
        "batch_s": t_batch,
        "sequential_s": t_seq,
        "speedup_batch_over_sequential": t_seq / t_batch,
        "batch_success": int(sum(r.success for r in res_b)),
        "sequential_success": int(sum(r.success for r in res_s)),
        "batch_iterations_max": int(max(r.iterations for r in res_b)),
        "sequential_iterations_sum": int(sum(r.iterations for r in res_s)),
    }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--iters", type=int, default=40)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--out", default="results/bench_ipm.json")
    ap.add_argument("--skip-compile", action="store_true")
    ap.add_argument("--skip-batch", action="store_true")
    ap.add_argument("--skip-per-iteration", action="store_true")
    ap.add_argument("--skip-spread", action="store_true")
    ap.add_argument("--compile-only", type=int, default=0, metavar="RUNS", help="only the compile times, RUNS times")
    ap.add_argument("--compile-sweeps", nargs="+", default=["joint"], choices=SWEEPS, help="sweeps to compile with")
    args = ap.parse_args()
    enable_compilation_cache()
    results = {"omp_num_threads": os.environ.get("OMP_NUM_THREADS")}
    if args.compile_only:
        results["compile_spread"] = c = compile_spread(args.compile_only, tuple(args.compile_sweeps))
        for mode, r in c.items():
            each = ", ".join(f"{x['cold_compile_s']:.1f}" for x in r["runs"])
            print(
                f"IPM compile at N=100, {mode}: cold {r['cold_compile_s_median']:.1f} s ({each}), "
                f"warm {r['warm_compile_s_median']:.1f} s"
            )
        write_record({"scheme": SCHEME, "N": 100, "results": results}, args.out)
        return

    if not args.skip_per_iteration:
        results["per_iteration_N100"] = pi = per_iteration(args.runs, args.iters)
        print(
            f"per iteration at N=100: IPM {pi['ipm']['ms_per_iteration_median']:.1f} ms, "
            f"IPOPT {pi['ipopt']['ms_per_iteration_median']:.1f} ms, ratio {pi['ratio_ipm_over_ipopt']:.2f}"
        )

    results["whole_2s"] = {}
    print(
        f"{'task':5s} {'IPM status':>34s} {'its':>9s} {'s':>6s} | {'IPOPT its':>9s} {'s':>6s} | {'rel obj':>8s} {'max dq':>7s}"
    )
    for task in args.tasks:
        r = results["whole_2s"][task] = whole_2s(task, args.runs)
        a, b = r["ipm"], r["ipopt"]
        print(
            f"{task:5s} {'+'.join(s[:16] for s in a['status']):>34s} {'+'.join(map(str, a['iterations'])):>9s} "
            f"{a['solve_s_median']:6.2f} | {'+'.join(map(str, b['iterations'])):>9s} {b['solve_s_median']:6.2f} | "
            f"{r['objective_rel_diff']:8.1e} {r['max_abs_dq_rad']:7.3f}"
        )

    results["stage2_same_start"] = {}
    print(
        f"{'task':5s} {'stage 2 from IPOPT stage 1: IPM':>34s} {'its':>5s} {'ms/it':>6s} | {'IPOPT its':>9s} {'ms/it':>6s} | {'rel obj':>8s} {'max dq':>7s}"
    )
    for task in args.tasks:
        r = results["stage2_same_start"][task] = stage2_same_start(task)
        a, b = r["ipm"], r["ipopt"]
        print(
            f"{task:5s} {a['status'][:34]:>34s} {a['iterations']:5d} {a['ms_per_iteration']:6.1f} | "
            f"{b['iterations']:9d} {b['ms_per_iteration']:6.1f} | {r['objective_rel_diff']:8.1e} {r['max_abs_dq_rad']:7.1e}"
        )

    if not args.skip_spread:
        results["stage1_rounding_spread"] = {}
        print(
            f"{'task':5s} {'stage 1: IPOPT its (rounding variants)':>40s} {'optima':>8s} | {'IPM its':>7s} {'objective':>10s}"
        )
        for task in args.tasks:
            r = results["stage1_rounding_spread"][task] = rounding_spread(task)
            print(
                f"{task:5s} {' '.join(str(v['iterations']) for v in r['ipopt']):>40s} {len(r['ipopt_distinct_optima']):8d} | "
                f"{r['ipm']['iterations']:7d} {r['ipm']['objective']:10.4g}"
            )

    if not args.skip_compile:
        results["compile"] = c = compile_times()
        print(
            f"IPM compile at N=100: cold {c['cold_compile_s']:.1f} s, warm (persistent cache) {c['warm_compile_s']:.1f} s"
        )
    if not args.skip_batch:
        results["batch"] = bt = batch_throughput(args.batch)
        print(
            f"vmap batch of {bt['batch']}: {bt['batch_s']:.1f} s vs sequential {bt['sequential_s']:.1f} s "
            f"(x{bt['speedup_batch_over_sequential']:.2f}); success {bt['batch_success']}/{bt['batch']}"
        )
    write_record({"scheme": SCHEME, "N": 100, "results": results}, args.out)


if __name__ == "__main__":
    main()
