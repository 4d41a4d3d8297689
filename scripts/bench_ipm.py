"""Benchmark: the own interior-point method (IPM) against IPOPT on the same NLPs, in one run.

    OMP_NUM_THREADS=1 python scripts/bench_ipm.py [--problems T1 T2 T3 T4 ref:T1 ref:T2 ref:T3 ref:T4]
        [--runs 3] [--compile-runs 3] [--compile-tasks T1 ref:T1] [--parts stage2 compile]
        [--ref-dir ../shared/reference_posing] [--out results/bench_ipm.json]

Problems: a built-in task key (``T1``..``T4``, as posed) or ``ref:T1`` .. for
``<ref-dir>/T1.toml`` (the reference posing). Parts (``--parts``):

- ``stage2``: stage 2 of A,F+C,2S from the same start for both solvers: the last NLP of a
  direct-hand-over 2S solve by IPOPT (stage 1 by IPOPT), with the options that solve gives it
  (the task file's included). The IPM without a progress callback (``ipm``: its loop in one call)
  and as the command line runs it, with one (``ipm_cli``: the same loop a chunk at a time), and IPOPT are
  solved in alternation, ``--runs`` times each after one warm-up, timed by CPU time of this
  process and by wall time. Also the counts that set an iteration's cost: the IPM's
  factorisations (inertia-correction trials), line-search trial points (each an evaluation of f
  and g), second-order corrections and restoration iterations; IPOPT's function, gradient,
  Jacobian and Hessian evaluations and its own timing statistics.
- ``compile``: ``jaxhumanoid solve --task T1 --solver ipm`` (each of ``--compile-tasks``) in a
  fresh process with an empty compilation cache, ``--compile-runs`` times: each stage's compile
  time from its report, the process's CPU and wall time.
- ``programs``: the programs the IPM compiles for the final NLP of each of ``--compile-tasks``
  (``N`` = 100, nothing solved): the four parts of its core (prepare, start, advance, finish),
  each traced and compiled in this process: trace and lowering seconds,
  XLA compile CPU seconds, lines of StableHLO, and the kernels (fusions) of the optimised HLO.
- ``spread``: stage 1 of the benchmark tasks by IPOPT under options that change only the
  rounding of its linear solves, and by the IPM (the spread of IPOPT's own iteration counts).
- ``batch``: a ``vmap`` batch of T1 stage-1 problems against the same problems one by one.
- ``pivots``: how the IPM's factorisations pivot over a whole stage-2 solve of each problem: the
  pivot blocks on the quasi-definite fast path, and those eigen-decomposed by the inertia found.

Prints a table per part and writes a JSON record (``--out``) with the git commit and the
environment (``jaxhumanoid.runtime.environment``).
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import collections
import dataclasses
import functools
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile
import time
from unittest import mock

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.runtime import enable_compilation_cache, environment
from jaxhumanoid.solvers.ipm import batch_solve_ipm, solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.handover import STAGE2_DEFAULTS
from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.studies.bench import (
    BENCH_STAGE1_OPTIONS,
    bench_settings,
    git_state,
    recorded_solve,
    stage1_problem,
)

SCHEME = "A,F+C,2S"
REPO = pathlib.Path(__file__).resolve().parents[1]
REF_DIR = REPO.parent.parent / "shared" / "reference_posing"


# ----------------------------------------------------------------------------- problems
def solve_kwargs_of(name: str, ref_dir: pathlib.Path) -> dict:
    if name.startswith("ref:"):
        return load_task_file(ref_dir / f"{name[4:]}.toml").as_solve_kwargs()
    return {"task": name}


def stage2_start(name: str, ref_dir: pathlib.Path):
    """(problem, x0, options) of the last solve of a direct-hand-over 2S solve by IPOPT: stage 2
    from IPOPT's stage 1, with the options that stage gets."""
    kw = solve_kwargs_of(name, ref_dir)
    settings = bench_settings(kw.get("settings")).replace(stage1_solver="ipopt", handover="direct")
    _, runs = recorded_solve(**{**kw, "solver": "ipopt", "settings": settings})
    return runs[-1].problem, runs[-1].x0, runs[-1].options


# ----------------------------------------------------------------------------- stage 2
IPOPT_COUNTS = {
    "f": "objective function evaluations",
    "g": "equality constraint evaluations",
    "grad": "objective gradient evaluations",
    "jac": "equality constraint Jacobian evaluations",
    "hess": "Lagrangian Hessian evaluations",
}
IPOPT_TIMERS = ("OverallAlgorithm", "PDSystemSolverTotal", "Function Evaluations", "ComputeAcceptableTrialPoint")


def ipopt_counts(log: str) -> dict:
    """IPOPT's evaluation counts, CPU seconds of its timers and the iterations whose KKT matrix it
    regularised (its iteration lines with a value under lg(rg): at least two factorisations each,
    as the IPM's ``regularized_iterations``), read from its log."""
    lines = re.findall(r"^\s*(\d+)r?\s+\S+\s+\S+\s+\S+\s+\S+\s+\S+\s+(\S+)\s", log, re.M)
    out: dict = {"regularized_iterations": sum(rg != "-" for k, rg in lines if int(k) > 0)}
    for key, text in IPOPT_COUNTS.items():
        m = re.search(rf"Number of {text}\s*=\s*(\d+)", log)
        out[key] = int(m.group(1)) if m else None
    for key in IPOPT_TIMERS:
        m = re.search(rf"^{re.escape(key)}\.*:\s*([\d.]+)", log, re.M)
        out[f"{key}_cpu_s"] = float(m.group(1)) if m else None
    return out


def ipm_counts(r) -> dict:
    """The IPM's per-solve counts from its history (iterations 1..k)."""
    h, k = r.history, r.iterations
    kind = np.asarray(h["kind"][1 : k + 1])
    return {
        "factorizations": int(np.sum(h["n_fact"][1 : k + 1])),
        "trial_points": int(np.sum(h["ls"][1 : k + 1])),
        "soc_steps": int(np.sum((kind == ord("F")) | (kind == ord("H")))),
        "restoration_iterations": int(np.sum(h["mode"][1 : k + 1])),
        "regularized_iterations": int(np.sum(np.asarray(h["reg"][1 : k + 1]) > 0)),
    }


def timed(fn):
    c0, t0 = time.process_time(), time.perf_counter()
    r = fn()
    return r, time.process_time() - c0, time.perf_counter() - t0


def stage2_case(name: str, runs: int, ref_dir: pathlib.Path) -> dict:
    """The three solvers on one stage-2 NLP from the same start, in alternation."""
    problem, x0, opts = stage2_start(name, ref_dir)
    nlp, p, b = problem.nlp, problem.p, problem.bounds
    io = {**opts, "print_timing_statistics": "yes"}
    solvers = {
        "ipm": lambda: solve_ipm(nlp, p, b, x0=x0, options=opts),
        "ipm_cli": lambda: solve_ipm(nlp, p, b, x0=x0, options=opts, progress=lambda k, f, inf: None),
        "ipopt": lambda: solve_ipopt(nlp, p, b, x0=x0, options=io),
    }
    samples: dict = {k: {"cpu": [], "wall": []} for k in solvers}
    last = {k: f() for k, f in solvers.items()}  # compile / jit the callbacks
    for _ in range(runs):
        for k, f in solvers.items():
            last[k], cpu, wall = timed(f)
            samples[k]["cpu"].append(cpu)
            samples[k]["wall"].append(wall)
    out: dict = {"options": opts, "n": nlp.n, "m": nlp.m}
    for k, r in last.items():
        its = max(r.iterations, 1)
        out[k] = {
            "status": r.status,
            "iterations": int(r.iterations),
            "objective": float(r.objective),
            "cpu_ms_per_iteration": [c / its * 1e3 for c in samples[k]["cpu"]],
            "wall_ms_per_iteration": [w / its * 1e3 for w in samples[k]["wall"]],
            "cpu_ms_per_iteration_median": float(np.median(samples[k]["cpu"])) / its * 1e3,
            "wall_ms_per_iteration_median": float(np.median(samples[k]["wall"])) / its * 1e3,
            **(ipopt_counts(r.log or "") if k == "ipopt" else ipm_counts(r)),
        }
    a, c = last["ipm"], last["ipopt"]
    out["objective_rel_diff"] = abs(a.objective - c.objective) / max(abs(c.objective), 1e-12)
    out["max_abs_dx"] = float(np.max(np.abs(np.asarray(a.x) - np.asarray(c.x))))
    for k in ("ipm", "ipm_cli"):
        for t in ("cpu", "wall"):
            out[f"ratio_{k}_over_ipopt_{t}"] = (
                out[k][f"{t}_ms_per_iteration_median"] / out["ipopt"][f"{t}_ms_per_iteration_median"]
            )
    return out


def print_stage2(res: dict) -> None:
    print(
        f"{'problem':8s} {'IPM its':>7s} {'IPOPT its':>9s} | {'ms/it CPU: IPM':>14s} {'IPM cli':>7s} {'IPOPT':>6s}"
        f" {'ratio':>5s} {'cli':>5s} | {'wall ratio':>10s} | {'fact/it':>7s} {'trials/it':>9s} {'IPOPT f/it':>10s}"
        f" {'soc':>4s} {'resto':>5s} {'reg. its IPM/IPOPT':>18s} | {'rel obj':>8s}"
    )
    for name, r in res.items():
        a, c, cl = r["ipm"], r["ipopt"], r["ipm_cli"]
        k, kc = max(a["iterations"], 1), max(c["iterations"], 1)
        print(
            f"{name:8s} {a['iterations']:7d} {c['iterations']:9d} | {a['cpu_ms_per_iteration_median']:14.1f}"
            f" {cl['cpu_ms_per_iteration_median']:7.1f} {c['cpu_ms_per_iteration_median']:6.1f}"
            f" {r['ratio_ipm_over_ipopt_cpu']:5.2f} {r['ratio_ipm_cli_over_ipopt_cpu']:5.2f} |"
            f" {r['ratio_ipm_over_ipopt_wall']:10.2f} | {a['factorizations'] / k:7.2f} {a['trial_points'] / k:9.2f}"
            f" {(c['f'] or 0) / kc:10.2f} {a['soc_steps']:4d} {a['restoration_iterations']:5d}"
            f" {a['regularized_iterations']:>9d}/{c['regularized_iterations']:<8d} |"
            f" {r['objective_rel_diff']:8.1e}"
        )


# ----------------------------------------------------------------------------- compile
def cold_compile(name: str, ref_dir: pathlib.Path, python: str = sys.executable) -> dict:
    """``jaxhumanoid solve ... --solver ipm`` by the interpreter ``python`` in a fresh process with
    an empty compilation cache: the compile time of each stage (its report) and the process's
    CPU and wall time."""
    task = ["--task-file", str(ref_dir / f"{name[4:]}.toml")] if name.startswith("ref:") else ["--task", name]
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "JAXHUMANOID_CACHE": str(pathlib.Path(tmp) / "cache")}
        cmd = [python, "-m", "jaxhumanoid", "solve", *task, "--solver", "ipm", "--quiet", "--out", tmp]
        before = os.times()
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=False, capture_output=True)
        wall = time.perf_counter() - t0
        after = os.times()
        report = json.loads((pathlib.Path(tmp) / "report.json").read_text())
    stages = [
        {"name": s["name"], "compile_s": s["compile_time_s"], "iterations": s["iterations"]} for s in report["stages"]
    ]
    ipm = [s for s in stages if s["name"].startswith("stage 2") or name.startswith("ref:")]
    return {
        "stages": stages,
        "compile_s": report["compile_time_s"],
        "compile_s_ipm_stages": sum(s["compile_s"] for s in ipm),
        "process_cpu_s": (after.children_user + after.children_system)
        - (before.children_user + before.children_system),
        "process_wall_s": wall,
    }


def compile_part(tasks: list[str], runs: int, ref_dir: pathlib.Path, baseline: str | None) -> dict:
    """``cold_compile`` of each task ``runs`` times, in alternation with the interpreter
    ``baseline`` (another environment, e.g. the last release's) where given (rows "<task> baseline")."""
    srcs = {"": sys.executable} if baseline is None else {"": sys.executable, " baseline": baseline}
    rows: dict = {f"{t}{label}": [] for t in tasks for label in srcs}
    for _ in range(runs):
        for t in tasks:
            for label, src in srcs.items():
                rows[f"{t}{label}"].append(cold_compile(t, ref_dir, src))
    out = {}
    print(
        f"{'cold solve --solver ipm':24s} {'compile s (median)':>18s} {'IPM stages':>10s} {'process CPU s':>13s} {'runs':>24s}"
    )
    for t, r in rows.items():
        out[t] = {
            "runs": r,
            **{
                f"{k}_median": float(np.median([x[k] for x in r]))
                for k in ("compile_s", "compile_s_ipm_stages", "process_cpu_s")
            },
        }
        each = ", ".join(f"{x['compile_s']:.1f}" for x in r)
        print(
            f"{t:24s} {out[t]['compile_s_median']:18.1f} {out[t]['compile_s_ipm_stages_median']:10.1f}"
            f" {out[t]['process_cpu_s_median']:13.1f} {each:>24s}"
        )
    return out


# ----------------------------------------------------------------------------- programs
def program_sizes(name: str, fn, *args) -> dict:
    """Trace + lower ``fn`` (a jitted function) at ``args`` and compile it: seconds (compile as
    CPU time of this process: XLA's codegen threads included), StableHLO lines and fusions."""
    t0 = time.perf_counter()
    lowered = fn.lower(*args)
    trace = time.perf_counter() - t0
    c0, t0 = time.process_time(), time.perf_counter()
    compiled = lowered.compile()
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    hlo = compiled.as_text()
    row = {
        "program": name,
        "trace_s": trace,
        "compile_cpu_s": cpu,
        "compile_wall_s": wall,
        "stablehlo_lines": lowered.as_text().count("\n"),
        "fusions": len(re.findall(r"^\s+%\S+ = .* fusion\(", hlo, re.M)),
    }
    print(
        f"{name:10s} trace {trace:5.2f} s  compile CPU {cpu:6.2f} s (wall {wall:6.2f})"
        f"  {row['stablehlo_lines']:6d} lines  {row['fusions']:5d} fusions"
    )
    return row


def programs_part(tasks: list[str], ref_dir: pathlib.Path) -> dict:
    """``program_sizes`` of the IPM's programs on each task's final NLP (stage 2's structure)."""
    from jaxhumanoid.solvers.ipm import driver
    from jaxhumanoid.solvers.ipm.options import as_float64, make_options
    from jaxhumanoid.solvers.ipm.state import Evals
    from jaxhumanoid.strategy.problem import build_problem

    out = {}
    for name in tasks:
        kw = solve_kwargs_of(name, ref_dir)
        task = kw.get("task", "T1")
        final = build_problem(task, SCHEME, N=int(kw.get("N", 100)), guess="linear")
        nlp, p, b = final.nlp, final.p, final.bounds
        o = as_float64(make_options(dict(STAGE2_DEFAULTS)))
        data = [jnp.asarray(a, float) for a in (b.x0, b.xl, b.xu, b.gl, b.gu)]
        core = driver._stepped_core(nlp)
        fns = core["nlp"]
        rows = [program_sizes("prepare", core["prepare"], *data, o)]
        B = core["prepare"](*data, o)
        at_x0 = fns.grad_jac(B.x0, p)
        f, g = fns.fg(B.x, p)
        grad, jac = fns.grad_jac(B.x, p)
        raw = Evals(f=f, g=g, grad=grad, jac=jac)
        rows.append(program_sizes("start", core["start"], B, p, at_x0, raw, o))
        S, P = core["start"](B, p, at_x0, raw, o)
        rows.append(program_sizes("advance", core["advance"], P, S, o, jnp.asarray(1, jnp.int32)))
        rows.append(program_sizes("finish", core["finish"], P, S, o))
        out[name] = rows
    return out


# ----------------------------------------------------------------------------- spread, batch
ROUNDING_VARIANTS = ({}, {"mumps_scaling": 0}, {"mumps_pivtol": 1e-5}, {"mumps_permuting_scaling": 0})


def rounding_spread(task: str) -> dict:
    """Stage 1 of ``stage1_problem(task)`` with IPOPT under ``ROUNDING_VARIANTS`` and with the IPM."""
    first, _ = stage1_problem(task)
    runs = []
    for extra in ROUNDING_VARIANTS:
        r = solve_ipopt(first.nlp, first.p, first.bounds, options={**BENCH_STAGE1_OPTIONS, **extra})
        runs.append(
            {"options": extra, "status": r.status, "iterations": int(r.iterations), "objective": float(r.objective)}
        )
    r = solve_ipm(first.nlp, first.p, first.bounds, options=BENCH_STAGE1_OPTIONS)
    print(f"{task}: IPOPT its {[v['iterations'] for v in runs]}, IPM its {r.iterations} objective {r.objective:.4g}")
    return {
        "ipopt": runs,
        "ipm": {"status": r.status, "iterations": int(r.iterations), "objective": float(r.objective)},
    }


def batch_throughput(batch: int) -> dict:
    """A vmap batch of T1 stage-1 problems with log-normally perturbed weights (sigma = 0.2)."""
    prob, _ = stage1_problem("T1")
    rng = np.random.default_rng(0)
    weights = np.asarray(prob.p.weights)[None] * np.exp(0.2 * rng.standard_normal((batch, np.size(prob.p.weights))))
    p_batch = jax.tree.map(lambda a: jnp.broadcast_to(a, (batch,) + jnp.shape(a)), prob.p)
    p_batch = dataclasses.replace(p_batch, weights=jnp.asarray(weights))
    opts = dict(BENCH_STAGE1_OPTIONS)
    batch_solve_ipm(prob.nlp, p_batch, prob.bounds, options=opts)  # compile
    res_b, _, t_batch = timed(lambda: batch_solve_ipm(prob.nlp, p_batch, prob.bounds, options=opts))
    members = [jax.tree.map(lambda a, i=i: a[i], p_batch) for i in range(batch)]
    solve_ipm(prob.nlp, members[0], prob.bounds, options=opts)  # compile
    res_s, _, t_seq = timed(lambda: [solve_ipm(prob.nlp, q, prob.bounds, options=opts) for q in members])
    print(f"vmap batch of {batch}: {t_batch:.1f} s against {t_seq:.1f} s one by one")
    return {
        "batch": batch,
        "batch_s": t_batch,
        "sequential_s": t_seq,
        "batch_success": int(sum(r.success for r in res_b)),
        "sequential_success": int(sum(r.success for r in res_s)),
    }


# the pivot blocks counted by ``pivot_census``; one counter for the process, since problems of one
# layout share the IPM's compiled programs and with them the callback traced first
PIVOTS: collections.Counter = collections.Counter()


# larger gammas of the fast path (``pivot.quasidefinite_block``) tried on each eigen-decomposed block
RETRY_GAMMAS = (100.0, 300.0, 1000.0, 3000.0, 10000.0)


def _tally(info, certified, nc):
    nneg, nzero, path = (int(v) for v in info)
    if path != 2:
        PIVOTS["fast"] += 1
        return
    kind = "eig_zero" if nzero else ("eig_more_negative" if nneg > nc else "eig_fast_inertia")
    PIVOTS[kind] += 1
    for gamma, ok in zip(RETRY_GAMMAS, certified, strict=True):
        if bool(ok):
            PIVOTS[f"{kind}_certified_by_gamma_{gamma:g}"] += 1
            break


def pivot_census(name: str, ref_dir: pathlib.Path) -> dict:
    """How the IPM's factorisations pivot over a whole stage-2 solve (``stage2_start``): the pivot blocks on the quasi-definite fast path and those
    eigen-decomposed, the latter split by the inertia the decomposition finds (the fast path's
    (nbx, nc, 0), more negative eigenvalues, zero ones) and by the smallest of ``RETRY_GAMMAS`` at
    which the fast path would have certified it. Each block is counted by a
    ``jax.debug.callback`` in the block loop (``elimination._eliminate`` wrapped here), which
    changes no value; the solve compiles its own programs for it."""
    from jaxhumanoid.solvers.ipm.kkt import elimination
    from jaxhumanoid.solvers.ipm.kkt.pivot import quasidefinite_block
    from jaxhumanoid.solvers.ipm.kkt.structure import static_index2

    eliminate = elimination._eliminate

    def counted(st, sc, k, C, X, diag_r, fast, rel_zero_tol):
        out = eliminate(st, sc, k, C, X, diag_r, fast, rel_zero_tol)
        Dk = elimination._filled_block(sc.A[k], C, static_index2(st.b_rows, st.b_rows))
        certified = jnp.stack([quasidefinite_block(Dk, st.nbx, gamma=g)[1] for g in RETRY_GAMMAS])
        jax.debug.callback(functools.partial(_tally, nc=st.nb - st.nbx), out[5], certified)
        return out

    problem, x0, opts = stage2_start(name, ref_dir)
    PIVOTS.clear()
    with mock.patch.object(elimination, "_eliminate", counted):
        r = solve_ipm(problem.nlp, problem.p, problem.bounds, x0=x0, options=opts)
    out = {"iterations": int(r.iterations), "objective": float(r.objective), **ipm_counts(r), **PIVOTS}
    print(
        f"{name}: {out['iterations']} iterations, {out['factorizations']} factorisations; pivot blocks: "
        f"{PIVOTS['fast']} fast, eigen-decomposed {PIVOTS['eig_fast_inertia']} with the fast path's inertia, "
        f"{PIVOTS['eig_more_negative']} with more negative eigenvalues, {PIVOTS['eig_zero']} singular"
    )
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--problems", nargs="+", default=["T1", "T2", "T3", "T4", "ref:T1", "ref:T2", "ref:T3", "ref:T4"])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--compile-tasks", nargs="+", default=["T1"])
    ap.add_argument("--compile-runs", type=int, default=3)
    ap.add_argument(
        "--compile-baseline", help="the python of another environment (e.g. with the last release) to compare with"
    )
    ap.add_argument(
        "--parts",
        nargs="+",
        default=["stage2", "compile"],
        choices=["stage2", "compile", "programs", "spread", "batch", "pivots"],
    )
    ap.add_argument("--spread-tasks", nargs="+", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--ref-dir", type=pathlib.Path, default=REF_DIR)
    ap.add_argument("--out", default="results/bench_ipm.json")
    args = ap.parse_args()
    record: dict = {"git": git_state(), "environment": environment(), "argv": sys.argv[1:], "scheme": SCHEME}
    if "compile" in args.parts:  # first: fresh processes, before this one loads the machine
        record["compile"] = compile_part(args.compile_tasks, args.compile_runs, args.ref_dir, args.compile_baseline)
    if "programs" in args.parts:  # before the persistent cache is on
        record["programs"] = programs_part(args.compile_tasks, args.ref_dir)
    enable_compilation_cache()
    if "stage2" in args.parts:
        record["stage2"] = res = {}
        for name in args.problems:
            res[name] = stage2_case(name, args.runs, args.ref_dir)
        print_stage2(res)
    if "pivots" in args.parts:
        record["pivots"] = {name: pivot_census(name, args.ref_dir) for name in args.problems}
    if "spread" in args.parts:
        record["stage1_rounding_spread"] = {t: rounding_spread(t) for t in args.spread_tasks}
    if "batch" in args.parts:
        record["batch"] = batch_throughput(args.batch)
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2, default=str) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
