"""Study: the whole 2S over the robustness study's perturbed problems under variants of stage 1's
guess, grid and the intermediate stages' tolerance.

    OMP_NUM_THREADS=1 python scripts/study_stage1_guess.py --out docs/study_stage1_guess.json \
        --draws 10 --variant '{}' --variant '{"settings": {"guess": "static_path"}}' ...

A variant is a JSON object: ``settings`` (``SolveSettings`` fields replaced on the case's),
``stage1`` (IPOPT options of stage 1), ``relaxed`` (options of the relaxed-law dynamic solve) and
``mid`` (options of the continuation's laws before the nominal one). Each case of
``examples/studies/robustness.toml`` (IPOPT, draws below ``--draws``) is solved under every variant
in one worker process, so that the variants share its compiled NLPs. The record holds one row per
case and variant (status, iterations per stage, objective, solve time), the commit and the
environment.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import pathlib
import sys
import time
import traceback

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPEC = ROOT / "examples" / "studies" / "robustness.toml"
_ORIGINAL: dict = {}


def _patch(variant: dict) -> None:
    """Route the variant's options into the strategy (the module functions as they were first)."""
    from jaxhumanoid.strategy import handover
    from jaxhumanoid.studies import run as run_mod

    run_path = _ORIGINAL.setdefault("run_path", handover.run_path)
    base_problem = _ORIGINAL.setdefault("base_problem", run_mod.base_problem)

    def patched_run_path(problems, x0, options, runner, label):
        if label.startswith("stage 1 (dynamic") and variant.get("relaxed"):
            return run_path(problems, x0, {**options, **variant["relaxed"]}, runner, label)
        if not (label.startswith("stage 2") and variant.get("mid") and len(problems) > 1):
            return run_path(problems, x0, options, runner, label)
        attempts, x = [], x0
        for j, problem in enumerate(problems):
            opts = options if j == len(problems) - 1 else {**options, **variant["mid"]}
            if j:
                opts = {**opts, **handover.CONTINUATION_OPTIONS}
            runs, solved = run_path([problem], x, opts, runner, label)
            attempts += runs
            if not solved:
                return attempts, j
            x = runs[-1].x
        return attempts, len(problems)

    def patched_base_problem(case):
        kw = base_problem(case)
        s = kw["settings"]
        if variant.get("stage1"):
            s = s.replace(stage1_options={**(s.stage1_options or {}), **variant["stage1"]})
        kw["settings"] = s.replace(**variant.get("settings", {}))
        return kw

    handover.run_path = patched_run_path
    run_mod.base_problem = patched_base_problem


def solve_variants(job: tuple[list[str], str]) -> list[dict]:
    """Every variant of one case, in this process."""
    from jaxhumanoid.studies import run as run_mod
    from jaxhumanoid.studies.spec import load_spec

    variants, case_id = job
    case = next(c for c in load_spec(SPEC).cases if c.id == case_id)
    rows = []
    for variant in variants:
        _patch(json.loads(variant))
        row = {"variant": variant, "case": case_id, "task": case.task, "draw": case.draw}
        t0 = time.perf_counter()
        try:
            out = run_mod.solve_case(case, pathlib.Path("/tmp/study_stage1_guess"))
            row.update(
                success=out["success"],
                iterations=out["iterations"],
                total=out["iterations_total"],
                objective=out["objective"],
                solve_time_s=out["solve_time_s"],
            )
        except Exception:  # noqa: BLE001 - a case that raises is a row, the study goes on
            row.update(success=False, iterations="", total=0, objective=float("nan"), error=traceback.format_exc()[-1500:])
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--variant", action="append", default=None, help="a JSON object (see above); repeatable")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    import jaxhumanoid  # noqa: F401 - float64 and the BLAS kernels before anything else
    from jaxhumanoid.runtime import environment
    from jaxhumanoid.studies.bench import git_state
    from jaxhumanoid.studies.spec import load_spec

    variants = args.variant or ["{}"]
    out = pathlib.Path(args.out)
    record = json.loads(out.read_text()) if out.exists() else {"rows": []}
    record.update(command=sys.argv, **git_state(), environment=environment())
    done = {(r["variant"], r["case"]) for r in record["rows"]}
    cases = [c.id for c in load_spec(SPEC).cases if c.solver == "ipopt" and (c.draw or 0) < args.draws]
    jobs = [([v for v in variants if (v, c) not in done], c) for c in cases]
    with mp.get_context("spawn").Pool(args.workers, maxtasksperchild=4) as pool:
        for rows in pool.imap_unordered(solve_variants, [j for j in jobs if j[0]]):
            record["rows"] += rows
            out.write_text(json.dumps(record, indent=1))
            for r in rows:
                print(r["task"], r["draw"], r["variant"], r["success"], r["iterations"], f"{r['objective']:.6g}", flush=True)


if __name__ == "__main__":
    main()
