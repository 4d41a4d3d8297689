"""Own primal-dual interior-point NLP solver in JAX (after the IPOPT paper, Waechter & Biegler 2006).

``solve_ipm(nlp, p, bounds)`` is the convenient entry point returning an ``NLPResult``;
``make_ipm(nlp, options)`` gives the pure, jit- and vmap-able core. The method is assembled from
parts, each a module of pure functions of an explicit ``problem.Context``: ``problem`` (the
scaled NLP), ``barrier``, ``step``, ``inertia``, ``direction``, ``filter``, ``linesearch``,
``restoration``, ``termination``, ``mu_oracle`` (the adaptive barrier update), with the typed
state in ``state`` and the iteration and loop in ``algorithm``.
"""

from jaxhumanoid.solvers.ipm.algorithm import make_ipm
from jaxhumanoid.solvers.ipm.driver import batch_solve_ipm, precompile_ipm, solve_ipm
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import unscale

__all__ = ["IPMOptions", "batch_solve_ipm", "make_ipm", "precompile_ipm", "solve_ipm", "unscale"]
