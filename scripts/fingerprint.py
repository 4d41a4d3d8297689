"""Behaviour fingerprint: what the solvers compute, to prove that a refactor changed nothing.

    python scripts/fingerprint.py --out results/fingerprint.json [--tasks T1 T2 T3 T4]
    python scripts/fingerprint.py --compare results/before.json results/after.json

Records, per task (A,F+C,2S at N = 100): stage 1 with IPOPT and with the IPM (status, iterations,
objective, a digest of x), stage 2 from IPOPT's stage-1 point with both solvers; the IPM on the
small test problems; and the sensitivity check errors (T1, T3 at N = 15). ``--compare`` prints a
table of both runs and exits 1 when an iteration count or status differs or an objective differs
by more than 1e-12 relative. Run with ``OMP_NUM_THREADS=1``.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import hashlib
import json
import pathlib
import sys

import numpy as np

import jaxhumanoid  # noqa: F401  (x64)
from jaxhumanoid.diff import sensitivity_table
from jaxhumanoid.solvers.ipm import solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.handover import STAGE2_DEFAULTS, stage_two_start
from jaxhumanoid.studies.bench import BENCH_STAGE1_OPTIONS, stage1_problem
from jaxhumanoid.validation import testproblems as tp


def _digest(x) -> str:
    return hashlib.sha256(np.ascontiguousarray(np.asarray(x, dtype=np.float64)).tobytes()).hexdigest()[:16]


def _rec(r) -> dict:
    return {"status": r.status, "iterations": int(r.iterations), "objective": float(r.objective), "x": _digest(r.x)}


def task_records(task: str) -> dict:
    first, final = stage1_problem(task)
    out = {}
    r1 = solve_ipopt(first.nlp, first.p, first.bounds, options=BENCH_STAGE1_OPTIONS)
    out["stage1_ipopt"] = _rec(r1)
    out["stage1_ipm"] = _rec(solve_ipm(first.nlp, first.p, first.bounds, options=BENCH_STAGE1_OPTIONS))
    x0, _ = stage_two_start(first.full(r1.x), final)
    for name, fn in (("ipopt", solve_ipopt), ("ipm", solve_ipm)):
        out[f"stage2_{name}"] = _rec(fn(final.nlp, final.p, final.bounds, x0=x0, options=STAGE2_DEFAULTS))
    return out


def testproblem_records() -> dict:
    cases = {**tp.HS_PROBLEMS, "wachter_biegler": tp.wachter_biegler, "infeasible_disk": tp.infeasible_disk}
    out = {}
    for name, make in cases.items():
        nlp, bounds, p = make()[:3]
        out[name] = _rec(solve_ipm(nlp, p, bounds))
    return out


def sensitivity_records(tasks=("T1", "T3")) -> dict:
    rows, _ = sensitivity_table(tasks, "A,F+C,1S", N=15)
    return {f"{r['case']} {r['quantity']}": r["value"] for r in rows}


def compare(a: dict, b: dict) -> int:
    bad = 0
    print(f"{'case':<34} {'before':>28} {'after':>28} {'rel dobj':>9}")
    for group in ("tasks", "testproblems"):
        for key in a[group]:
            recs_a = a[group][key] if group == "tasks" else {"ipm": a[group][key]}
            recs_b = b[group].get(key, {}) if group == "tasks" else {"ipm": b[group].get(key)}
            for sub, ra in recs_a.items():
                rb = recs_b.get(sub)
                if rb is None:
                    print(f"{key + ' ' + sub:<34} missing after")
                    bad += 1
                    continue
                d = abs(ra["objective"] - rb["objective"]) / max(abs(ra["objective"]), 1e-300)
                same = ra["iterations"] == rb["iterations"] and ra["status"] == rb["status"] and d <= 1e-12
                bad += not same
                fa = f"{ra['iterations']} {ra['objective']:.12g}"
                fb = f"{rb['iterations']} {rb['objective']:.12g}"
                print(
                    f"{key + ' ' + sub:<34} {fa:>28} {fb:>28} {d:9.1e}{'' if same else '  DIFFERS'}"
                    f"{'  (x bitwise equal)' if ra['x'] == rb['x'] else ''}"
                )
    for key, va in a.get("sensitivities", {}).items():
        vb = b.get("sensitivities", {}).get(key, float("nan"))
        print(f"{key:<60} {va:10.3e} {vb:10.3e}")
    print(f"{bad} differences")
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", nargs="+", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--out", default="results/fingerprint.json")
    ap.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    ap.add_argument("--skip-sensitivities", action="store_true")
    args = ap.parse_args(argv)
    if args.compare:
        a, b = (json.loads(pathlib.Path(f).read_text()) for f in args.compare)
        return compare(a, b)
    res = {"testproblems": testproblem_records(), "tasks": {}}
    for task in args.tasks:
        res["tasks"][task] = task_records(task)
        print(task, json.dumps(res["tasks"][task]), flush=True)
    if not args.skip_sensitivities:
        res["sensitivities"] = sensitivity_records()
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
