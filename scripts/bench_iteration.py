"""Benchmark: what one IPOPT iteration of the A,F+C,2S solve costs, and what a cold start compiles.

    OMP_NUM_THREADS=1 python scripts/bench_iteration.py [--tasks T1 T4] [--task-dir DIR] [--runs 3]
        [--parts evals kkt solve compile]
        [--variant NAME[,env:KEY=VALUE][,opt:KEY=VALUE][,lib:PATH|casadi][,sweeps:S][,solver:S] ...]
        [--kkt-iterations 60] [--start-dir DIR] [--out results/bench_iteration.json]

Each part is timed in CPU seconds (steady on a shared machine) and wall seconds:

* ``evals``: the callbacks of one IPOPT iteration (f and g, grad f and J, the Lagrangian Hessian)
  at the start of each task's dynamic stage (N = 100), with each derivative sweep (``joint``,
  ``grouped``), timed in alternation, median of 50 calls.
* ``kkt``: the dynamic stage of each task's 2S solve re-run from its own start for
  ``--kkt-iterations`` iterations, every variant (IPOPT library, IPOPT options) in one process in
  alternation: IPOPT's "PDSystemSolverTotal" (MUMPS's factorisations, inertia corrections and
  back-solves) and "Function Evaluations" per iteration.
* ``solve``: the task's A,F+C,2S solve in a fresh process per run and variant (variants alternate
  run by run), with IPOPT's ``print_timing_statistics``, per iteration of the first (pseudo-static)
  and the last (dynamic) stage. Paths move with rounding, so compare per iteration.
* ``compile``: ``jaxhumanoid solve --task T1`` in a fresh process with an empty compilation cache,
  once as the command line runs it and once with every clock of the solve reading CPU time:
  ``compile_time_s`` of its report (problem set-up, tracing and compilation).

A variant is a name and settings: ``env:KEY=VALUE`` sets an environment variable of the processes
it starts (``OPENBLAS_CORETYPE``; ``PYTHONPATH`` of another checkout runs that code),
``opt:KEY=VALUE`` an IPOPT option of every stage, ``lib:PATH`` the IPOPT library (``lib:casadi``
the casadi wheel's), ``sweeps:joint|grouped`` the derivative sweeps (kkt part), ``solver:ipm`` the
command line's ``--solver`` (compile part). ``--task-dir`` reads ``DIR/T1.toml`` ... (e.g. the reference posing of
another implementation) instead of the built-in tasks. The record (``--out``) carries the git
commit and the environment (``jaxhumanoid.runtime.environment``). This script imports no other
script.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import contextlib
import io
import json
import os
import pathlib
import re
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from jaxhumanoid.runtime import environment

ROOT = pathlib.Path(__file__).resolve().parent.parent
_TIMING_KEYS = ("OverallAlgorithm", "PDSystemSolverTotal", "Function Evaluations")


def _commit() -> dict:
    def git(*args):
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
        return out.stdout.strip() if out.returncode == 0 else None

    status = git("status", "--porcelain", "--untracked-files=no")
    return {"commit": git("rev-parse", "HEAD"), "dirty": bool(status) if status is not None else None}


def casadi_ipopt_library() -> str:
    """The IPOPT library of the casadi wheel (IPOPT 3.14.19, MUMPS with METIS)."""
    import casadi

    return str(next(pathlib.Path(casadi.__file__).parent.glob("libipopt.so*")))


def _parse_variant(text: str) -> dict:
    name, *specs = text.split(",")
    env, opts, lib = {}, {}, None
    named: dict[str, str | None] = {"sweeps": None, "solver": None}
    for spec in specs:
        kind, _, pair = spec.partition(":")
        if kind == "lib":
            lib = casadi_ipopt_library() if pair == "casadi" else pair
            continue
        if kind in named:
            named[kind] = pair
            continue
        key, _, val = pair.partition("=")
        if kind not in ("env", "opt") or not key or not _:
            raise SystemExit(
                f"--variant {text!r}: expected NAME[,env:KEY=VALUE][,opt:KEY=VALUE][,lib:PATH|casadi]"
                "[,sweeps:joint|grouped][,solver:ipopt|ipm|casadi]"
            )
        (env if kind == "env" else opts)[key] = val
    if lib:
        env["JAXHUMANOID_IPOPT_LIBRARY"] = lib
    return {"name": name, "env": env, "options": opts, "library": lib, **named}


def _solve_kwargs(task: str, task_dir: str | None) -> dict:
    from jaxhumanoid.strategy.taskfile import load_task_file, solve_kwargs

    if task_dir:
        return load_task_file(pathlib.Path(task_dir) / f"{task}.toml").as_solve_kwargs()
    return solve_kwargs(task)


def _option_value(val: str):
    for cast in (int, float):
        try:
            return cast(val)
        except ValueError:
            continue
    return val


def timing_statistics(log: str) -> list[dict]:
    """Every block of IPOPT's ``print_timing_statistics`` in ``log``: {key: (cpu, wall)} seconds
    of the entries in ``_TIMING_KEYS``, with the block's iteration count."""
    blocks = []
    for text in re.split(r"(?=^Number of Iterations\.+:)", log, flags=re.MULTILINE)[1:]:
        block = {"iterations": int(re.match(r"Number of Iterations\.+:\s*(\d+)", text).group(1))}
        for key in _TIMING_KEYS:
            m = re.search(re.escape(key) + r"\.*:\s+([\d.]+) \(sys:\s+[\d.]+ wall:\s+([\d.]+)\)", text)
            if m:
                block[key] = (float(m.group(1)), float(m.group(2)))
        if len(block) > 1:
            blocks.append(block)
    return blocks


def worker_solve(spec: dict) -> dict:
    """One 2S solve in this process (a fresh one per run), IPOPT's timing statistics per stage."""
    import jaxhumanoid as jh

    kw = _solve_kwargs(spec["task"], spec.get("task_dir"))
    options = {**(kw.pop("options") or {}), **spec["options"], "print_timing_statistics": "yes"}
    out = io.StringIO()
    c0, w0 = time.process_time(), time.perf_counter()
    with contextlib.redirect_stdout(out):
        sol = jh.solve(**{**kw, "scheme": "A,F+C,2S"}, options=options, verbose=True)
    stages = timing_statistics(out.getvalue())
    return {
        "success": bool(sol.success),
        "objective": float(sol.objective),
        "iterations": [int(s.iterations) for s in sol.stages],
        "compile_time_s": [float(s.compile_time_s) for s in sol.stages],
        "solve_time_s": [float(s.solve_time_s) for s in sol.stages],
        "timing": stages,
        "process_cpu_s": time.process_time() - c0,
        "process_wall_s": time.perf_counter() - w0,
        "blas_kernels": environment()["blas_kernels"],
    }


def _subprocess(args: list[str], env_extra: dict, cwd=None) -> tuple[subprocess.CompletedProcess, float, float]:
    env = {**os.environ, **env_extra}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    proc = subprocess.run(args, env=env, capture_output=True, text=True, cwd=cwd)
    wall = time.perf_counter() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return proc, cpu, wall


def part_solve(tasks, task_dir, variants, runs) -> list[dict]:
    rows = []
    for task in tasks:
        for run in range(runs):
            order = variants if run % 2 == 0 else variants[::-1]
            for var in order:
                spec = {
                    "task": task,
                    "task_dir": task_dir,
                    "options": {k: _option_value(v) for k, v in var["options"].items()},
                }
                proc, _, _ = _subprocess([sys.executable, __file__, "--worker-solve", json.dumps(spec)], var["env"])
                lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
                if proc.returncode != 0 or not lines:
                    print(f"  {task} {var['name']}: failed\n{proc.stderr[-2000:]}", file=sys.stderr)
                    continue
                res = json.loads(lines[-1])
                rows.append({"task": task, "variant": var["name"], "run": run, **res})
                final = res["timing"][-1] if res["timing"] else {}
                its = final.get("iterations", 0) or 1
                per = {k: 1e3 * final[k][0] / its for k in _TIMING_KEYS if k in final}
                print(
                    f"  {task} {var['name']:12s} run {run}: stage-2 its {final.get('iterations')}, CPU ms/it "
                    f"all {per.get('OverallAlgorithm', float('nan')):.2f} evals {per.get('Function Evaluations', float('nan')):.2f} "
                    f"KKT {per.get('PDSystemSolverTotal', float('nan')):.2f}, objective {res['objective']:.6g}",
                    flush=True,
                )
    return rows


def summarise_solve(rows: list[dict]) -> list[dict]:
    """Medians over runs, per task and variant, of IPOPT's timing split per iteration of the last
    (dynamic) and the first (pseudo-static) stage."""
    table = []
    for task in dict.fromkeys(r["task"] for r in rows):
        for var in dict.fromkeys(r["variant"] for r in rows if r["task"] == task):
            runs = [r for r in rows if r["task"] == task and r["variant"] == var and r["timing"]]
            entry: dict = {"task": task, "variant": var, "runs": len(runs), "objective": [r["objective"] for r in runs]}
            for stage, pick in (("stage 2", -1), ("stage 1", 0)):
                blocks = [r["timing"][pick] for r in runs]
                entry[f"{stage} iterations"] = [b["iterations"] for b in blocks]
                for key in _TIMING_KEYS:
                    for i, clock in enumerate(("cpu", "wall")):
                        vals = [1e3 * b[key][i] / max(b["iterations"], 1) for b in blocks if key in b]
                        if vals:
                            entry[f"{stage} {key} {clock} ms/it"] = {
                                "median": float(np.median(vals)),
                                "min": min(vals),
                                "max": max(vals),
                            }
            table.append(entry)
    print(
        f"\n{'task':5s} {'variant':12s} {'stage-2 its':>12s} {'stage 2 ms/it CPU: all':>23s} {'evals':>7s} {'KKT':>7s} "
        f"{'(wall: all':>11s} {'evals':>7s} {'KKT)':>7s} {'stage 1 ms/it CPU: all':>23s} {'evals':>7s}"
    )
    for e in table:

        def med(key, e=e):
            v = e.get(f"{key} ms/it")
            return v["median"] if v else float("nan")

        its = "/".join(str(i) for i in e["stage 2 iterations"])
        print(
            f"{e['task']:5s} {e['variant']:12s} {its:>12s} {med('stage 2 OverallAlgorithm cpu'):23.2f} "
            f"{med('stage 2 Function Evaluations cpu'):7.2f} {med('stage 2 PDSystemSolverTotal cpu'):7.2f} "
            f"{med('stage 2 OverallAlgorithm wall'):11.2f} {med('stage 2 Function Evaluations wall'):7.2f} "
            f"{med('stage 2 PDSystemSolverTotal wall'):7.2f} {med('stage 1 OverallAlgorithm cpu'):23.2f} "
            f"{med('stage 1 Function Evaluations cpu'):7.2f}"
        )
    return table


def worker_compile(spec: dict) -> None:
    """``jaxhumanoid solve`` in this (fresh) process, every clock of it reading this process's CPU
    time: the report's ``compile_time_s`` is then the CPU time of set-up, tracing and compilation
    (all threads), which a shared machine does not inflate as it does wall time."""
    time.perf_counter = time.process_time  # the solve's own timers, and only in this worker
    from jaxhumanoid.outputs.cli import main as cli

    cli(["solve", "--task", spec["task"], "--quiet", "--out", spec["out"], *spec["args"]])


def part_compile(variants, runs, task: str = "T1") -> list[dict]:
    """``jaxhumanoid solve --task T1`` cold (an empty compilation cache, a fresh process) per run and
    variant: once as the command line runs it (wall clock) and once with CPU clocks."""
    rows = []
    for run in range(runs):
        for var in variants if run % 2 == 0 else variants[::-1]:
            row = {"variant": var["name"], "run": run}
            for clock in ("wall", "cpu"):
                with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
                    env = {**var["env"], "JAXHUMANOID_CACHE": cache}
                    extra = [a for k, v in var["options"].items() for a in ("--ipopt-option", f"{k}={v}")]
                    extra += ["--solver", var["solver"]] if var.get("solver") else []
                    if clock == "wall":
                        args = [
                            sys.executable,
                            "-m",
                            "jaxhumanoid",
                            "solve",
                            "--task",
                            task,
                            "--quiet",
                            "--out",
                            out,
                            *extra,
                        ]
                    else:
                        spec = {"task": task, "out": out, "args": extra}
                        args = [
                            sys.executable,
                            str(pathlib.Path(__file__).resolve()),
                            "--worker-compile",
                            json.dumps(spec),
                        ]
                    proc, cpu, wall = _subprocess(args, env, cwd=out)  # not the checkout: PYTHONPATH decides
                    report = pathlib.Path(out) / "report.json"
                    if not report.exists():
                        print(f"  compile {var['name']} ({clock}): failed\n{proc.stderr[-2000:]}", file=sys.stderr)
                        continue
                    rep = json.loads(report.read_text())
                    row[f"compile_{clock}_s"] = float(rep["compile_time_s"])
                    row[f"stage_compile_{clock}_s"] = [float(s["compile_time_s"]) for s in rep["stages"]]
                    row[f"process_cpu_s ({clock} run)"] = cpu
                    row[f"process_wall_s ({clock} run)"] = wall
                    row["iterations"] = [s["iterations"] for s in rep["stages"]]
            rows.append(row)
            print(
                f"  compile {var['name']:12s} run {run}: compile_time_s {row.get('compile_wall_s', float('nan')):.1f} wall, "
                f"{row.get('compile_cpu_s', float('nan')):.1f} CPU (stages {row.get('stage_compile_cpu_s')}); "
                f"process CPU {row.get('process_cpu_s (wall run)', float('nan')):.1f} s, "
                f"wall {row.get('process_wall_s (wall run)', float('nan')):.1f} s",
                flush=True,
            )
    for var in dict.fromkeys(r["variant"] for r in rows):
        mine = [r for r in rows if r["variant"] == var]

        def med(key, mine=mine):
            vals = [r[key] for r in mine if key in r]
            return float(np.median(vals)) if vals else float("nan")

        print(
            f"compile {var:12s}: compile_time_s median {med('compile_wall_s'):.1f} s wall, {med('compile_cpu_s'):.1f} s CPU; "
            f"process CPU {med('process_cpu_s (wall run)'):.1f} s, wall {med('process_wall_s (wall run)'):.1f} s over {len(mine)} runs"
        )
    return rows


def final_stage(task: str, task_dir: str | None) -> dict:
    """The task's A,F+C,2S solved once; returns the last IPOPT solve it ran (its dynamic stage)
    as the strategy posed it: nlp, p, bounds, x0, options (captured by wrapping ``solve_ipopt``
    wherever the package refers to it)."""
    import jaxhumanoid as jh
    from jaxhumanoid.solvers import ipopt as ip

    orig, calls = ip.solve_ipopt, []

    def spy(nlp, p, bounds, x0=None, options=None, **kw):
        start = np.array(bounds.x0 if x0 is None else x0, dtype=float)
        calls.append({"nlp": nlp, "p": p, "bounds": bounds, "x0": start, "options": dict(options or {})})
        return orig(nlp, p, bounds, x0=x0, options=options, **kw)

    holders = [
        m
        for name, m in list(sys.modules.items())
        if name.startswith("jaxhumanoid") and getattr(m, "solve_ipopt", None) is orig
    ]
    for m in holders:
        m.solve_ipopt = spy
    try:
        kw = _solve_kwargs(task, task_dir)
        with contextlib.redirect_stdout(io.StringIO()):
            jh.solve(**{**kw, "scheme": "A,F+C,2S"})
    finally:
        for m in holders:
            m.solve_ipopt = orig
    return calls[-1]


def part_kkt(tasks, task_dir, variants, runs, iterations: int, start_dir: str | None = None) -> list[dict]:
    """IPOPT's KKT solves and evaluations per iteration, every variant (IPOPT library, IPOPT
    options, derivative sweeps; ``env:`` settings do not apply) in this process in alternation:
    the dynamic stage (N = 100) of each task's 2S solve from its own start (``final_stage``),
    ``iterations`` iterations. With ``start_dir`` the start is read from (or, absent, written to)
    ``start_dir/<task>.pkl``, so that another checkout (``PYTHONPATH``) runs from the same start."""
    import pickle

    from jaxhumanoid.solvers.ipopt import solve_ipopt
    from jaxhumanoid.strategy.problem import build_problem, with_sweeps

    rows = []
    for task in tasks:
        saved = pathlib.Path(start_dir) / f"{task}.pkl" if start_dir else None
        if saved is not None and saved.exists():
            st = pickle.loads(saved.read_bytes())
        else:
            st = final_stage(task, task_dir)
            if saved is not None:
                saved.parent.mkdir(parents=True, exist_ok=True)
                saved.write_bytes(pickle.dumps({k: st[k] for k in ("p", "bounds", "x0", "options")}))
        kw = _solve_kwargs(task, task_dir)
        problem = build_problem(
            kw["task"], "A,F+C,1S", N=100, model=kw.get("model"), foot=kw.get("foot"), guess="linear"
        )
        base_opts = {**st["options"], "max_iter": iterations, "print_timing_statistics": "yes"}
        for run in range(runs):
            for var in variants if run % 2 == 0 else variants[::-1]:
                opts = {**base_opts, **{k: _option_value(v) for k, v in var["options"].items()}}
                nlp = with_sweeps(problem, var["sweeps"]).nlp if var.get("sweeps") else problem.nlp
                lib = {"library_path": var["library"]} if var.get("library") else {}
                res = solve_ipopt(nlp, st["p"], st["bounds"], x0=st["x0"], options=opts, **lib)
                stats = timing_statistics(res.log)[-1]
                its = max(stats["iterations"], 1)
                row = {
                    "task": task,
                    "variant": var["name"],
                    "run": run,
                    "iterations": stats["iterations"],
                    "status": res.status,
                }
                for key in _TIMING_KEYS:
                    row[f"{key} cpu ms/it"] = 1e3 * stats[key][0] / its
                    row[f"{key} wall ms/it"] = 1e3 * stats[key][1] / its
                rows.append(row)
                print(
                    f"  kkt {task} {var['name']:12s} run {run}: {stats['iterations']} its, KKT CPU "
                    f"{row['PDSystemSolverTotal cpu ms/it']:.2f} ms/it (wall {row['PDSystemSolverTotal wall ms/it']:.2f}), "
                    f"evaluations {row['Function Evaluations cpu ms/it']:.2f}, iteration {row['OverallAlgorithm cpu ms/it']:.2f}",
                    flush=True,
                )
    print(f"\n{'task':5s} {'variant':12s} {'KKT CPU ms/it':>14s} {'(min-max)':>14s} {'evals':>7s} {'iteration':>10s}")
    for task in tasks:
        for var in variants:
            mine = [r for r in rows if r["task"] == task and r["variant"] == var["name"]]
            kkt = [r["PDSystemSolverTotal cpu ms/it"] for r in mine]
            ev = [r["Function Evaluations cpu ms/it"] for r in mine]
            it = [r["OverallAlgorithm cpu ms/it"] for r in mine]
            print(
                f"{task:5s} {var['name']:12s} {np.median(kkt):14.2f} {min(kkt):6.2f}-{max(kkt):<6.2f} "
                f"{np.median(ev):7.2f} {np.median(it):10.2f}"
            )
    return rows


def part_evals(tasks, task_dir) -> list[dict]:
    """The callbacks of one IPOPT iteration at the start of each task's dynamic stage
    (``final_stage``), with each derivative sweep, timed in alternation (50 rounds)."""
    import jax

    from jaxhumanoid.strategy.problem import build_problem, with_sweeps

    rows = []
    for task in tasks:
        st = final_stage(task, task_dir)
        kw = _solve_kwargs(task, task_dir)
        base = build_problem(kw["task"], "A,F+C,1S", N=100, model=kw.get("model"), foot=kw.get("foot"), guess="linear")
        p, x = st["p"], st["x0"]
        lam = np.random.default_rng(0).normal(size=st["nlp"].m)
        calls = {}
        for sweeps in ("joint", "grouped"):
            nlp = with_sweeps(base, sweeps).nlp
            assert nlp.n == st["nlp"].n and nlp.m == st["nlp"].m, "the dynamic stage is A,F+C on N = 100"
            ev = nlp.jitted()
            calls[(sweeps, "f+g")] = lambda ev=ev: ev.fg(x, p)
            calls[(sweeps, "grad+J")] = lambda ev=ev: ev.grad_jac(x, p)
            calls[(sweeps, "H")] = lambda ev=ev: ev.hess(x, lam, 1.0, p)
        for fn in calls.values():
            jax.block_until_ready(fn())
        cpu: dict = {k: [] for k in calls}
        wall: dict = {k: [] for k in calls}
        keys, rng = list(calls), np.random.default_rng(0)
        for _ in range(50):
            rng.shuffle(keys)
            for k in keys:
                c0, w0 = time.process_time(), time.perf_counter()
                jax.tree_util.tree_map(np.asarray, calls[k]())
                cpu[k].append(1e3 * (time.process_time() - c0))
                wall[k].append(1e3 * (time.perf_counter() - w0))
        for sweeps, name in calls:
            rows.append(
                {
                    "task": task,
                    "sweeps": sweeps,
                    "call": name,
                    "cpu_ms": float(np.median(cpu[(sweeps, name)])),
                    "wall_ms": float(np.median(wall[(sweeps, name)])),
                }
            )
        print(f"\n{task}: callbacks at the start of the dynamic stage (N = 100), median ms of 50 (CPU / wall)")
        for sweeps in ("joint", "grouped"):
            mine = {r["call"]: r for r in rows if r["task"] == task and r["sweeps"] == sweeps}
            total = sum(r["cpu_ms"] for r in mine.values())
            print(
                f"  {sweeps:8s} "
                + "  ".join(f"{k} {r['cpu_ms']:.2f}/{r['wall_ms']:.2f}" for k, r in mine.items())
                + f"  sum CPU {total:.2f}"
            )
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="*", default=["T1", "T4"])
    ap.add_argument("--task-dir", default=None, help="read DIR/<task>.toml instead of the built-in tasks")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument(
        "--parts", nargs="*", default=["evals", "solve", "compile"], choices=["evals", "kkt", "solve", "compile"]
    )
    ap.add_argument("--kkt-iterations", type=int, default=60, help="iterations of each run of the kkt part")
    ap.add_argument("--start-dir", default=None, help="kkt part: read (or write) each task's start there")
    ap.add_argument(
        "--variant", action="append", default=None, help="NAME[,env:KEY=VALUE][,opt:KEY=VALUE][,solver:S] (repeatable)"
    )
    ap.add_argument("--out", default="results/bench_iteration.json")
    ap.add_argument("--worker-solve", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--worker-compile", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker_solve:
        print(json.dumps(worker_solve(json.loads(args.worker_solve))))
        return
    if args.worker_compile:
        worker_compile(json.loads(args.worker_compile))
        return
    variants = [_parse_variant(v) for v in (args.variant or ["default"])]
    record = {"argv": sys.argv[1:], **_commit(), "environment": environment(), "variants": variants}
    if "evals" in args.parts:
        record["evals"] = part_evals(args.tasks, args.task_dir)
    if "kkt" in args.parts:
        record["kkt"] = part_kkt(args.tasks, args.task_dir, variants, args.runs, args.kkt_iterations, args.start_dir)
    if "solve" in args.parts:
        record["solve_runs"] = part_solve(args.tasks, args.task_dir, variants, args.runs)
        record["solve"] = summarise_solve(record["solve_runs"])
    if "compile" in args.parts:
        record["compile"] = part_compile(variants, args.runs)
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
