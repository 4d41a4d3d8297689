"""What the benchmark scripts and ``jaxhumanoid bench`` share: timing of repeated calls, the
benchmarks' workloads, and records that carry the commit and the environment.

- ``time_fn``, ``alternate``: medians of wall and CPU time of jitted calls (in alternation where
  several are compared, so that a varying load on a shared machine affects all alike);
- ``bench_task``, ``stage1_problem``, ``stage2_warm_start``: the built-in tasks as the benchmarks
  pose them, and the two NLPs of A,F+C,2S with the stage-2 start that 2S gives IPOPT;
- ``recorded_solve``: a ``solve`` with every NLP solve of its strategy recorded (problem, start,
  options, result), for studies that solve one of them again;
- ``git_state``, ``write_record``, ``show_table``: a JSON record stamped with the commit (and
  whether the work tree had changes) and ``runtime.environment()``, and a markdown table.
"""

from __future__ import annotations

import json
import pathlib
import subprocess
import time
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple
from unittest import mock

import jax
import numpy as np

from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, Task, with_force_limit
from jaxhumanoid.runtime import environment
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.solvers.ipopt_capi import default_library_path
from jaxhumanoid.solvers.result import NLPResult
from jaxhumanoid.strategy.handover import stage_two_start
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import DEFAULT_STRATEGY_GUESS, Problem, build_problem
from jaxhumanoid.strategy.runner import Runner
from jaxhumanoid.strategy.settings import STAGE1_N, SolveSettings
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.strategy.solve import solve

SCHEME = "A,F+C,2S"
# Stage 1's options for the benchmark workloads (stage-2 starts, KKT data, fingerprints): fixed
# here, so that a change of ``solve``'s stage-1 defaults does not move the workloads the per-
# iteration records compare.
BENCH_STAGE1_OPTIONS = {"mu_init": 1e-2}
# The dynamic stages' options of the plans made for the tracking studies: every dynamic stage to
# IPOPT's tol = 1e-8, the relaxed-law and intermediate ones included (``handover.INTERMEDIATE_OPTIONS``
# loosens those by default), so that the plans the tracking records were made from stay the same.
BENCH_STAGE2_OPTIONS = {"tol": 1e-8}
# Stage 1's guess of those plans, for the same reason (``solve``'s default runs from the static path).
BENCH_GUESS = "inverse_dynamics"
REPO = pathlib.Path(__file__).resolve().parents[2]


def time_fn(fn: Callable, *args, repeats: int = 50) -> dict:
    """Compile time (first call), then median / min wall time and median CPU time (this process,
    all threads) of ``repeats`` further calls, in ms. On a shared machine the CPU time is the
    steadier figure: time-slicing inflates wall time, not the work done."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_ms = (time.perf_counter() - t0) * 1e3
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(fn(*args))
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return {
        "median_ms": float(np.median(wall)),
        "min_ms": float(np.min(wall)),
        "cpu_median_ms": float(np.median(cpu)),
        "compile_ms": compile_ms,
        "repeats": repeats,
    }


def alternate(fns: Mapping[str, Callable], repeats: int, per: Mapping[str, int] | None = None) -> dict:
    """Median wall and CPU ms (this process) of each zero-argument function, called in alternation
    (one call of each per round, in a new random order each round) after one warm-up call; divided
    by ``per[k]`` (batch members) where given."""
    for f in fns.values():
        jax.block_until_ready(f())
    wall: dict = {k: [] for k in fns}
    cpu: dict = {k: [] for k in fns}
    order, rng = list(fns), np.random.default_rng(0)
    for _ in range(repeats):
        rng.shuffle(order)
        for k in order:
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(fns[k]())
            wall[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    per = per or {}
    return {
        k: {
            "median_ms": float(np.median(wall[k])) / per.get(k, 1),
            "min_ms": float(np.min(wall[k])) / per.get(k, 1),
            "cpu_median_ms": float(np.median(cpu[k])) / per.get(k, 1),
            "per": per.get(k, 1),
        }
        for k in fns
    }


def bench_task(key: str) -> Task:
    """The benchmarks' workload for the built-in task ``key``: that task without a contact-force
    limit (T3 carries one), so that what a benchmark times does not move with the task's posing."""
    return with_force_limit(key, NO_FORCE_LIMIT)


def stage1_problem(task: str, N1: int = STAGE1_N) -> tuple[Problem, Problem]:
    """Stage 1 of 2S (pseudo-static, relaxed contact law, re-seated start) of ``bench_task(task)``,
    and its stage-2 problem (N = 100)."""
    t = bench_task(task)
    final = build_problem(t, parse_scheme(SCHEME), N=100)
    relaxed = ContactParams.relaxed()
    q1, _ = reseat_for_contact(final.p, final.p.q_start, final.layout.active, relaxed)
    first = build_problem(t, parse_scheme(SCHEME), N=N1, pseudo_static=True, contact=relaxed, q_start=q1)
    return first, final


def bench_settings(settings: SolveSettings | None = None) -> SolveSettings:
    """``settings`` (``SolveSettings()`` when None) with stage 1's options ``BENCH_STAGE1_OPTIONS``
    and the dynamic stages' ``BENCH_STAGE2_OPTIONS`` where it sets none of its own, and stage 1's
    guess ``BENCH_GUESS`` where it keeps the default one."""
    settings = settings or SolveSettings()
    if settings.guess == DEFAULT_STRATEGY_GUESS:
        settings = settings.replace(guess=BENCH_GUESS)
    if not settings.stage1_options:
        settings = settings.replace(stage1_options=BENCH_STAGE1_OPTIONS)
    return settings if settings.stage2_options else settings.replace(stage2_options=BENCH_STAGE2_OPTIONS)


def stage2_warm_start(task: str) -> tuple[Problem, np.ndarray]:
    """The stage-2 problem and its 2S start from IPOPT's stage-1 solution (``stage_two_start``)."""
    first, prob = stage1_problem(task)
    r1 = solve_ipopt(first.nlp, first.p, first.bounds, options=BENCH_STAGE1_OPTIONS)
    return prob, stage_two_start(first.full(r1.x), prob)[0]


def git_state(root: pathlib.Path | str = REPO) -> dict[str, Any]:
    """The commit checked out at ``root``, its ``git describe`` and whether tracked files differ
    from it (``dirty``); ``None`` for each outside a git work tree."""

    def git(*args: str) -> str | None:
        try:
            out = subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return out.stdout.strip() if out.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    status = git("status", "--porcelain", "--untracked-files=no") if commit else None
    describe = git("describe", "--always", "--tags", "--dirty") if commit else None
    return {"commit": commit, "describe": describe, "dirty": None if status is None else bool(status)}


def stamp(results: Mapping[str, Any]) -> dict[str, Any]:
    """``results`` with the commit, the dirty flag and ``runtime.environment()`` in front, with the
    IPOPT library the solves load (``ipopt_library``): the process that writes a record need not
    have loaded it, its workers do."""
    env = {**environment(), "ipopt_library": default_library_path()}
    return {**git_state(), "environment": env, **results}


class StageRun(NamedTuple):
    """One NLP solve of a strategy, as ``Runner.run`` was called for it and what it returned."""

    stage: str  # the stage's name, e.g. "stage 1 (pseudo-static)" or "stage 2 (dynamic), rerun 1"
    problem: Problem
    x0: np.ndarray  # (n,) the start, a copy
    options: dict[str, Any]  # the solver options of the call
    result: NLPResult


def recorded_solve(**kwargs) -> tuple[Solution, list[StageRun]]:
    """``solve(**kwargs)`` and every NLP solve it ran, in order: every stage, fallback and rerun
    goes through ``Runner.run``, which is wrapped for the call. Studies take a stage's problem,
    start and options from it to solve that stage again under variants."""
    runs: list[StageRun] = []
    run = Runner.run

    def record(runner, problem, x0, options, stage):
        res = run(runner, problem, x0, options, stage)
        runs.append(StageRun(stage, problem, np.array(x0, dtype=float), dict(options), res))
        return res

    with mock.patch.object(Runner, "run", record):
        sol = solve(**kwargs)
    return sol, runs


def write_record(results: Mapping[str, Any], path: str | pathlib.Path, quiet: bool = False) -> pathlib.Path:
    """Write ``stamp(results)`` as JSON to ``path`` (folders made); returns the path."""
    out = pathlib.Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(stamp(results), indent=2, default=float) + "\n")
    if not quiet:
        print(f"wrote {out}")
    return out


def show_table(text: str, path: str | pathlib.Path | None) -> None:
    """Print a markdown table and, with ``path``, write it there too."""
    print(text)
    if path:
        pathlib.Path(path).write_text(text + "\n")
