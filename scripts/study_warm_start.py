"""Study: how the stage-2 warm start of 2S should be set up (barrier parameter, primal variants).

    OMP_NUM_THREADS=1 python scripts/study_warm_start.py --task T1 [--out results/warm_start_T1.json]

One stage-1 solve (pseudo-static, N1 = 30, relaxed contact, the strategy's stage-1 settings), then
stage 2 (full problem, N = 100) from its interpolated primal solution under several IPOPT
settings and primal variants, and 1S from the linear guess for reference. Prints a table and
writes JSON.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

import jax
import numpy as np
from _bench import write

import jaxhumanoid  # noqa: F401
from jaxhumanoid.model import contact as ct
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.solve import STAGE1_DEFAULTS, STAGE1_N, interpolate_full

VARIANTS = {
    "mu_init=0.1 (IPOPT default)": ({"mu_init": 1e-1}, None),
    "mu_init=1e-2": ({"mu_init": 1e-2}, None),
    "mu_init=1e-3": ({"mu_init": 1e-3}, None),
    "mu_init=1e-4": ({"mu_init": 1e-4}, None),
    "mu_init=1e-3, bound_push=bound_frac=1e-6": ({"mu_init": 1e-3, "bound_push": 1e-6, "bound_frac": 1e-6}, None),
    "mu_strategy=adaptive": ({"mu_strategy": "adaptive"}, None),
    "mu_init=1e-3, qd from q": ({"mu_init": 1e-3}, "smooth_qd"),
    "mu_init=1e-3, nominal-law forces": ({"mu_init": 1e-3}, "nominal_forces"),
    "mu_init=1e-3, both": ({"mu_init": 1e-3}, "both"),
}


def _smooth_qd(Z, h):
    Z = Z.copy()
    Z[:, 5:10] = np.gradient(Z[:, 0:5], h, axis=0)
    Z[0, 5:10] = 0.0
    Z[-2:, 5:10] = 0.0
    return Z


def _nominal_forces(Z, problem):
    Z = Z.copy()
    p, lay = problem.p, problem.layout
    qb, qdb = 0.5 * (Z[:-1, 0:5] + Z[1:, 0:5]), 0.5 * (Z[:-1, 5:10] + Z[1:, 5:10])
    forces = jax.vmap(lambda a, b: ct.contact_forces(p.model, p.foot, p.contact, a, b, lay.active))(qb, qdb)
    Z[:-1, 15:] = np.asarray(forces).reshape(lay.N, -1)
    return Z


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--task", default="T1")
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    final = build_problem(args.task, "A,F+C,2S", N=100)
    h = float(final.p.T) / final.layout.N
    q1, _ = reseat_for_contact(final.p, final.p.q_start, final.layout.active, ContactParams.relaxed())
    first = build_problem(
        args.task, "A,F+C,2S", N=STAGE1_N, pseudo_static=True, contact=ContactParams.relaxed(), q_start=q1
    )
    r1 = solve_ipopt(first.nlp, first.p, first.bounds, options=STAGE1_DEFAULTS)
    Zf = interpolate_full(first.full(r1.x), float(final.p.T), final.layout)
    primal = {
        None: Zf,
        "smooth_qd": _smooth_qd(Zf, h),
        "nominal_forces": _nominal_forces(Zf, final),
        "both": _nominal_forces(_smooth_qd(Zf, h), final),
    }
    results = {"stage1": {"status": r1.status, "iterations": r1.iterations}}
    print(f"{args.task} stage 1: {r1.status}, {r1.iterations} iterations")
    print(f"{'stage-2 variant':45s} {'status':28s} {'its':>5s} {'time s':>7s} {'objective':>10s}")
    runs = [(name, opts, primal[kind]) for name, (opts, kind) in VARIANTS.items()] + [
        ("1S from the linear guess", {}, None)
    ]
    for name, opts, Z in runs:
        x0 = (
            None
            if Z is None
            else np.clip(np.asarray(tr.free_from_full(final.layout, Z)), final.bounds.xl, final.bounds.xu)
        )
        r = solve_ipopt(final.nlp, final.p, final.bounds, x0=x0, options={"max_iter": 1500, **opts})
        results[name] = {
            "status": r.status,
            "iterations": r.iterations,
            "solve_time_s": r.solve_time_s,
            "objective": r.objective,
        }
        print(f"{name:45s} {r.status:28s} {r.iterations:5d} {r.solve_time_s:7.2f} {r.objective:10.4g}", flush=True)
    write({"task": args.task, "results": results}, args.out or f"results/warm_start_{args.task}.json")


if __name__ == "__main__":
    main()
