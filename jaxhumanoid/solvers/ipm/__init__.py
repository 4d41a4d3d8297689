"""Own primal-dual interior-point NLP solver in JAX (after the IPOPT paper, Waechter & Biegler 2006).

``solve_ipm(nlp, p, bounds)`` is the convenient entry point returning an ``NLPResult``;
``make_ipm(nlp, options)`` gives the pure, jit- and vmap-able core.
"""

from jaxhumanoid.solvers.ipm.algorithm import STATUS, make_ipm, unscale
from jaxhumanoid.solvers.ipm.driver import batch_solve_ipm, solve_ipm
from jaxhumanoid.solvers.ipm.options import IPMOptions

__all__ = ["IPMOptions", "STATUS", "batch_solve_ipm", "make_ipm", "solve_ipm", "unscale"]
