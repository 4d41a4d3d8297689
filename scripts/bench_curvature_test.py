"""Benchmark: IPOPT's inertia test against its inertia-free curvature test, in one run.

    OMP_NUM_THREADS=1 python scripts/bench_curvature_test.py [--tasks T1 T2 T3 T4] [--draws 4] [--seed 0]
                                                            [--tol 1e-12] [--out results/bench_curvature_test.json]

IPOPT factors K until its inertia is (n, m, 0) (Algorithm IC); on these non-convex NLPs the plain
trial (delta_w = 0) fails on most iterations, so an iteration factors K about twice. With
``neg_curv_test_tol`` > 0 IPOPT ignores a wrong inertia and accepts the step when its curvature
is positive enough (the test of Chiang and Zavala), which saves the second factorisation where
the step passes. Would the IPM gain by the same test? The NLPs are ``bench_first_trial.py``'s:
per task, draw 0 as posed and draws 1.. with the four cost terms scaled log-uniformly in [0.5, 2];
stage 1 of 2S from the initial guess and the dynamic stage 2 from IPOPT's stage-1 solution. Each
is solved by IPOPT with each test, one after the other after a two-iteration warm-up (callbacks
compiled): status, iterations, solve time, objective. The table (``bench_first_trial.table``)
gives per test the successes, the medians of iterations, solve time and time per iteration, the
median ratios (curvature / inertia, same NLP) and on how many NLPs both reach the same optimum
(objectives within 1e-6 relative).
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

from _bench import write
from bench_first_trial import problem_args, record, run_all, summarise, table

from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy import solve as strat

TESTS = ("inertia", "curvature")


def run_nlp(problem, x0, stage: str, tol: float) -> dict:
    base = strat.STAGE1_DEFAULTS if stage == "stage 1" else strat.STAGE2_DEFAULTS
    solve_ipopt(problem.nlp, problem.p, problem.bounds, x0=x0, options={**base, "max_iter": 2})
    out = {}
    for test, extra in zip(TESTS, ({}, {"neg_curv_test_tol": tol})):
        r = solve_ipopt(problem.nlp, problem.p, problem.bounds, x0=x0, options={**base, **extra})
        out[test] = record(r)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    problem_args(ap, "results/bench_curvature_test.json")
    ap.add_argument("--tol", type=float, default=1e-12, help="IPOPT's neg_curv_test_tol of the curvature test")
    args = ap.parse_args()
    if not args.tol > 0:
        raise SystemExit("--tol: expected a positive tolerance")
    records = run_all(args, lambda problem, x0, stage: run_nlp(problem, x0, stage, args.tol))
    summary = summarise(records, TESTS)
    write({"args": vars(args), "summary": summary, "records": records}, args.out)
    print(table(summary, TESTS, label="test"))


if __name__ == "__main__":
    main()
