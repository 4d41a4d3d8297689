"""Study: the start of stage 2 on the reference posing, the direct hand-over from one stage-1 point.

    OMP_NUM_THREADS=1 python scripts/study_reference_start.py --draws 6 \
        [--tasks T1 T2 T3 T4] [--ref-dir ../shared/reference_posing] [--out results/study_reference_start.json]

Each reference-posing file, over ``--draws`` draws of its cost weights (the reference-draws suite's,
``studies.suites.reference_draw_weights``; draw 0 as posed), is solved as A,F+C,2S by IPOPT with
the direct hand-over (``solve``). Stage 2 is then solved again from the same stage-1 point under
each variant, with the options ``solve`` gives it:

- ``multipliers``: IPOPT's ``warm_start_init_point`` with stage 1's multipliers carried over.
  Rows and bounds are interpolated as the primal variables are (constraint rows at interval
  midpoints, bound multipliers in the full layout, ``handover.interpolate_full``) and scaled by
  how each kind scales with the step h: the kinematic rows (6a) keep their value (a costate),
  stage 1's dynamics rows (8) are divided by h1 (stage 2's (6b) carry a factor h), and every other
  row and bound multiplier is multiplied by h2 / h1 (they balance terms of (7), which carry h).
- ``multipliers_rescaled``: the same, the bound multipliers scaled before they are interpolated:
  starting multipliers that differ from ``multipliers`` by rounding only (at most about 1e-13),
  a measure of how far such a difference moves the path.
- ``projected``: the interpolated start moved onto the equality rows (and violated inequality rows)
  by damped Gauss-Newton steps of least change in the norm scaled by max(1, |x0|), clipped to the
  bounds.

Prints one line per problem and writes a JSON record with the commit and the environment.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import pathlib

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.solvers.result import NLPResult
from jaxhumanoid.strategy.handover import interpolate_full
from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.studies.bench import recorded_solve, write_record
from jaxhumanoid.studies.suites import SAME_OPTIMUM_RTOL, reference_draw_weights

WARM = {
    "warm_start_init_point": "yes",
    "warm_start_bound_push": 1e-6,
    "warm_start_bound_frac": 1e-6,
    "warm_start_mult_bound_push": 1e-6,
    "warm_start_slack_bound_push": 1e-6,
    "warm_start_slack_bound_frac": 1e-6,
}
VARIANTS = ("as_solved", "multipliers", "multipliers_rescaled", "projected")


def carried_multipliers(
    res1: NLPResult, prob1, prob2, scale_first: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Stage 1's multipliers (lam_g, z_l, z_u) on stage 2's rows and variables (module docstring).
    ``scale_first``: the bound multipliers scaled before they are interpolated, which changes only
    the rounding (``multipliers_rescaled``)."""
    L1, L2, T = prob1.layout, prob2.layout, float(prob2.p.T)
    h1, h2, n, nc = T / L1.N, T / L2.N, L1.n_links, L1.n_con
    rows1 = np.asarray(res1.lam_g).reshape(L1.N, nc)
    mid1, mid2 = (np.arange(L1.N) + 0.5) * T / L1.N, (np.arange(L2.N) + 0.5) * T / L2.N
    rows2 = np.stack([np.interp(mid2, mid1, rows1[:, j]) for j in range(nc)], axis=1)
    scale = np.full(nc, h2 / h1)
    scale[:n], scale[n : 2 * n] = 1.0, 1.0 / h1
    free1 = np.flatnonzero(L1.free_mask().ravel())
    bounds = []
    for z in (res1.z_l, res1.z_u):
        Z1 = np.zeros((L1.N + 1, L1.s))
        Z1.ravel()[free1] = np.asarray(z) * (h2 / h1 if scale_first else 1.0)
        z2 = np.asarray(tr.free_from_full(L2, interpolate_full(Z1, T, L2)))
        bounds.append(z2 if scale_first else z2 * h2 / h1)
    return (rows2 * scale).ravel(), bounds[0], bounds[1]


def projected(problem, x0: np.ndarray, steps: int = 15) -> tuple[np.ndarray, list[float]]:
    """x0 moved towards the rows it violates by damped Gauss-Newton steps; returns (x, violations)."""
    nlp, p, b = problem.nlp, problem.p, problem.bounds
    fns, gl, gu = nlp.jitted(), np.asarray(b.gl), np.asarray(b.gu)
    eq, scale2 = gl == gu, np.maximum(1.0, np.abs(x0)) ** 2

    def residual(x):
        g = np.asarray(fns.g(x, p))
        return np.where(eq, g - gl, np.minimum(0.0, g - gl) + np.maximum(0.0, g - gu))

    x, c = x0.copy(), residual(x0)
    history = [float(np.max(np.abs(c)))]
    for _ in range(steps):
        act = eq | (c != 0)
        _, jv = fns.grad_jac(x, p)
        J = sp.csr_matrix((np.asarray(jv), (nlp.jac_rows, nlp.jac_cols)), shape=(nlp.m, nlp.n))[act]
        A = (J @ sp.diags(scale2) @ J.T).tocsc() + 1e-12 * sp.eye(J.shape[0])
        dx, step = scale2 * (J.T @ spla.splu(A).solve(-c[act])), 1.0
        while step > 1e-4 and np.max(np.abs(residual(np.clip(x + step * dx, b.xl, b.xu)))) >= history[-1]:
            step *= 0.5
        x = np.clip(x + step * dx, b.xl, b.xu)
        c = residual(x)
        history.append(float(np.max(np.abs(c))))
    return x, history


def study_case(path: pathlib.Path, draw: int) -> dict:
    kwargs = load_task_file(path).as_solve_kwargs()
    _, runs = recorded_solve(**kwargs, weights=reference_draw_weights(kwargs, draw))
    last1 = [r for r in runs if r.stage.startswith("stage 1")][-1]
    prob1, res1 = last1.problem, last1.result
    name, prob2, x0, options, res2 = runs[-1]
    assert name.startswith("stage 2"), name
    nlp, p, b = prob2.nlp, prob2.p, prob2.bounds
    warm = {
        key: NLPResult(x0, *carried_multipliers(res1, prob1, prob2, first), "", True, 0, 0.0, 0.0, 0.0, 0.0)
        for key, first in (("multipliers", False), ("multipliers_rescaled", True))
    }
    x_proj, violations = projected(prob2, x0)
    runs = {"as_solved": res2}
    for key, w in warm.items():
        runs[key] = solve_ipopt(nlp, p, b, x0=x0, options={**options, **WARM}, warm=w)
    runs["projected"] = solve_ipopt(nlp, p, b, x0=x_proj, options=options)
    row = {"task": path.stem, "draw": draw, "stage1_iterations": res1.iterations, "projection_violations": violations}
    for key, r in runs.items():
        row[key] = {"status": r.status, "iterations": int(r.iterations), "objective": float(r.objective)}
    return row


def summary(rows: list[dict]) -> dict:
    """Per task and over all: stage 2's median and total iterations per variant, and how often it
    reaches the best optimum any variant found for that problem (``SAME_OPTIMUM_RTOL``)."""
    out = {}
    for task in sorted({r["task"] for r in rows}) + ["all"]:
        sel = [r for r in rows if task in ("all", r["task"])]
        best = [min(r[v]["objective"] for v in VARIANTS) for r in sel]
        out[task] = {
            v: {
                "median": float(np.median([r[v]["iterations"] for r in sel])),
                "total": int(sum(r[v]["iterations"] for r in sel)),
                "at_best": int(sum(r[v]["objective"] <= bo + SAME_OPTIMUM_RTOL * abs(bo) for r, bo in zip(sel, best))),
                "problems": len(sel),
            }
            for v in VARIANTS
        }
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", nargs="+", default=["T1", "T2", "T3", "T4"])
    ap.add_argument("--draws", type=int, default=6)
    ap.add_argument("--ref-dir", default="../shared/reference_posing")
    ap.add_argument("--out", default="results/study_reference_start.json")
    args = ap.parse_args()
    rows = []
    for task in args.tasks:
        for draw in range(args.draws):
            rows.append(study_case(pathlib.Path(args.ref_dir) / f"{task}.toml", draw))
            r = rows[-1]
            print(
                task, draw, " ".join(f"{v} {r[v]['iterations']} {r[v]['objective']:.6g}" for v in VARIANTS), flush=True
            )
    summ = summary(rows)
    for task, s in summ.items():
        print(
            task,
            " | ".join(
                f"{v}: median {s[v]['median']:.0f}, total {s[v]['total']}, best {s[v]['at_best']}/{s[v]['problems']}"
                for v in VARIANTS
            ),
        )
    write_record(
        {"command": "scripts/study_reference_start.py", "draws": args.draws, "rows": rows, "summary": summ}, args.out
    )


if __name__ == "__main__":
    main()
