"""Shared timing helper for the benchmark scripts: medians of repeated runs, JSON output."""

from __future__ import annotations

import json
import pathlib
import platform
import time

import jax
import numpy as np


def time_fn(fn, *args, repeats: int = 50) -> dict:
    """Compile time (first call) and median / min of ``repeats`` further calls, in ms."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_ms = (time.perf_counter() - t0) * 1e3
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        samples.append((time.perf_counter() - t0) * 1e3)
    return {"median_ms": float(np.median(samples)), "min_ms": float(np.min(samples)), "compile_ms": compile_ms, "repeats": repeats}


def write(results: dict, path: str) -> None:
    results = {"machine": {"platform": platform.platform(), "processor": platform.processor(), "jax": jax.__version__, "devices": [str(d) for d in jax.devices()]}, **results}
    out = pathlib.Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out}")
