"""Benchmark: whole solves with the derivatives swept jointly against group by group, in one run.

    OMP_NUM_THREADS=1 python scripts/bench_sweeps.py [--tasks T1 T2 T3 T4] [--draws 4] [--seed 0]
                                                    [--out results/bench_sweeps.json] [--md FILE]

``stagewise_nlp(sweeps="grouped")`` gives the Jacobian and the Lagrangian Hessian the values of the
joint sweeps to round-off in fewer operations (``scripts/bench_derivatives.py`` times them alone).
Round-off moves the solvers' paths, so what a solve gains is measured here over perturbed NLPs:
``bench_first_trial.py``'s (per task, draw 0 as posed and draws 1.. with the four cost terms
scaled log-uniformly in [0.5, 2]; stage 1 of 2S from the initial guess and the dynamic stage 2
import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
from IPOPT's stage-1 solution). Each NLP is solved by IPOPT and by the IPM with each sweep, one
after the other, the sweep that goes first alternating from draw to draw (IPOPT after a
two-iteration warm-up; the IPM's solve time excludes compilation): status, iterations, solve
time, objective. The tables (``bench_first_trial.table``) give per solver the successes, the
medians of iterations, solve time and time per iteration, the median ratios (grouped / joint,
same NLP) and on how many NLPs both reach the same optimum.
"""

from __future__ import annotations

import argparse
import itertools
import pathlib

from _bench import write
from bench_first_trial import problem_args, record, run_all, summarise, table

from jaxhumanoid.derivatives.stagewise import SWEEPS
from jaxhumanoid.solvers.ipm import solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy import solve as strat
from jaxhumanoid.strategy.problem import with_sweeps

SOLVERS = ("ipopt", "ipm")


def run_nlp(problem, x0, stage: str, first: str) -> dict:
    base = strat.STAGE1_DEFAULTS if stage == "stage 1" else strat.STAGE2_DEFAULTS
    out = {}
    for sweeps in sorted(SWEEPS, key=lambda s: s != first):
        pr = with_sweeps(problem, sweeps)
        solve_ipopt(pr.nlp, pr.p, pr.bounds, x0=x0, options={**base, "max_iter": 2})
        for solver, solve in (("ipopt", solve_ipopt), ("ipm", solve_ipm)):
            r = solve(pr.nlp, pr.p, pr.bounds, x0=x0, options=dict(base))
            out[f"{solver} {sweeps}"] = record(r)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    problem_args(ap, "results/bench_sweeps.json")
    ap.add_argument("--md", default=None, help="also write the tables as Markdown")
    args = ap.parse_args()
    calls = itertools.count()  # stage 1 and stage 2 of a draw; the sweep solved first alternates by draw
    records = run_all(args, lambda problem, x0, stage: run_nlp(problem, x0, stage, SWEEPS[next(calls) // 2 % 2]))
    summary, text = {}, ""
    for solver in SOLVERS:
        variants = (f"{solver} joint", f"{solver} grouped")
        summary[solver] = summarise(records, variants)
        text += f"\n{solver}:\n\n" + table(summary[solver], variants, label="sweeps")
    write({"summary": summary, "records": records}, args.out)
    print(text)
    if args.md:
        pathlib.Path(args.md).write_text(text)


if __name__ == "__main__":
    main()
