"""Shared helpers of the benchmark and study scripts: medians of repeated runs, JSON and table output,
the benchmarks' tasks."""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import json
import pathlib
import platform
import time

import jax
import numpy as np

from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, Task, with_force_limit


def time_fn(fn, *args, repeats: int = 50) -> dict:
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


def alternate(fns: dict, repeats: int, per: dict | None = None) -> dict:
    """Median wall and CPU ms (this process) of each zero-argument function, called in alternation
    (one call of each per round, in a new random order each round) after one warm-up call; divided
    by ``per[k]`` (batch members) where given. A varying load on a shared machine affects all alike."""
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


def write(results: dict, path: str) -> None:
    results = {
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor(),
            "jax": jax.__version__,
            "devices": [str(d) for d in jax.devices()],
        },
        **results,
    }
    out = pathlib.Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out}")


def show_table(text: str, path: str | None) -> None:
    """Print a markdown table and, with ``path``, write it there too."""
    print(text)
    if path:
        pathlib.Path(path).write_text(text + "\n")


def bench_task(key: str) -> Task:
    """The benchmarks' workload for the built-in task ``key``: that task without a contact-force
    limit (T3 carries one), so that what a benchmark times does not move with the task's posing."""
    return with_force_limit(key, NO_FORCE_LIMIT)
