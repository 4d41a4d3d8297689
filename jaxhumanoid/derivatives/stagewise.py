"""Sparse NLP derivatives that exploit the stage structure of the transcription.

Every constraint of interval k and the cost of interval k are functions of the local vector
w_k = (Z[k], Z[k+1]) in R^{2s}. So

    dg/dx          = blocks J_k = d c_k / d w_k          (n_con x 2s), one per interval
    Hess Lagrangian = sum_k P_k^T H_k P_k,  H_k = d2/dw_k2 (sigma l_k + lam_k . c_k)   (2s x 2s)

with P_k selecting w_k from x. The local blocks are computed by compressed forward (Jacobian) and
forward-over-reverse (Hessian) evaluation with seeds from a colouring of the *local* pattern, for
all N intervals at once under ``vmap``. The global patterns are the unions of the local ones; the
Hessian values of the two intervals sharing Z[k+1] are summed by a precomputed two-wide gather.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives.local import ColumnGroups, LocalDerivatives, local_derivatives
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.nlp import NLP


def _free_index(layout: tr.Layout) -> np.ndarray:
    """(N+1, s) map from the full layout to NLP variable indices (-1 for fixed entries)."""
    mask = layout.free_mask()
    idx = np.full(mask.shape, -1, dtype=np.int64)
    idx[mask] = np.arange(mask.sum())
    return idx


def _local_functions(layout: tr.Layout):
    s = layout.s

    def con_r(r, p):
        return tr.interval_constraints_midpoint(layout, r, p)

    def cost(w, p, last):
        return tr.interval_cost(layout, w[:s], w[s:], p, last)

    return con_r, cost


SWEEPS = ("joint", "grouped")
# Grouped sweeps: the same derivatives to round-off in fewer operations (an IPOPT iteration's
# evaluations take 40 % less time at N = 100, scripts/bench_iteration.py), for a tenth more compile time.
DEFAULT_SWEEPS = "grouped"


def stagewise_nlp(layout: tr.Layout, p_example: tr.OCPParams, name: str = "ocp", sweeps: str = DEFAULT_SWEEPS) -> NLP:
    """The NLP of a transcription with sparse, stage-exploiting derivatives.

    ``p_example`` is used only to detect the local sparsity patterns (at random local points).
    ``sweeps``: ``"joint"`` sweeps the interval Jacobian and Hessian with one colouring each of all
    midpoint variables; ``"grouped"`` sweeps each of ``transcription.MIDPOINT_GROUPS`` apart (the
    same values to round-off, fewer operations: ``derivatives.local``).
    """
    if sweeps not in SWEEPS:
        raise ValueError(f"sweeps: {sweeps!r} not in {SWEEPS}")
    N = layout.N
    con_r, cost = _local_functions(layout)
    groups = None
    if sweeps == "grouped":
        groups = ColumnGroups(tr.midpoint_groups(layout), lambda zs, p: tr.interval_constraints_grouped(layout, zs, p))
    loc: LocalDerivatives = local_derivatives(con_r, tr.midpoint_map(layout), cost, p_example, groups=groups)
    fidx = _free_index(layout)
    n = int((fidx >= 0).sum())
    n_con = layout.n_con

    # Global column of each local column, per interval: (N, 2s).
    gcol = np.concatenate([fidx[:-1], fidx[1:]], axis=1)

    # Jacobian: keep local entries whose column is free.
    jr, jc = loc.jac_rows, loc.jac_cols
    k_all = np.repeat(np.arange(N), jr.size)
    r_all = np.tile(jr, N)
    c_all = gcol[k_all, np.tile(jc, N)]
    keep = c_all >= 0
    jac_gather = np.flatnonzero(keep)  # into the (N, nnz_local) value array, flattened
    jac_rows = (k_all * n_con + r_all)[keep]
    jac_cols = c_all[keep]

    # Hessian: map local lower-triangle entries to global (row >= col) pairs, sum duplicates.
    hr, hc = loc.hess_rows, loc.hess_cols
    k_all = np.repeat(np.arange(N), hr.size)
    gr = gcol[k_all, np.tile(hr, N)]
    gc = gcol[k_all, np.tile(hc, N)]
    keep = (gr >= 0) & (gc >= 0)
    hess_gather = np.flatnonzero(keep)
    pairs = np.stack([np.maximum(gr[keep], gc[keep]), np.minimum(gr[keep], gc[keep])], axis=1)
    uniq, seg = np.unique(pairs, axis=0, return_inverse=True)
    seg = seg.ravel()
    # Each global entry sums at most two local ones (intervals k and k+1 share Z[k+1]): a padded
    # two-wide gather instead of a scatter-add.
    order = np.argsort(seg, kind="stable")
    counts = np.bincount(seg, minlength=uniq.shape[0])
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    width = int(counts.max())
    hess_src = np.full((uniq.shape[0], width), hess_gather.size, dtype=np.int64)  # padding -> a zero
    for k in range(width):
        has = counts > k
        hess_src[has, k] = order[starts[has] + k]

    last = jnp.arange(N) == N - 1

    def full(x, p):
        return tr.full_from_free(layout, x, p)

    def local_w(x, p):
        Z = full(x, p)
        return jnp.concatenate([Z[:-1], Z[1:]], axis=1)  # (N, 2s)

    def f(x, p):
        return tr.total_cost(layout, full(x, p), p)

    def g(x, p):
        return tr.all_constraints(layout, full(x, p), p)

    grad = jax.grad(f)

    def jac_values(x, p):
        return loc.jacobian(local_w(x, p), p).ravel()[jac_gather]

    def hess_values(x, lam, sigma, p):
        W = local_w(x, p)
        lam_k = jnp.reshape(lam, (N, n_con))
        vals = loc.hessian(W, lam_k, sigma, last, p).ravel()[hess_gather]
        return jnp.sum(jnp.append(vals, 0.0)[hess_src], axis=1)

    var_stage = np.nonzero(layout.free_mask())[0]
    con_stage = np.repeat(np.arange(N), n_con)
    return NLP(
        n=n,
        m=N * n_con,
        f=f,
        g=g,
        grad=grad,
        jac_values=jac_values,
        hess_values=hess_values,
        jac_rows=jac_rows.astype(np.int64),
        jac_cols=jac_cols.astype(np.int64),
        hess_rows=uniq[:, 0].astype(np.int64),
        hess_cols=uniq[:, 1].astype(np.int64),
        var_stage=var_stage.astype(np.int64),
        con_stage=con_stage.astype(np.int64),
        name=name,
    )
