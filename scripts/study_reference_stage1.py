"""Study: where stage 1 of the reference posing ends from the files' linear guess, and why.

    OMP_NUM_THREADS=1 python scripts/study_reference_stage1.py --starts 12 --draws 6 \
        [--tasks T1 T2 T3 T4] [--ref-dir ../shared/reference_posing] [--out results/study_reference_stage1.json]

Two questions about stage 1 of each reference-posing file (``guess = "linear"``, the independent
implementation's first guess; IPOPT with the file's options, every stage on it):

- ``starts``: is its end point a matter of rounding? Stage 1 of draw 0 is solved again from its
  start with every free entry moved by ``--eps`` * max(|x|, 1e-3) * z (z standard normal, seed
  1..``--starts``); each run's iterations, status and stage-1 objective.
- ``sums``: does the objective's form move it? The paper's (7) is f = v^T W v, sums over the
  nodes; the files write the independent implementation's sums as this project's time integrals
  (effort h * w * u^2, changes w * du^2 / h), which equal the sums on the final grid (h = T / N)
  but weight effort (N / N1)^2 times more against the changes on stage 1's grid. Over ``--draws``
  draws (the reference-draws suite's weights), the whole solve as posed and with stage 1's
  weights rescaled to the sums on its own grid (effort times N1 / N, changes times N / N1); each
  solve's iterations per NLP solve, objective (7), and stage 1's objective under the integrals.

- ``variants``: which known difference to the independent implementation moves stage 1 to its
  counts (106, 36, 34, 37 iterations)? Stage 1 of draw 0 under every combination of the sums
  above, the torques of the guess at the start's equilibrium torques u_0 instead of zero, and the
  start as the file gives it instead of re-seated for the relaxed law (the linear guess made
  again from it); each run's iterations, status and stage-1 objective under the files' weights.

Prints one line per run and writes a JSON record with the commit and the environment.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import dataclasses
import itertools
import pathlib
from unittest import mock

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy import stage_one as stage_one_mod
from jaxhumanoid.strategy.problem import Problem, with_guess
from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.studies.bench import StageRun, recorded_solve, write_record
from jaxhumanoid.studies.suites import reference_draw_weights

_STAGE_ONE_PROBLEM = stage_one_mod.stage_one_problem


def sums_weighted(problem: Problem, N: int) -> Problem:
    """Stage 1's ``problem`` with the weights that make its time integrals the paper's sums on its
    own grid of N1 intervals, for weights written as integrals of the final grid of N intervals."""
    n, N1 = problem.layout.n_links, problem.layout.N
    w = np.array(problem.p.weights, dtype=float)
    w[: n + 1] *= N1 / N  # effort: h1 * w' = h * w
    w[n + 1 :] *= N / N1  # changes: w' / h1 = w / h
    return dataclasses.replace(problem, p=dataclasses.replace(problem.p, weights=jnp.asarray(w)))


def _stage1(runs: list[StageRun]) -> StageRun:
    return next(r for r in runs if r.stage.startswith("stage 1"))


def moved_starts(s1: StageRun, starts: int, eps: float) -> dict:
    """Stage 1 (``s1``, as draw 0's solve ran it) from ``starts`` moved copies of its start
    (module docstring)."""
    prob, x0, b = s1.problem, s1.x0, s1.problem.bounds
    out: dict = {"as_posed": [int(s1.result.iterations), float(s1.result.objective)], "moved": []}
    for seed in range(1, starts + 1):
        z = np.random.default_rng(seed).standard_normal(x0.shape)
        x = np.clip(x0 + eps * np.maximum(np.abs(x0), 1e-3) * z, b.xl, b.xu)
        r = solve_ipopt(prob.nlp, prob.p, b, x0=x, options=s1.options)
        out["moved"].append([int(r.iterations), r.status, float(r.objective)])
    return out


def start_variant(problem: Problem, N: int, start, sums: bool, u_eq: bool, reseat: bool) -> tuple[Problem, np.ndarray]:
    """Stage 1's ``problem`` and start under one combination of ``variants`` (module docstring);
    ``start``: the file's start posture, ``N``: the final grid."""
    if not reseat:
        p = dataclasses.replace(problem.p, q_start=jnp.asarray(start, dtype=float))
        problem = with_guess(dataclasses.replace(problem, p=p), "linear")
    if sums:
        problem = sums_weighted(problem, N)
    x0 = problem.bounds.x0
    if u_eq:
        L, sl = problem.layout, problem.layout.stage_slices()
        Z = np.array(problem.full(x0))
        Z[1 : L.N, sl["u"]] = Z[0, sl["u"]]
        x0 = np.clip(Z[L.free_mask()], problem.bounds.xl, problem.bounds.xu)
    return problem, x0


def variants(s1: StageRun, N: int, start) -> dict:
    """Stage 1 (``s1``, as draw 0's solve ran it) under every combination of ``variants`` (module
    docstring); ``N``: the final grid, ``start``: the file's start posture."""
    out = {}
    for sums, u_eq, reseat in itertools.product((False, True), (False, True), (True, False)):
        prob, x0 = start_variant(s1.problem, N, start, sums, u_eq, reseat)
        r = solve_ipopt(prob.nlp, prob.p, prob.bounds, x0=x0, options=s1.options)
        f = float(s1.problem.nlp.jitted().f(r.x, s1.problem.p))
        key = f"sums={int(sums)} u_eq={int(u_eq)} reseat={int(reseat)}"
        out[key] = [int(r.iterations), r.status, f]
    return out


def whole(kwargs: dict, sums: bool) -> dict:
    """The whole solve, stage 1 weighted as posed or as the paper's sums on its grid; stage 1's
    objective is given under the files' weights either way."""
    posed: list[Problem] = []

    def stage_one_problem(task, scheme, final, N1, *args, **kw):
        problem = _STAGE_ONE_PROBLEM(task, scheme, final, N1, *args, **kw)
        posed.append(problem)
        return sums_weighted(problem, final.layout.N) if sums else problem

    with mock.patch.object(stage_one_mod, "stage_one_problem", stage_one_problem):
        sol, runs = recorded_solve(**kwargs)
    s1 = _stage1(runs)
    return {
        "iterations": [int(r.result.iterations) for r in runs],
        "objective": float(sol.objective),
        "success": bool(sol.success),
        "stage1_objective": float(posed[0].nlp.jitted().f(s1.result.x, posed[0].p)),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="+", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--starts", type=int, default=12)
    ap.add_argument("--eps", type=float, default=1e-6)
    ap.add_argument("--draws", type=int, default=6)
    ap.add_argument("--ref-dir", default="../shared/reference_posing")
    ap.add_argument("--out", default="results/study_reference_stage1.json")
    args = ap.parse_args()
    record: dict = {"starts": {}, "variants": {}, "sums": []}
    for task in args.tasks:
        kwargs = load_task_file(pathlib.Path(args.ref_dir) / f"{task}.toml").as_solve_kwargs()
        s1 = _stage1(recorded_solve(**kwargs)[1])
        st = record["starts"][task] = moved_starts(s1, args.starts, args.eps)
        ends = sorted(round(m[2], 1) for m in st["moved"])
        print(f"{task} stage 1 as posed {st['as_posed']}; moved starts end at {ends}", flush=True)
        var = record["variants"][task] = variants(s1, kwargs["N"], kwargs["task"].start)
        print(f"{task} stage 1: " + "; ".join(f"{k}: {v[0]} its, {v[2]:.5g}" for k, v in var.items()), flush=True)
        for draw in range(args.draws):
            kw = {**kwargs, "weights": reference_draw_weights(kwargs, draw)}
            row = {"task": task, "draw": draw, "as_posed": whole(kw, False), "sums": whole(kw, True)}
            record["sums"].append(row)
            print(
                " | ".join(
                    f"{task} draw {draw} {key}: {'+'.join(map(str, r['iterations']))} = {sum(r['iterations'])},"
                    f" {r['objective']:.6g}, stage 1 at {r['stage1_objective']:.5g}"
                    for key, r in (("as posed", row["as_posed"]), ("sums", row["sums"]))
                ),
                flush=True,
            )
    record["settings"] = vars(args)
    write_record(record, args.out)


if __name__ == "__main__":
    main()
