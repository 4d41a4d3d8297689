"""Derivatives of one interval's constraints and Lagrangian, evaluated for all intervals at once.

The interval's constraints are c(r, p) of its midpoint variables r = M w, with w = (Z[k], Z[k+1])
and M constant (``ocp.transcription.midpoint_map``); its cost l(w, p, last) is quadratic in w.
Derivatives are taken in r, where the nonlinear dependence is concentrated in few variables, with
compressed evaluation (seeds from a distance-2 column colouring of the local Jacobian pattern and
a star colouring of the local Hessian pattern, ``compressed.stage_jacobian``/``stage_hessian``),
vmapped over the intervals, and mapped back to w by the chain rule:

    dc/dw = (dc/dr) M,        d2(lam.c)/dw2 = M^T (d2(lam.c)/dr2) M,

each as a precomputed fixed-width gather from the r-values to the entries of the w-pattern.
The cost's (constant-pattern) Hessian is added in w directly.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives import colouring, compressed, sparsity


@dataclasses.dataclass(frozen=True, eq=False)
class LocalDerivatives:
    jac_rows: np.ndarray  # local pattern in w
    jac_cols: np.ndarray
    hess_rows: np.ndarray  # lower triangle, rows >= cols
    hess_cols: np.ndarray
    jacobian: Callable  # (W (K, nw), p) -> (K, nnz_jac)
    hessian: Callable  # (W (K, nw), lam (K, n_con), sigma, last (K,), p) -> (K, nnz_hess)
    n_jac_colours: int
    n_hess_colours: int


def _chain(entries: dict):
    """Targets (sorted pattern) and their sources as a padded (n_targets, width) gather:
    value[t] = sum_k source[src[t, k]] * coef[t, k] (padding has coefficient 0). A gather is much
    cheaper than a scatter-add on CPU."""
    keys = sorted(entries)
    width = max(len(v) for v in entries.values())
    src = np.zeros((len(keys), width), dtype=np.int64)
    coef = np.zeros((len(keys), width))
    for t, key in enumerate(keys):
        for k, (s_idx, c) in enumerate(entries[key]):
            src[t, k], coef[t, k] = s_idx, c
    rows = np.array([k[0] for k in keys], dtype=np.int64)
    cols = np.array([k[1] for k in keys], dtype=np.int64)
    return rows, cols, src, coef


def local_derivatives(con_r, M: np.ndarray, cost, p_example, seed: int = 0) -> LocalDerivatives:
    """Local patterns (union over random points) and evaluators of the interval derivatives."""
    nr, nw = M.shape
    Mj = jnp.asarray(M)
    col_of = [np.flatnonzero(M[i]) for i in range(nr)]

    def lag_r(r, lam, p):
        return jnp.dot(lam, con_r(r, p))

    # Jacobian in r, mapped to w.
    jr, jc = sparsity.jacobian_sparsity(con_r, nr, p_example, seed=seed)
    n_con = int(jr.max()) + 1
    entries = defaultdict(list)
    for e, (row, i) in enumerate(zip(jr, jc)):
        for a in col_of[i]:
            entries[(row, a)].append((e, M[i, a]))
    jw_rows, jw_cols, j_src, j_coef = _chain(entries)
    jcol = colouring.colour_columns(jr, jc, (n_con, nr))
    jac_r = compressed.stage_jacobian(con_r, jr, jc, nr, colouring=jcol, args_axes=(None,))

    # Hessian of lam.c in r (pattern union over two multiplier draws), mapped to w; plus the cost.
    rng = np.random.default_rng(seed)
    hr, hc = sparsity.hessian_sparsity(
        lag_r, nr, seed=seed, arg_sets=[(jnp.asarray(rng.normal(size=n_con)), p_example) for _ in range(2)]
    )
    cr, cc = sparsity.hessian_sparsity(cost, nw, seed=seed, arg_sets=[(p_example, last) for last in (False, True)])

    entries = defaultdict(list)
    for e, (i, j) in enumerate(zip(hr, hc)):
        for i2, j2 in ((i, j), (j, i)) if i != j else ((i, j),):
            for a in col_of[i2]:
                for b in col_of[j2]:
                    if a >= b:
                        entries[(a, b)].append((e, M[i2, a] * M[j2, b]))
    for e, (a, b) in enumerate(zip(cr, cc)):
        entries[(a, b)].append((hr.size + e, 1.0))
    hw_rows, hw_cols, h_src, h_coef = _chain(entries)
    hcol = colouring.star_colouring(hr, hc, nr)
    ccol = colouring.star_colouring(cr, cc, nw)
    hess_r = compressed.stage_hessian(lag_r, hr, hc, nr, colouring=hcol, args_axes=(0, None))
    hess_cost = compressed.stage_hessian(
        lambda w, sigma, last, p: sigma * cost(w, p, last), cr, cc, nw, colouring=ccol, args_axes=(None, 0, None)
    )

    j_src_j, j_coef_j = jnp.asarray(j_src), jnp.asarray(j_coef)
    h_src_j, h_coef_j = jnp.asarray(h_src), jnp.asarray(h_coef)

    def jacobian(W, p):
        vals = jac_r(W @ Mj.T, p)  # (K, nnz_r)
        return jnp.sum(vals[:, j_src_j] * j_coef_j, axis=-1)

    def hessian(W, lam, sigma, last, p):
        vals = jnp.concatenate([hess_r(W @ Mj.T, lam, p), hess_cost(W, sigma, last, p)], axis=1)
        return jnp.sum(vals[:, h_src_j] * h_coef_j, axis=-1)

    return LocalDerivatives(
        jw_rows,
        jw_cols,
        hw_rows,
        hw_cols,
        jacobian,
        hessian,
        colouring.num_colours(jcol),
        colouring.num_colours(hcol) + colouring.num_colours(ccol),
    )
