"""One NLP solve of a strategy's stage (``Runner``) and the statistics of a stage's solves.

Every NLP a strategy solves, in every stage, fallback and rerun, goes through ``Runner.run``: the
backend, its log, the progress callback and the units are fixed for a solve, and each run names
its stage.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from jaxhumanoid.ocp.nlp import NLP, Bounds
from jaxhumanoid.ocp.scaling import NLPScaling, as_jax, physical_scaling, scaled_bounds, scaled_nlp
from jaxhumanoid.solvers.ipm import precompile_ipm, solve_ipm
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.solvers.result import IterationCallback, NLPResult, constraint_violation, unscaled, unscaled_progress
from jaxhumanoid.strategy.problem import Problem
from jaxhumanoid.strategy.settings import SOLVERS
from jaxhumanoid.strategy.solution import StageStats
from jaxhumanoid.validation.casadi_backend import solve_casadi

# The adaptive barrier update (IPOPT's and the IPM's ``mu_strategy``), which later reruns of a
# failed stage-1 run or dynamic solve add to their options.
ADAPTIVE = {"mu_strategy": "adaptive"}

StageProgress = Callable[[str, int, float, float], None]
"""What ``solve`` reports after every iteration: (stage name, iteration, objective, primal infeasibility)."""


@dataclasses.dataclass(frozen=True)
class Runner:
    """How the NLPs of one solve run: by ``solver`` (``SOLVERS``), with the backend's iteration log
    when ``verbose``, reporting every iteration to ``progress`` under the run's stage name, in the
    units of ``scaling`` (``"physical"``: the scaled problem of ``ocp.scaling``, the result back in
    the problem's own units; ``"none"``: as posed)."""

    solver: str
    verbose: bool = False
    progress: StageProgress | None = None
    scaling: str = "none"

    def with_solver(self, solver: str) -> Runner:
        """The same runs by another solver."""
        return self if solver == self.solver else dataclasses.replace(self, solver=solver)

    def for_stage(self, stage: str) -> IterationCallback | None:
        """The progress callback of one run of ``stage``."""
        return None if self.progress is None else functools.partial(self.progress, stage)

    def _posed(self, problem: Problem) -> tuple[NLPScaling | None, NLP, Any, Bounds]:
        """(scaling, NLP, parameters, bounds) of ``problem`` as the backends solve it: as posed, or
        the scaled problem of ``ocp.scaling`` with its parameters (p, S)."""
        if self.scaling == "none":
            return None, problem.nlp, problem.p, problem.bounds
        s = physical_scaling(problem.layout, float(problem.p.T))
        return s, scaled_nlp(problem.nlp), (problem.p, as_jax(s)), scaled_bounds(problem.bounds, s)

    def precompile(self, problem: Problem, options: Mapping[str, Any]) -> None:
        """Start compiling, in background threads, what a later ``run`` of a problem shaped like
        ``problem`` with ``options`` compiles (IPOPT: the NLP's three programs; the IPM: its own),
        so that a later stage compiles while an earlier one solves; nothing for CasADi."""
        _, nlp, p, bounds = self._posed(problem)
        if self.solver == "ipopt":
            nlp.precompile(bounds.x0, p)
        elif self.solver == "ipm":
            precompile_ipm(nlp, p, bounds, dict(options))

    def run(self, problem: Problem, x0, options: Mapping[str, Any], stage: str) -> NLPResult:
        """One solve of ``problem`` from x0 with solver ``options``, reported as ``stage``."""
        if self.solver not in SOLVERS:
            raise ValueError(f"solver: {self.solver!r} not in {SOLVERS}")
        options = dict(options)
        progress = self.for_stage(stage)
        s, nlp, p, bounds = self._posed(problem)
        run = progress if s is None else unscaled_progress(progress, s.obj)
        if self.solver == "casadi":
            return solve_casadi(problem, x0=x0, options=options, verbose=self.verbose, progress=run, scaling=s)
        y0 = np.asarray(x0) if s is None else np.asarray(x0) * s.x
        if self.solver == "ipopt":
            res = solve_ipopt(nlp, p, bounds, x0=y0, options=options, verbose=self.verbose, progress=run)
        else:
            res = solve_ipm(nlp, p, bounds, x0=y0, options=options, progress=run)
        if s is None:
            return res
        return unscaled(res, s, violation_at(problem, np.asarray(res.x) / s.x))


def violation_at(problem: Problem, x) -> float:
    """The largest constraint or bound violation of ``problem`` at x (n,), in its own units."""
    x = np.asarray(x, dtype=float)
    g = problem.nlp.jitted().g(x, problem.p)
    b = problem.bounds
    return constraint_violation(np.asarray(g), x, b.gl, b.gu, b.xl, b.xu)


def stage_stats(name: str, problem: Problem, attempts: Sequence[NLPResult], setup_time_s: float, x0) -> StageStats:
    """Statistics of one stage from its solver runs (more than one when a fallback was needed) from
    the start point x0: status and objective of the last run, iterations and times summed over all
    of them. ``compile_time_s`` counts the one-off work: problem set-up (pattern detection,
    colouring) and tracing/compilation of the evaluators."""
    res = attempts[-1]
    return StageStats(
        name=name,
        status=res.status,
        success=bool(res.success),
        iterations=sum(int(r.iterations) for r in attempts),
        solve_time_s=sum(float(r.solve_time_s) for r in attempts),
        compile_time_s=sum(float(r.compile_time_s) for r in attempts) + setup_time_s,
        objective=float(res.objective),
        max_constraint_violation=float(res.max_constraint_violation),
        n_variables=int(problem.nlp.n),
        n_constraints=int(problem.nlp.m),
        attempts=len(attempts),
        start_violation=violation_at(problem, x0),
        runs=tuple(int(r.iterations) for r in attempts),
    )
