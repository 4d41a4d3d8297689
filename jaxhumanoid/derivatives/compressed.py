"""Compressed evaluation of sparse Jacobians and Hessians with JAX.

The structure (pattern, colouring, seeds, gather indices) is fixed in numpy when the value
function is built; the returned functions are pure and jit-/vmap-/grad-compatible. Only the
first argument x is differentiated; extra ``*args`` pass through untouched, so a Lagrangian
Hessian is ``sparse_hessian(lagrangian, ...)(x, lam, sigma, p)``.

* Jacobian: one ``jax.jvp`` per colour (vmapped), giving S J^T of shape (num_colours, m); entries
  are gathered directly.
* Hessian: one forward-over-reverse Hessian-vector product per star colour (vmapped), giving
  S H of shape (num_colours, n); lower-triangle entries are gathered directly (``star_recovery``).

The stage helpers apply the same to a per-stage function and vmap over stages; the caller
scatters the (K, nnz_local) values into its global pattern.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives import colouring as col
from jaxhumanoid.derivatives.sparsity import check_pattern


def _check_x(x, n: int):
    if jnp.ndim(x) != 1 or jnp.shape(x)[0] != n:
        raise ValueError(f"x: expected shape ({n},), got {jnp.shape(x)}")


def sparse_jacobian(fun: Callable[..., Any], rows, cols, n: int, colouring=None) -> Callable[..., jax.Array]:
    """Values of d fun(x, *args) / dx at the pattern (rows, cols), fun: (n,) -> (m,).

    ``colouring`` is a column colouring (n,) valid for the pattern (``colour_columns`` if None).
    Returns ``jac_values(x, *args) -> (nnz,)``, the entries in the order of (rows, cols).
    Raises ValueError for a bad pattern or an invalid colouring.
    """
    if n < 1:
        raise ValueError(f"n: expected a positive number of variables, got {n}")
    rows = np.asarray(rows)
    m = int(rows.max()) + 1 if rows.size else 0
    if colouring is None:
        colouring = col.colour_columns(rows, cols, (m, n))
    colour_index, row_index = col.jacobian_recovery(rows, cols, (m, n), colouring)
    seeds = col.seed_matrix(colouring)

    def jac_values(x, *args):
        _check_x(x, n)

        def f(z):
            return fun(z, *args)

        out = jax.eval_shape(f, x)
        if out.ndim != 1 or out.shape[0] < m:
            raise ValueError(f"fun: expected output shape (m,) with m >= {m} (pattern rows), got {out.shape}")
        tangents = jnp.asarray(seeds, dtype=x.dtype)
        compressed = jax.vmap(lambda s: jax.jvp(f, (x,), (s,))[1])(tangents)  # (num_colours, m)
        return compressed[colour_index, row_index]

    return jac_values


def sparse_hessian(fun: Callable[..., Any], rows, cols, n: int, colouring=None) -> Callable[..., jax.Array]:
    """Values of d^2 fun(x, *args) / dx^2 at the lower-triangle pattern (rows >= cols).

    fun: (n,) -> () scalar. ``colouring`` is a star colouring (n,) of the pattern
    (``star_colouring`` if None). Returns ``hess_values(x, *args) -> (nnz,)`` in the order of
    (rows, cols). Raises ValueError for a bad pattern or an invalid colouring.
    """
    if n < 1:
        raise ValueError(f"n: expected a positive number of variables, got {n}")
    rows, cols = check_pattern(rows, cols, (n, n), lower=True)
    if colouring is None:
        colouring = col.star_colouring(rows, cols, n)
    colour_index, component = col.star_recovery(rows, cols, n, colouring)
    seeds = col.seed_matrix(colouring)

    def hess_values(x, *args):
        _check_x(x, n)

        def f(z):
            return fun(z, *args)

        out = jax.eval_shape(f, x)
        if out.shape != ():
            raise ValueError(f"fun: expected a scalar-valued function, got output shape {out.shape}")
        grad = jax.grad(f)
        tangents = jnp.asarray(seeds, dtype=x.dtype)
        compressed = jax.vmap(lambda s: jax.jvp(grad, (x,), (s,))[1])(tangents)  # (num_colours, n)
        return compressed[colour_index, component]

    return hess_values


def _stage_map(local_values: Callable, nz: int, args_axes) -> Callable[..., jax.Array]:
    def values(Z, *args):
        if jnp.ndim(Z) != 2 or jnp.shape(Z)[1] != nz:
            raise ValueError(f"Z: expected shape (K, {nz}), got {jnp.shape(Z)}")
        axes = (args_axes,) * len(args) if not isinstance(args_axes, tuple) else args_axes
        if len(axes) != len(args):
            raise ValueError(f"args_axes: expected {len(args)} entries (one per extra argument), got {len(axes)}")
        return jax.vmap(local_values, in_axes=(0, *axes))(Z, *args)

    return values


def stage_jacobian(
    stage_fun: Callable[..., Any], local_rows, local_cols, nz: int, colouring=None, args_axes=0
) -> Callable[..., jax.Array]:
    """Per-stage sparse Jacobians of stage_fun: (nz,) -> (mc,), vmapped over K stages.

    (local_rows, local_cols) is the pattern of one stage's Jacobian (mc, nz). ``args_axes`` gives
    the vmap axis of each extra argument: an int/None for all, or a tuple with one entry per
    argument (a pytree prefix, as in ``jax.vmap``); 0 means the argument has a leading K axis,
    None means it is shared by all stages. Returns ``values(Z, *args) -> (K, nnz_local)`` with
    Z of shape (K, nz).
    """
    return _stage_map(sparse_jacobian(stage_fun, local_rows, local_cols, nz, colouring), nz, args_axes)


def stage_hessian(
    stage_fun: Callable[..., Any], local_rows, local_cols, nz: int, colouring=None, args_axes=0
) -> Callable[..., jax.Array]:
    """Per-stage sparse Hessians (lower triangle) of a scalar stage_fun: (nz,) -> (), vmapped.

    Typical use: stage_fun(z, lam_k, p) = lam_k . c(z, p) with per-stage multipliers lam_k
    (args_axes=(0, None)). Returns ``values(Z, *args) -> (K, nnz_local)`` with Z of shape (K, nz);
    ``args_axes`` as in ``stage_jacobian``.
    """
    return _stage_map(sparse_hessian(stage_fun, local_rows, local_cols, nz, colouring), nz, args_axes)
