"""Throughput of a sweep: the same solves by a plain loop, the local pool (1 and 2 workers) and
a local Dask cluster (2 workers).

    OMP_NUM_THREADS=1 python scripts/bench_sweep.py [--spec examples/sweep_small.toml] [--repeats 3]
        [--modes loop,local1,local2,dask2] [--json docs/bench_sweep.json] [--md docs/bench_sweep.md]

Each run is a fresh Python process (``--one MODE``) that does everything a user's run does:
import, problem set-up, compilation (from the persistent cache, warmed by one run that is not
counted), the solves and, for the sweeps, starting the workers, writing the table and the
summary. ``loop`` calls ``studies.run.run_case`` for every case in one process (no table, no
workers): the cost of the solves themselves. Reported per mode: the median wall time over the
repeats, cases per minute, and the overhead per case against the loop, (wall - wall_loop) / cases.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import statistics
import subprocess
import sys
import tempfile
import time

MODES = {"loop": ("loop", 1), "local1": ("local", 1), "local2": ("local", 2), "dask2": ("dask", 2)}


def one(mode: str, spec: str, out: str) -> dict:
    """One timed run in this process (called in a fresh one by ``measure``)."""
    t0 = time.perf_counter()
    from jaxhumanoid.runtime import enable_compilation_cache
    from jaxhumanoid.studies import load_spec, run_case, sweep

    enable_compilation_cache()
    engine, workers = MODES[mode]
    if engine == "loop":
        rows = [run_case(case, out) for case in load_spec(spec).cases]
        succeeded = sum(bool(r["success"]) for r in rows)
        statuses = [r["status"] for r in rows]
    else:
        summary = sweep(spec, out, engine=engine, workers=workers, quiet=True)
        succeeded = summary["n_succeeded"]
        statuses = None
    return {"mode": mode, "wall_s": time.perf_counter() - t0, "succeeded": succeeded, "statuses": statuses}


def measure(mode: str, spec: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="bench_sweep_") as out:
        cmd = [sys.executable, __file__, "--one", mode, "--spec", spec, "--out", out]
        proc = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def markdown(result: dict) -> str:
    lines = [
        f"{result['n_cases']} cases of `{result['spec']}`, medians of {result['repeats']} runs "
        f"(OMP_NUM_THREADS={result['omp_num_threads']}, {result['cpus']} CPUs)",
        "",
        "| mode | wall (s) | runs (s) | cases / min | overhead per case vs loop (s) |",
        "|---|---|---|---|---|",
    ]
    for m in result["modes"]:
        runs = ", ".join(f"{w:.1f}" for w in m["walls_s"])
        lines.append(
            f"| {m['mode']} | {m['wall_s']:.1f} | {runs} | {m['cases_per_min']:.1f} | {m['overhead_per_case_s']:+.2f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spec", default="examples/sweep_small.toml")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--json", default=None)
    ap.add_argument("--md", default=None)
    ap.add_argument("--one", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(one(args.one, args.spec, args.out)))
        return
    from jaxhumanoid.studies import load_spec

    modes = [m for m in args.modes.split(",") if m]
    n_cases = len(load_spec(args.spec).cases)
    print("warm-up (compilation cache)", flush=True)
    measure("loop", args.spec)
    walls: dict[str, list[float]] = {m: [] for m in modes}
    succeeded: dict[str, list[int]] = {m: [] for m in modes}
    for r in range(args.repeats):  # modes interleaved: a slow spell of the machine hits all of them
        for m in modes:
            res = measure(m, args.spec)
            walls[m].append(res["wall_s"])
            succeeded[m].append(res["succeeded"])
            print(f"repeat {r + 1}/{args.repeats} {m}: {res['wall_s']:.1f} s, {res['succeeded']} succeeded", flush=True)
    loop = statistics.median(walls["loop"]) if "loop" in walls else float("nan")
    result = {
        "spec": args.spec,
        "n_cases": n_cases,
        "repeats": args.repeats,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "modes": [
            {
                "mode": m,
                "engine": MODES[m][0],
                "workers": MODES[m][1],
                "walls_s": walls[m],
                "wall_s": statistics.median(walls[m]),
                "succeeded": succeeded[m],
                "cases_per_min": 60 * n_cases / statistics.median(walls[m]),
                "overhead_per_case_s": (statistics.median(walls[m]) - loop) / n_cases,
            }
            for m in modes
        ],
    }
    text = markdown(result)
    print(text)
    if args.json:
        pathlib.Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
    if args.md:
        pathlib.Path(args.md).write_text(text)


if __name__ == "__main__":
    main()
