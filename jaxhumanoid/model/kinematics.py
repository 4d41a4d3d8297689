"""Kinematics of the planar serial chain (Fig. 1).

With relative angles q and absolute angles theta = L q (L lower-triangular ones, theta_l =
q_1 + ... + q_l), every point of link l is O_0 plus a weighted sum of the unit vectors
e_i = (cos theta_i, sin theta_i), i <= l:

    O_l   = O_0 + sum_{i<=l} a_i e_i                       (joints: knee ... hand)
    COM_l = O_0 + sum_{i<=l} A[l, i] e_i,  A[l, i] = a_i (i < l), a_l - c_l (i = l)

so all positions, Jacobians and accelerations are ``lever @ e``-type products with constant
lever matrices. Derivatives with respect to q follow from d/dq = L^T d/dtheta.
All functions act on one configuration; use ``jax.vmap`` over stages.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.model.params import FootParams, PlanarChain


def absolute_angles(q):
    """theta = L q, theta_l = q_1 + ... + q_l. Shape (n,) -> (n,)."""
    return jnp.cumsum(q, axis=-1)


def to_relative_gradient(grad_theta):
    """Map a gradient w.r.t. theta to one w.r.t. q: L^T v, i.e. reverse cumulative sum."""
    return jnp.flip(jnp.cumsum(jnp.flip(grad_theta, -1), -1), -1)


def joint_lever(model: PlanarChain):
    """Lever matrix of the joints O_1..O_n: P[l, i] = a_i for i <= l. Shape (n, n)."""
    return jnp.tril(jnp.broadcast_to(jnp.asarray(model.a), (model.n, model.n)))


def com_lever(model: PlanarChain):
    """Lever matrix of the link COMs: A[l, i] = a_i (i < l), a_l - c_l (i = l), 0 (i > l)."""
    return joint_lever(model) - jnp.diag(jnp.asarray(model.c))


def _unit(theta):
    return jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)  # (n, 2)


def ankle(foot: FootParams):
    """O_0 = (0, ankle_height)."""
    return jnp.stack([jnp.zeros_like(foot.ankle_height), jnp.asarray(foot.ankle_height, dtype=jnp.float64)])


def joint_positions(model: PlanarChain, foot: FootParams, q):
    """Positions of O_0 (ankle) and the joints O_1..O_n (the humanoid: knee, hip, shoulder, elbow, hand).

    q: (n,) -> (n + 1, 2) array of (x, y).
    """
    rel = joint_lever(model) @ _unit(absolute_angles(q))
    o0 = ankle(foot)
    return jnp.concatenate([o0[None], o0 + rel], axis=0)


def com_positions(model: PlanarChain, foot: FootParams, q):
    """Centres of mass of the n links. q: (n,) -> (n, 2)."""
    return ankle(foot) + com_lever(model) @ _unit(absolute_angles(q))


def contact_gaps(model: PlanarChain, foot: FootParams, q):
    """Normal gaps y_i = height of O_i above the ground, i = 1..n. q: (n,) -> (n,)."""
    return foot.ankle_height + joint_lever(model) @ jnp.sin(absolute_angles(q))


def point_jacobians(lever, q):
    """Linear velocity Jacobians J_v (d position / d q) of the points with lever matrix ``lever``.

    lever: (p, n); q: (n,) -> (p, 2, n). d/dtheta_i of point p is lever[p, i] * e_i^perp,
    e_i^perp = (-sin, cos); then d/dq_j = sum_{i >= j} d/dtheta_i.
    """
    theta = absolute_angles(q)
    e_perp = jnp.stack([-jnp.sin(theta), jnp.cos(theta)], axis=0)  # (2, n)
    j_theta = lever[:, None, :] * e_perp[None]  # (p, 2, n)
    return to_relative_gradient(j_theta)


def joint_jacobians(model: PlanarChain, q):
    """J_v of the joints O_1..O_n, shape (n, 2, n): J[i] maps qd to the velocity of O_{i+1}."""
    return point_jacobians(joint_lever(model), q)


def com_jacobians(model: PlanarChain, q):
    """J_v of the n link COMs, shape (n, 2, n)."""
    return point_jacobians(com_lever(model), q)


def joint_velocities(model: PlanarChain, q, qd):
    """Velocities of O_1..O_n, shape (n, 2)."""
    return joint_jacobians(model, q) @ qd
