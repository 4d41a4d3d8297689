"""Parametric sensitivities of optimal solutions x*(p) by implicit differentiation of the KKT
conditions at a converged point, and what is built on them.

- ``active_set``: which bounds and inequalities are active (IPOPT's multiplier conventions),
  implied bounds, dependent active rows (LICQ at foot lift-off);
- ``kkt``: ``KKTSensitivity``, the factorised reduced KKT system: JVP, VJP, the optimal value by
  the envelope theorem, the goal posture as moving bounds;
- ``resolve``: warm-started, reference and continued IPOPT re-solves;
- ``adjoint``: ``make_solve``, x*(p) as a JAX function with a ``jax.custom_vjp`` (IPOPT or IPM);
- ``fd``: checks against central differences of re-solves (``jaxhumanoid check --sensitivities``);
- ``inverse``: ``WeightFit``, inverse optimal control of the cost weights.
"""

from jaxhumanoid.diff.active_set import (
    ActiveSet,
    StrictComplementarityWarning,
    dependent_active_rows,
    identify_active_set,
    implied_bounds,
    missed_active_set,
)
from jaxhumanoid.diff.adjoint import KKTPoint, make_solve, warm_start
from jaxhumanoid.diff.fd import (
    FD_TOL,
    GROUPS,
    check_against_fd,
    fd_directional,
    mutation_errors,
    param_direction,
    perturb,
    sensitivity_table,
    table_rows,
)
from jaxhumanoid.diff.inverse import (
    FREE_WEIGHTS,
    WEIGHT_NAMES,
    WeightFit,
    free_weights,
    perturbed_weights,
    trajectory_scale,
    weight_names,
)
from jaxhumanoid.diff.kkt import (
    KKTSensitivity,
    KKTValues,
    bounds_for_goal,
    goal_bound_jacobians,
    kkt_values,
    objective_gradient,
    solution_jvp,
    solution_vjp,
)
from jaxhumanoid.diff.resolve import continuation_solve, reference_solve, resolve, resolve_robust
from jaxhumanoid.diff.trees import rel_err, tree_vdot, zeros_like_params

__all__ = [
    "FD_TOL",
    "FREE_WEIGHTS",
    "GROUPS",
    "WEIGHT_NAMES",
    "weight_names",
    "free_weights",
    "ActiveSet",
    "KKTPoint",
    "KKTSensitivity",
    "KKTValues",
    "StrictComplementarityWarning",
    "WeightFit",
    "bounds_for_goal",
    "check_against_fd",
    "continuation_solve",
    "dependent_active_rows",
    "fd_directional",
    "goal_bound_jacobians",
    "identify_active_set",
    "implied_bounds",
    "kkt_values",
    "make_solve",
    "missed_active_set",
    "mutation_errors",
    "objective_gradient",
    "param_direction",
    "perturb",
    "perturbed_weights",
    "reference_solve",
    "rel_err",
    "resolve",
    "resolve_robust",
    "sensitivity_table",
    "solution_jvp",
    "solution_vjp",
    "table_rows",
    "trajectory_scale",
    "tree_vdot",
    "warm_start",
    "zeros_like_params",
]
