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

With ``ColumnGroups`` (a partition of r and the constraints written on its groups) both are swept
group by group instead: each group's columns get their own colouring, and its sweeps hold the other
groups fixed, so their tangents pass only through the operations that group reaches. The Hessian
of lam.c is then the Jacobian of its gradient, each lower-triangle entry read from the sweeps of
the earlier of its two groups (direct recovery, no star colouring). Where cheap groups (variables
that enter through products with terms of the others) take many colours, or the columns of a
dense block (positions against rates) fall into groups of unequal cost, this costs less than one
colouring of all of r, whose every sweep passes through the whole interval.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives import colouring, compressed, jaxpr_numpy, sparsity


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


@dataclasses.dataclass(frozen=True, eq=False)
class ColumnGroups:
    """A partition of r's columns, ``index[g]`` the columns of group g, and the interval's
    constraints written on the groups: ``con(zs, p)`` with zs[g] = r[index[g]] equals con_r(r, p)."""

    index: tuple[np.ndarray, ...]
    con: Callable

    @property
    def nr(self) -> int:
        """The number of columns of r."""
        return int(sum(i.size for i in self.index))

    def __post_init__(self):
        cols = np.sort(np.concatenate(self.index))
        if not np.array_equal(cols, np.arange(cols.size)):
            raise ValueError("ColumnGroups.index: expected a partition of the columns 0..nr-1")


def _grouped_sweeps(fun: Callable, groups: ColumnGroups, rows: np.ndarray, cols: np.ndarray, n_out: int, args_axes):
    """Entries (rows, cols) of d fun(zs, *args) / dr, fun: groups -> (n_out,), by compressed forward
    sweeps per group, each differentiating its group with the others held.

    Returns (values, pos, colours): values(R (K, nr), *args) -> (K, nnz) holds entry e in column
    pos[e]; ``args_axes`` are the vmap axes of ``args``; colours counts the sweeps of all groups."""
    sweeps, entries, n_colours = [], [], 0
    for g, idx in enumerate(groups.index):
        local = np.full(groups.nr, -1)
        local[idx] = np.arange(idx.size)
        e = np.flatnonzero(local[cols] >= 0)
        if e.size == 0:
            continue
        col = colouring.colour_columns(rows[e], local[cols[e]], (n_out, idx.size))

        def fun_g(z, r, *args, g=g):
            return fun(tuple(z if h == g else r[i] for h, i in enumerate(groups.index)), *args)

        sweep = compressed.stage_jacobian(fun_g, rows[e], local[cols[e]], idx.size, col, args_axes=(0, *args_axes))
        sweeps.append((sweep, idx))
        entries.append(e)
        n_colours += colouring.num_colours(col)
    pos = np.empty(rows.size, dtype=np.int64)
    pos[np.concatenate(entries)] = np.arange(rows.size)

    def values(R, *args):
        return jnp.concatenate([sweep(R[:, idx], R, *args) for sweep, idx in sweeps], axis=1)

    return values, pos, n_colours


def _grouped_hessian(groups: ColumnGroups, hr: np.ndarray, hc: np.ndarray):
    """The lower-triangle entries (hr, hc) of d2 (lam . con) / dr2 as columns of the Jacobian of the
    gradient, each entry taken from the sweeps of the earlier of its two groups. Returns
    (values(R, lam (K, n_con), p), pos, colours) as ``_grouped_sweeps``."""
    nr = groups.nr
    group = np.empty(nr, dtype=np.int64)
    for g, idx in enumerate(groups.index):
        group[idx] = g
    at = np.empty(nr, dtype=np.int64)  # position of r's entries in the gradient's group order
    at[np.concatenate(groups.index)] = np.arange(nr)
    by_col = group[hc] <= group[hr]
    rows, cols = at[np.where(by_col, hr, hc)], np.where(by_col, hc, hr)

    def grad(zs, lam, p):
        return jnp.concatenate(jax.grad(lambda zs: jnp.dot(lam, groups.con(zs, p)))(zs))

    return _grouped_sweeps(grad, groups, rows, cols, nr, (0, None))


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


def local_derivatives(
    con_r, M: np.ndarray, cost, p_example, seed: int = 0, groups: ColumnGroups | None = None
) -> LocalDerivatives:
    """Local patterns (union over random points) and evaluators of the interval derivatives; with
    ``groups``, the Jacobian and the constraints' Hessian are swept group by group (module docstring)."""
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
    if groups is None:
        jcol = colouring.colour_columns(jr, jc, (n_con, nr))
        jac_r = compressed.stage_jacobian(con_r, jr, jc, nr, colouring=jcol, args_axes=(None,))
        n_jac_colours = colouring.num_colours(jcol)
    else:
        r = np.random.default_rng(seed).normal(size=nr)
        a, b = jaxpr_numpy.evaluator(
            lambda r, p: (groups.con(tuple(r[i] for i in groups.index), p), con_r(r, p)), r, p_example
        )(r, p_example)
        if not np.allclose(a, b, rtol=1e-12, atol=1e-12):
            raise ValueError("groups.con: differs from con_r at a random point; zs[g] must be r[index[g]]")
        jac_r, pos, n_jac_colours = _grouped_sweeps(groups.con, groups, jr, jc, n_con, (None,))
        j_src = pos[j_src]

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
    if groups is None:
        hcol = colouring.star_colouring(hr, hc, nr)
        hess_r = compressed.stage_hessian(lag_r, hr, hc, nr, colouring=hcol, args_axes=(0, None))
        n_hess_colours = colouring.num_colours(hcol)
    else:
        hess_r, pos, n_hess_colours = _grouped_hessian(groups, hr, hc)
        h_src = np.concatenate([pos, np.arange(hr.size, hr.size + cr.size)])[h_src]  # the cost's entries stay
    ccol = colouring.star_colouring(cr, cc, nw)
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
        jac_rows=jw_rows,
        jac_cols=jw_cols,
        hess_rows=hw_rows,
        hess_cols=hw_cols,
        jacobian=jacobian,
        hessian=hessian,
        n_jac_colours=n_jac_colours,
        n_hess_colours=n_hess_colours + colouring.num_colours(ccol),
    )
