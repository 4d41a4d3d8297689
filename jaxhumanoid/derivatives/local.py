"""Derivatives of one interval's constraints and Lagrangian, evaluated for all intervals at once.

The local functions are c(w, p) -> (n_con,) and l(w, p, last) -> scalar of the local vector w in
R^{nw}. Their patterns are detected once (``sparsity``); values come from compressed evaluation
with seeds of a colouring of the *local* pattern (``compressed.stage_jacobian`` /
``stage_hessian``), vmapped over the intervals.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives import colouring, compressed, sparsity


@dataclasses.dataclass(frozen=True, eq=False)
class LocalDerivatives:
    jac_rows: np.ndarray
    jac_cols: np.ndarray
    hess_rows: np.ndarray  # lower triangle, rows >= cols
    hess_cols: np.ndarray
    jacobian: Callable  # (W (K, nw), p) -> (K, nnz_jac)
    hessian: Callable  # (W (K, nw), lam (K, n_con), sigma, last (K,), p) -> (K, nnz_hess)
    n_jac_colours: int
    n_hess_colours: int


def local_derivatives(con, cost, nw: int, p_example, seed: int = 0) -> LocalDerivatives:
    """Local patterns (union over random points, both values of ``last``) and their evaluators."""

    def lagrangian(w, lam, sigma, last, p):
        return sigma * cost(w, p, last) + jnp.dot(lam, con(w, p))

    jr, jc = sparsity.jacobian_sparsity(con, nw, p_example, seed=seed)
    n_con = int(jr.max()) + 1
    lam = jnp.asarray(np.random.default_rng(seed).normal(size=n_con))
    pats = [
        sparsity.hessian_sparsity(lagrangian, nw, lam, 1.0, last, p_example, seed=seed + i)
        for i, last in enumerate((False, True))
    ]
    mask = sparsity.pattern_to_dense(*pats[0], (nw, nw)) | sparsity.pattern_to_dense(*pats[1], (nw, nw))
    hr, hc = sparsity.dense_to_pattern(np.tril(mask))

    jcol = colouring.colour_columns(jr, jc, (n_con, nw))
    hcol = colouring.star_colouring(hr, hc, nw)
    jacobian = compressed.stage_jacobian(con, jr, jc, nw, colouring=jcol, args_axes=(None,))
    hessian = compressed.stage_hessian(lagrangian, hr, hc, nw, colouring=hcol, args_axes=(0, None, 0, None))
    return LocalDerivatives(jr, jc, hr, hc, jacobian, hessian, colouring.num_colours(jcol), colouring.num_colours(hcol))
