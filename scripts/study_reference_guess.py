"""Study: the reference posing solved with the files' own first guess and with another one.

    OMP_NUM_THREADS=1 python scripts/study_reference_guess.py --draws 6 --solvers ipopt \
        [--tasks T1 T2 T3 T4] [--guess auto] [--ref-dir ../shared/reference_posing] [--out results/study_reference_guess.json]

Each reference-posing file (``guess = "linear"``, the independent implementation's first guess),
over ``--draws`` draws of its cost weights (the reference-draws suite's,
``studies.suites.reference_draw_weights``; draw 0 as posed), is solved as the file poses it and with
its settings' ``guess`` replaced by ``--guess`` (default ``"auto"``, ``solve``'s default: stage 1
from the static path, checked by the objective it keeps), every stage on each of ``--solvers``.
The same as ``jaxhumanoid solve --task-file FILE --guess GUESS --solver SOLVER`` for draw 0.

For each run: the iterations and objective of every stage-1 run (a guess of ``"auto"`` may run
stage 1 twice), stage 2's iterations, status and objective (7). Prints one line per problem and
writes a JSON record with the commit and the environment.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import pathlib

import numpy as np

from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.studies.bench import recorded_solve, write_record
from jaxhumanoid.studies.suites import reference_draw_weights


def stage_runs(kwargs: dict) -> dict:
    """``solve(**kwargs)``: its stage-1 runs (iterations, objective) and its last stage."""
    sol, runs = recorded_solve(**kwargs)
    last = runs[-1].result
    return {
        "stage1": [
            [int(r.result.iterations), float(r.result.objective)] for r in runs if r.stage.startswith("stage 1")
        ],
        "stage2_iterations": int(last.iterations),
        "status": last.status,
        "objective": float(sol.objective),
        "total_iterations": int(sum(r.result.iterations for r in runs)),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="+", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--draws", type=int, default=6)
    ap.add_argument("--solvers", nargs="+", default=["ipopt"], choices=["ipopt", "ipm", "casadi"])
    ap.add_argument("--guess", default="auto")
    ap.add_argument("--ref-dir", default="../shared/reference_posing")
    ap.add_argument("--out", default="results/study_reference_guess.json")
    args = ap.parse_args()
    rows = []
    for task in args.tasks:
        kwargs = load_task_file(pathlib.Path(args.ref_dir) / f"{task}.toml").as_solve_kwargs()
        posed = kwargs["settings"].guess
        for draw in range(args.draws):
            for solver in args.solvers:
                row: dict = {"task": task, "draw": draw, "solver": solver}
                for key, guess in (("as_posed", posed), ("guess", args.guess)):
                    settings = kwargs["settings"].replace(guess=guess)
                    w = reference_draw_weights(kwargs, draw)
                    row[key] = {
                        "guess": guess,
                        **stage_runs({**kwargs, "weights": w, "solver": solver, "settings": settings}),
                    }
                rows.append(row)
                a, g = row["as_posed"], row["guess"]
                print(
                    f"{task} draw {draw} {solver}: {posed} {a['total_iterations']} its {a['objective']:.6g}"
                    f" (stage 1 ends at {a['stage1'][-1][1]:.4g}) | {args.guess} {g['total_iterations']} its"
                    f" {g['objective']:.6g} (stage 1 ends at {min(s[1] for s in g['stage1']):.4g})",
                    flush=True,
                )
    for solver in args.solvers:
        for key in ("as_posed", "guess"):
            its = [r[key]["total_iterations"] for r in rows if r["solver"] == solver]
            print(f"{solver} {key}: median {np.median(its):.1f}, total {sum(its)} over {len(its)}")
    record = {"command": "scripts/study_reference_guess.py", "guess": args.guess, "draws": args.draws, "rows": rows}
    write_record(record, args.out)


if __name__ == "__main__":
    main()
