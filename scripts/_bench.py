"""Shared helpers of the benchmark and study scripts: medians of repeated runs, JSON and table output."""

from __future__ import annotations

import json
import pathlib
import platform
import time

import jax
import numpy as np


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
