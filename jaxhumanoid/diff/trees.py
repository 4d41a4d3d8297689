"""Small helpers on parameter pytrees (``OCPParams`` and its tangents) and on vectors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def as_float_tree(p):
    """``p`` with every leaf a float64 JAX array."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.float64), p)


def zeros_like_params(p):
    """A tangent of ``p`` that is zero everywhere (float64 leaves)."""
    return jax.tree.map(lambda a: jnp.zeros_like(jnp.asarray(a, dtype=jnp.float64)), p)


def tree_vdot(a, b) -> float:
    """<a, b> summed over the leaves of two pytrees of the same structure."""
    return float(sum(np.vdot(np.asarray(u), np.asarray(v)) for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b))))


def rel_err(a, b) -> float:
    """||a - b||_2 / max(||b||_2, tiny)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(float(np.linalg.norm(b)), 1e-300))
