"""Study: the whole 2S (or stage 1 alone) over the robustness study's perturbed problems under
variants of stage 1's barrier and guess, of the hand-over's start and of the dynamic stages'
options.

    OMP_NUM_THREADS=1 python scripts/study_handover_variants.py --out docs/study_x.json \
        --draws 10 --variant '{}' --variant '{"stage1": {"mu_strategy": "adaptive"}}' ...

A variant is a JSON object:

- ``settings``: ``SolveSettings`` fields replaced on the case's;
- ``stage1``, ``relaxed``, ``mid``: IPOPT options of stage 1, of the relaxed-law dynamic solve and
  of the continuation's laws before the nominal one, on top of the strategy's;
- ``projection``: ``"relaxed"`` or ``"nominal"``, the hand-over's torques and forces set to the
  inverse dynamics of the interpolated motion under that law (``inverse_dynamics_guess``), so that
  the dynamics and force rows hold at the start of the dynamic stages;
- ``skip_relaxed``: the continuation without its relaxed-law dynamic solve, stage 1's solution
  handed to the first law after it.

Each case of ``examples/studies/robustness.toml`` (``--solvers``, default IPOPT; draws below
``--draws``) is solved under every variant in one worker process, so that the variants share its compiled NLPs. With
``--stage1-only`` each solve stops after stage 1 (its fallbacks included), and its row holds the
guess of the run handed over and the objective at that guess. The record holds one
row per case and variant (status, iterations per stage, objective, solve time), the commit and the
environment.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing as mp
import pathlib
import sys
import time
import traceback

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPEC = ROOT / "examples" / "studies" / "robustness.toml"
_ORIGINAL: dict = {}


class StageOneDone(Exception):
    """Raised after stage 1 in ``--stage1-only`` runs; carries its stats and its start's objective."""


def _original(module, name: str):
    return _ORIGINAL.setdefault((module.__name__, name), getattr(module, name))


def _patch(variant: dict, stage1_only: bool) -> None:
    """Route the variant into the strategy (every patched function calls the original one)."""
    import numpy as np

    from jaxhumanoid.ocp import transcription as tr
    from jaxhumanoid.strategy import handover
    from jaxhumanoid.strategy import solve as solve_mod
    from jaxhumanoid.strategy import stage_one as stage_one_mod
    from jaxhumanoid.studies import run as run_mod

    run_path = _original(handover, "run_path")
    base_problem = _original(run_mod, "base_problem")
    relaxed_stage_problem = _original(solve_mod, "relaxed_stage_problem")
    stage_two_start = _original(solve_mod, "stage_two_start")
    continuation_stages = _original(solve_mod, "continuation_stages")
    stage_one = _original(solve_mod, "stage_one")
    seen: dict = {}

    def patched_run_path(problems, x0, options, runner, label):
        if label.startswith("stage 1 (dynamic") and variant.get("relaxed"):
            return run_path(problems, x0, {**options, **variant["relaxed"]}, runner, label)
        if not (label.startswith("stage 2") and variant.get("mid") and len(problems) > 1):
            return run_path(problems, x0, options, runner, label)
        attempts, x = [], x0
        for j, problem in enumerate(problems):
            last = j == len(problems) - 1
            opts = options if last else {**handover.INTERMEDIATE_OPTIONS, **options, **variant["mid"]}
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

    def patched_relaxed(final, first, steps):
        out = relaxed_stage_problem(final, first, steps)
        seen["relaxed"] = out[0]
        return out

    def patched_stage_one(relaxed, settings, options, runner):
        stats, Z1 = stage_one(relaxed, settings, options, runner)
        if stage1_only:
            N1 = settings.stage1_grid(relaxed.layout.N)
            law = relaxed.p.contact
            first = stage_one_mod.stage_one_problem(relaxed.task, relaxed.scheme, relaxed, N1, law, stats.guess)
            raise StageOneDone(stats, stage_one_mod.start_objective(first))
        return stats, Z1

    def patched_start(Z1, final):
        x0, Zf = stage_two_start(Z1, final)
        if not variant.get("projection"):
            return x0, Zf
        law = (seen["relaxed"] if variant["projection"] == "relaxed" else final).p.contact
        Zf = np.asarray(tr.inverse_dynamics_guess(final.layout, Zf, dataclasses.replace(final.p, contact=law)))
        x0 = np.clip(np.asarray(tr.free_from_full(final.layout, Zf)), final.bounds.xl, final.bounds.xu)
        return x0, Zf

    def patched_stages(path, x0, options, runners, setup_time_s):
        return continuation_stages(
            path[1:] if variant.get("skip_relaxed") else path, x0, options, runners, setup_time_s
        )

    handover.run_path = patched_run_path
    run_mod.base_problem = patched_base_problem
    solve_mod.relaxed_stage_problem = patched_relaxed
    solve_mod.stage_one = patched_stage_one
    solve_mod.stage_two_start = patched_start
    solve_mod.continuation_stages = patched_stages


def solve_variants(job: tuple[list[str], str, bool]) -> list[dict]:
    """Every variant of one case, in this process."""
    from jaxhumanoid.studies import run as run_mod
    from jaxhumanoid.studies.spec import load_spec

    variants, case_id, stage1_only = job
    case = next(c for c in load_spec(SPEC).cases if c.id == case_id)
    rows = []
    for variant in variants:
        _patch(json.loads(variant), stage1_only)
        row = {"variant": variant, "case": case_id, "task": case.task, "draw": case.draw, "solver": case.solver}
        t0 = time.perf_counter()
        try:
            out = run_mod.solve_case(case, pathlib.Path("/tmp/study_handover_variants"))
            row.update(
                success=out["success"],
                iterations=out["iterations"],
                total=out["iterations_total"],
                objective=out["objective"],
                solve_time_s=out["solve_time_s"],
            )
        except StageOneDone as done:
            st, start_objective = done.args
            row.update(
                success=bool(st.success),
                iterations=str(st.iterations),
                total=int(st.iterations),
                objective=float(st.objective),
                solve_time_s=float(st.solve_time_s),
                guess=st.guess,
                start_objective=start_objective,
            )
        except Exception:  # noqa: BLE001 - a case that raises is a row, the study goes on
            row.update(
                success=False, iterations="", total=0, objective=float("nan"), error=traceback.format_exc()[-1500:]
            )
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--variant", action="append", default=None, help="a JSON object (see above); repeatable")
    ap.add_argument("--stage1-only", action="store_true", help="stop every solve after stage 1")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--solvers", nargs="+", default=["ipopt"], choices=["ipopt", "ipm", "casadi"])
    args = ap.parse_args()
    import jaxhumanoid  # noqa: F401 - float64 and the BLAS kernels before anything else
    from jaxhumanoid.runtime import environment
    from jaxhumanoid.studies.bench import git_state
    from jaxhumanoid.studies.spec import load_spec

    variants = args.variant or ["{}"]
    out = pathlib.Path(args.out)
    record = json.loads(out.read_text()) if out.exists() else {"rows": []}
    record.update(command=sys.argv, stage1_only=args.stage1_only, **git_state(), environment=environment())
    done = {(r["variant"], r["case"]) for r in record["rows"]}
    cases = [c.id for c in load_spec(SPEC).cases if c.solver in args.solvers and (c.draw or 0) < args.draws]
    jobs = [([v for v in variants if (v, c) not in done], c, args.stage1_only) for c in cases]
    with mp.get_context("spawn").Pool(args.workers, maxtasksperchild=4) as pool:
        for rows in pool.imap_unordered(solve_variants, [j for j in jobs if j[0]]):
            record["rows"] += rows
            out.write_text(json.dumps(record, indent=1))
            for r in rows:
                print(
                    r["task"],
                    r["draw"],
                    r["solver"],
                    r["variant"],
                    r["success"],
                    r["iterations"],
                    f"{r['objective']:.6g}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
