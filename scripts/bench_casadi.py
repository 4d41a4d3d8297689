"""Benchmark: the CasADi backend per stage-2 iteration, against the project's IPOPT path and (optionally)
an earlier version of the backend, from the same start, side by side in one run.

    OMP_NUM_THREADS=1 python scripts/bench_casadi.py [--dir ../shared/reference_posing] [--tasks T1 T2 T3 T4]
        [--runs 3] [--baseline REV] [--out results/bench_casadi.json]

For each task file DIR/<task>.toml: the stage-2 NLP (dynamic, nominal law, N = 100) and its start
as ``jaxhumanoid solve --task-file DIR/<task>.toml --solver ipopt`` poses them (IPOPT's stage-1
solution, interpolated; captured from the strategy's solver calls, stage 2 is not run there). Then
``--runs`` rounds, each solving that NLP from that start once with every backend in a new random
order, with the task file's stage-2 options:

* ``casadi``: ``validation.casadi_backend.solve_casadi`` of this checkout;
* ``casadi@REV`` (with ``--baseline REV``): the backend module as it was at the git revision REV,
  loaded from ``git show`` (the rest of the package of this checkout);
* ``ipopt``: the project's IPOPT path (``solvers.ipopt.solve_ipopt``, JAX derivatives).

Every run sets IPOPT's ``print_timing_statistics``; the table gives medians over the runs of IPOPT's
own figures per iteration: CPU time of the whole algorithm (``OverallAlgorithm``, the steadier figure
on a shared machine), its wall time, the NLP function evaluations and the KKT solves
(``PDSystemSolverTotal``), each divided by IPOPT's iteration count; the backend's build (graph
and solver construction; the JAX path compiles once before the runs); and the largest difference
of the joint angles from the IPOPT path's solution. ``/ ref`` divides by the independent CasADi SX
implementation's wall time per iteration (``REFERENCE_MS``, and its function evaluations'
share ``REFERENCE_EVAL_SHARE``), measured on an idle machine: CPU time is what compares on a
shared one, and only where both take similar paths (regularised iterations factorise more than
once). Writes a JSON record with the git commit and the environment (``--out``).
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import contextlib
import importlib.util
import json
import pathlib
import re
import subprocess
import sys
import tempfile
import time
from unittest import mock

import numpy as np

import jaxhumanoid as jh
from jaxhumanoid.runtime import environment
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.runner import Runner
from jaxhumanoid.validation.casadi_backend import solve_casadi

# Stage-2 wall time per iteration of the independent CasADi SX + IPOPT 3.14.19/MUMPS implementation and
# the share of its function evaluations (its README, reference_posing/README.md), idle 2-core machine,
# OMP_NUM_THREADS=1.
REFERENCE_MS = {"T1": 14.5, "T2": 14.8, "T3": 15.8, "T4": 15.6}
REFERENCE_EVAL_SHARE = {"T1": 0.36, "T2": 0.37, "T3": 0.38, "T4": 0.39}
_TIMERS = {"all": "OverallAlgorithm", "evals": "Function Evaluations", "kkt": "PDSystemSolverTotal"}


class _Captured(Exception):
    """Raised to stop the strategy at its first dynamic-stage solve, once it is captured."""


def stage2_start(path: pathlib.Path):
    """(problem, x0, options) of the first dynamic-stage solve of the task file's 2S with IPOPT."""
    got: dict = {}
    run = Runner.run

    def capture(runner, problem, x0, options, stage):
        if not problem.layout.pseudo_static:
            got.update(problem=problem, x0=np.array(x0), options=dict(options))
            raise _Captured
        return run(runner, problem, x0, options, stage)

    kwargs = jh.load_task_file(path).as_solve_kwargs()
    kwargs.update(solver="ipopt", settings=kwargs["settings"].replace(stage1_solver="ipopt"))
    with mock.patch.object(Runner, "run", capture), contextlib.suppress(_Captured):
        jh.solve(**kwargs)
    if not got:
        raise RuntimeError(f"{path}: the strategy reached no dynamic stage")
    return got["problem"], got["x0"], got["options"]


def load_baseline(rev: str):
    """The module ``validation/casadi_backend.py`` as it was at git revision ``rev``."""
    text = subprocess.run(
        ["git", "show", f"{rev}:jaxhumanoid/validation/casadi_backend.py"], capture_output=True, text=True, check=True
    ).stdout
    path = pathlib.Path(tempfile.mkdtemp(prefix="bench_casadi_")) / "casadi_backend_baseline.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location("casadi_backend_baseline", path)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    sys.modules[spec.name] = module  # type: ignore[union-attr]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def timers(log: str) -> dict:
    """IPOPT's timing statistics (CPU and wall seconds) and iteration count from its log."""
    out = {}
    for key, label in _TIMERS.items():
        m = re.search(rf"^\s*{re.escape(label)}\.*:\s*([\d.]+) \(sys:\s*[\d.]+ wall:\s*([\d.]+)\)", log, re.M)
        out[key] = (float(m.group(1)), float(m.group(2))) if m else (float("nan"), float("nan"))
    return out


def run_once(name: str, backend, problem, x0, options) -> dict:
    opts = {**options, "print_timing_statistics": "yes"}
    if name == "ipopt":
        r = solve_ipopt(problem.nlp, problem.p, problem.bounds, x0=x0, options=opts)
    else:
        r = backend(problem, x0=x0, options=opts)
    t = timers(r.log or "")
    its = max(int(r.iterations), 1)
    return {
        "status": r.status,
        "iterations": int(r.iterations),
        "objective": float(r.objective),
        "build_s": float(r.compile_time_s),
        "solve_s": float(r.solve_time_s),
        **{f"{k}_cpu_ms_per_it": v[0] / its * 1e3 for k, v in t.items()},
        **{f"{k}_wall_ms_per_it": v[1] / its * 1e3 for k, v in t.items()},
        "q": np.asarray(problem.full(r.x))[:, : problem.layout.n_links],
    }


def bench_task(path: pathlib.Path, backends: dict, runs: int, rng) -> dict:
    problem, x0, options = stage2_start(path)
    warm = solve_ipopt(problem.nlp, problem.p, problem.bounds, x0=x0, options={**options, "max_iter": 1})
    samples: dict = {k: [] for k in backends}
    order = list(backends)
    for _ in range(runs):
        rng.shuffle(order)
        for k in order:
            samples[k].append(run_once(k, backends[k], problem, x0, options))
    out = {"n": int(problem.nlp.n), "m": int(problem.nlp.m), "options": options, "backends": {}}
    out["ipopt_first_call_compile_s"] = float(warm.compile_time_s)
    ref_q = samples["ipopt"][0]["q"]
    for k, rows in samples.items():
        med = {key: float(np.median([r[key] for r in rows])) for key in rows[0] if key.endswith(("_ms_per_it", "_s"))}
        out["backends"][k] = {
            "status": rows[0]["status"],
            "iterations": rows[0]["iterations"],
            "objective": rows[0]["objective"],
            "max_q_difference_to_ipopt": float(np.max(np.abs(rows[0]["q"] - ref_q))),
            "medians": med,
            "runs": [{key: v for key, v in r.items() if key != "q"} for r in rows],
        }
    return out


def git_commit() -> str:
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True)
    return head + ("-dirty" if dirty.stdout.strip() else "")


def table(results: dict) -> str:
    lines = [
        "| task | backend | iterations | objective | max dq to ipopt | build s | ms/it CPU | ms/it wall | "
        "evals ms/it CPU | KKT ms/it CPU | CPU / ref | wall / ref | evals / ref | CPU / ipopt |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for task, rec in results.items():
        ipopt_cpu = rec["backends"]["ipopt"]["medians"]["all_cpu_ms_per_it"]
        ref = REFERENCE_MS.get(task, float("nan"))
        ref_evals = ref * REFERENCE_EVAL_SHARE.get(task, float("nan"))
        for k, b in rec["backends"].items():
            m = b["medians"]
            cpu, wall, evals = m["all_cpu_ms_per_it"], m["all_wall_ms_per_it"], m["evals_cpu_ms_per_it"]
            lines.append(
                f"| {task} | {k} | {b['iterations']} | {b['objective']:.6f} | {b['max_q_difference_to_ipopt']:.0e} | "
                f"{m['build_s']:.2f} | {cpu:.1f} | {wall:.1f} | {evals:.1f} | {m['kkt_cpu_ms_per_it']:.1f} | "
                f"{cpu / ref:.2f} | {wall / ref:.2f} | {evals / ref_evals:.2f} | {cpu / ipopt_cpu:.2f} |"
            )
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dir", default="../shared/reference_posing", help="folder of the task files <task>.toml")
    ap.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--baseline", default=None, help="a git revision whose CasADi backend runs beside this one")
    ap.add_argument("--out", default="results/bench_casadi.json")
    args = ap.parse_args()
    backends: dict = {"casadi": solve_casadi, "ipopt": None}
    if args.baseline:
        backends[f"casadi@{args.baseline}"] = load_baseline(args.baseline).solve_casadi
    rng = np.random.default_rng(0)
    results = {}
    t0 = time.perf_counter()
    for task in args.tasks:
        results[task] = bench_task(pathlib.Path(args.dir) / f"{task}.toml", backends, args.runs, rng)
        print(f"{task} done after {time.perf_counter() - t0:.0f} s", flush=True)
    print(table(results))
    record = {
        "commit": git_commit(),
        "environment": environment(),
        "argv": sys.argv[1:],
        "reference_ms_per_iteration": REFERENCE_MS,
        "reference_evaluation_share": REFERENCE_EVAL_SHARE,
        "tasks": results,
    }
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
