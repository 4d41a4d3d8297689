"""Sparsity patterns of Jacobians and Hessians, detected from dense derivatives at sample points.

The pattern is the union of the nonzeros of the dense ``jax.jacfwd`` (or ``jax.hessian``) at a
few random points x = center + scale * u, u_i = +-U(0.5, 1.5) drawn per variable. For a function
that is analytic in x, an entry that is not identically zero vanishes only on a set of measure
zero, so the union is the exact mathematical pattern with probability one. This is tighter than a
graph-based (structural) pattern: dependencies that cancel exactly (theta_i - theta_j does not
depend on q_1) or that are multiplied by constant zeros are dropped.

Two caveats, both the caller's to control through ``points``/``center``/``scale``:

* Piecewise functions (``where``, ``maximum``, ``abs``) only show the branches that the points
  visit: sample points must cover every branch.
* A derivative that underflows to exactly 0.0 in float64 is missed (e.g. a stiff softplus
  ``log2(1 + 2^(-500 y))`` at y ~ 1). The small default ``scale`` keeps arguments moderate.

Extra ``*args`` (parameters, multipliers) are held fixed. An argument that is exactly zero can
hide entries (a multiplier of 0 removes its constraint's Hessian): pass random multipliers when
detecting the pattern of a Lagrangian's Hessian.

Cost: one dense (m, n) Jacobian or (n, n) Hessian per point, so O(m n) memory. For
stage-structured functions detect the pattern of one stage function instead.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.derivatives import jaxpr_numpy


def sample_points(n: int, num_points: int = 3, center=0.0, scale=0.1, seed: int = 0, points=None) -> np.ndarray:
    """Random points center + scale * u with u_i = +-U(0.5, 1.5), shape (num_points, n).

    ``center`` and ``scale`` are scalars or arrays of shape (n,) (per-variable scaling). The
    magnitude of u is bounded away from 0 so that no coordinate sits near a special value.
    Given ``points`` (shape (num_points, n)), returns them validated instead.
    """
    if n < 1:
        raise ValueError(f"n: expected a positive number of variables, got {n}")
    if points is not None:
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != n or points.shape[0] < 1:
            raise ValueError(f"points: expected shape (num_points, {n}), got {points.shape}")
        return points
    if num_points < 1:
        raise ValueError(f"num_points: expected at least 1, got {num_points}")
    center = np.broadcast_to(np.asarray(center, dtype=np.float64), (n,))
    scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), (n,))
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.5, 1.5, (num_points, n)) * rng.choice([-1.0, 1.0], (num_points, n))
    return center + scale * u


def _union_nonzeros(fun, n: int, arg_sets, draw, shape_ok, expected: str, derivative, name: str) -> np.ndarray:
    """Union of the nonzeros of the dense ``derivative`` of x -> fun(x, *args) over the sample
    points ``draw(k)`` of every argument tuple ``arg_sets[k]``. The derivative is traced once and
    evaluated by numpy (``jaxpr_numpy``: no compilation), or compiled once where it uses a
    primitive that interpreter lacks."""
    arg_sets = [tuple(a) for a in arg_sets]
    if not arg_sets:
        raise ValueError("arg_sets: expected at least one tuple of extra arguments")
    out = jax.eval_shape(lambda x: fun(x, *arg_sets[0]), jax.ShapeDtypeStruct((n,), jnp.float64))
    if not hasattr(out, "shape") or not shape_ok(out.shape):
        raise ValueError(f"fun: expected {expected}, got output {out}")
    dense = jaxpr_numpy.cached_evaluator(derivative(fun), fallback=jax.jit)
    mask = None
    for k, args in enumerate(arg_sets):
        for x in draw(k):
            d = np.asarray(dense(np.asarray(x, dtype=np.float64), *args))
            if not np.all(np.isfinite(d)):
                raise ValueError(f"fun: {name} is not finite at a sample point; choose points/center/scale where it is")
            mask = d != 0 if mask is None else mask | (d != 0)
    assert mask is not None  # arg_sets is not empty and draw yields points
    return mask


def jacobian_sparsity(
    fun: Callable[..., Any],
    n: int,
    *args: Any,
    points=None,
    num_points: int = 3,
    center=0.0,
    scale=0.1,
    seed: int = 0,
    arg_sets=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Pattern of d fun(x, *args) / dx for fun: (n,) -> (m,).

    Returns (rows, cols), int64 arrays of shape (nnz,), sorted row-major. ``points`` (shape
    (num_points, n)) overrides the random sample drawn from ``center``/``scale``/``seed``.
    ``arg_sets`` (instead of ``*args``): a list of argument tuples; the pattern is the union over
    them, tuple k sampled with seed ``seed + k``.
    """
    mask = _union_nonzeros(
        fun,
        n,
        _arg_sets(args, arg_sets),
        lambda k: sample_points(n, num_points, center, scale, seed + k, points),
        lambda shape: len(shape) == 1,
        "a function returning a 1-D array",
        jax.jacfwd,
        "the Jacobian",
    )
    rows, cols = np.nonzero(mask)
    return rows.astype(np.int64), cols.astype(np.int64)


def hessian_sparsity(
    fun: Callable[..., Any],
    n: int,
    *args: Any,
    points=None,
    num_points: int = 3,
    center=0.0,
    scale=0.1,
    seed: int = 0,
    arg_sets=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Lower triangle of the pattern of d^2 fun(x, *args) / dx^2 for scalar fun: (n,) -> ().

    Returns (rows, cols), int64 arrays of shape (nnz,) with rows >= cols, sorted row-major. The
    pattern is symmetrised before taking the triangle, so round-off asymmetry cannot drop an entry.
    ``arg_sets`` as in ``jacobian_sparsity`` (e.g. several random multiplier draws).
    """
    mask = _union_nonzeros(
        fun,
        n,
        _arg_sets(args, arg_sets),
        lambda k: sample_points(n, num_points, center, scale, seed + k, points),
        lambda shape: shape == (),
        "a scalar-valued function",
        jax.hessian,
        "the Hessian",
    )
    rows, cols = np.nonzero(np.tril(mask | mask.T))
    return rows.astype(np.int64), cols.astype(np.int64)


def _arg_sets(args, arg_sets):
    if arg_sets is None:
        return [args]
    if args:
        raise ValueError("arg_sets: give the extra arguments either as *args or as arg_sets, not both")
    return arg_sets


def pattern_to_dense(rows, cols, shape: tuple[int, int]) -> np.ndarray:
    """Boolean matrix of the given shape, True at (rows, cols)."""
    rows, cols = check_pattern(rows, cols, shape)
    mask = np.zeros(shape, dtype=bool)
    mask[rows, cols] = True
    return mask


def dense_to_pattern(mask) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) int64 of the True entries of a 2-D boolean matrix, sorted row-major."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask: expected a 2-D array, got shape {mask.shape}")
    rows, cols = np.nonzero(mask)
    return rows.astype(np.int64), cols.astype(np.int64)


def check_pattern(rows, cols, shape: tuple[int, int], lower: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Validate a coordinate pattern; returns (rows, cols) as int64 arrays.

    Raises ValueError if the arrays are not 1-D of equal length, hold out-of-range or duplicate
    coordinates, or (``lower=True``) have an entry above the diagonal.
    """
    rows = np.asarray(rows)
    cols = np.asarray(cols)
    if rows.ndim != 1 or cols.ndim != 1 or rows.shape != cols.shape:
        raise ValueError(f"rows/cols: expected 1-D arrays of equal length, got shapes {rows.shape} and {cols.shape}")
    if rows.size and not (np.issubdtype(rows.dtype, np.integer) and np.issubdtype(cols.dtype, np.integer)):
        raise ValueError(f"rows/cols: expected integer arrays, got {rows.dtype} and {cols.dtype}")
    rows = rows.astype(np.int64)
    cols = cols.astype(np.int64)
    m, n = shape
    if rows.size and (rows.min() < 0 or rows.max() >= m):
        raise ValueError(f"rows: entries must lie in [0, {m}), got range [{rows.min()}, {rows.max()}]")
    if cols.size and (cols.min() < 0 or cols.max() >= n):
        raise ValueError(f"cols: entries must lie in [0, {n}), got range [{cols.min()}, {cols.max()}]")
    if lower and np.any(rows < cols):
        raise ValueError("rows/cols: expected the lower triangle (rows >= cols) of a symmetric pattern")
    if np.unique(rows * n + cols).size != rows.size:
        raise ValueError("rows/cols: the pattern has duplicate coordinates")
    return rows, cols
