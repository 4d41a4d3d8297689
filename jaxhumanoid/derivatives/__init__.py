"""Sparse derivatives from JAX: sparsity patterns, graph colouring, compressed evaluation.

rows, cols = jacobian_sparsity(g, n, p)              # pattern of dg/dx
jac_values = sparse_jacobian(g, rows, cols, n)       # jac_values(x, p) -> (nnz,)
hr, hc = hessian_sparsity(lagrangian, n, lam, 1.0, p)  # random lam: exact union pattern
hess_values = sparse_hessian(lagrangian, hr, hc, n)  # hess_values(x, lam, sigma, p)
"""

from jaxhumanoid.derivatives.colouring import (
    colour_columns,
    is_valid_column_colouring,
    is_valid_star_colouring,
    jacobian_recovery,
    num_colours,
    seed_matrix,
    star_colouring,
    star_recovery,
)
from jaxhumanoid.derivatives.compressed import (
    sparse_hessian,
    sparse_jacobian,
    stage_hessian,
    stage_jacobian,
)
from jaxhumanoid.derivatives.sparsity import (
    check_pattern,
    dense_to_pattern,
    hessian_sparsity,
    jacobian_sparsity,
    pattern_to_dense,
    sample_points,
)

__all__ = [
    "check_pattern",
    "colour_columns",
    "dense_to_pattern",
    "hessian_sparsity",
    "is_valid_column_colouring",
    "is_valid_star_colouring",
    "jacobian_recovery",
    "jacobian_sparsity",
    "num_colours",
    "pattern_to_dense",
    "sample_points",
    "seed_matrix",
    "sparse_hessian",
    "sparse_jacobian",
    "stage_hessian",
    "stage_jacobian",
    "star_colouring",
    "star_recovery",
]
