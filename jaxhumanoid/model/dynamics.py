"""Euler-Lagrange dynamics (1)-(2) and the pseudo-static model (8).

    B(q) qdd + C(q, qd) qd + G(q) = Q(q, qd, u)                                   (1)
    Q_j = sum_{i in F} J_vi(q)[:, j]^T f_ci + u_j                                 (2)

Inertia matrix in the paper's pattern form (Sec. II-C). With the COM lever matrix A
(``kinematics.com_lever``), U = L^T (upper-triangular ones) and cos-matrix
Ctheta[i, j] = cos(theta_i - theta_j) = cos(qbar) with qbar = q_{min(i,j)+1} + ... + q_{max(i,j)},

    M_l[r, s] = m_l sum_{i >= r} sum_{j >= s} A[l, i] A[l, j] cos(theta_i - theta_j)
              (the paper's sum of (a_i^l)^2 over i >= max(r, s) plus the i != j cosine terms)
    I_l[r, s] = i_l  if max(r, s) <= l else 0
    B = sum_l (M_l + I_l) = U (K o Ctheta) U^T + sum_l I_l,   K = sum_l m_l A[l]^T A[l]

K is a constant n x n matrix: the whole q-dependence sits in the n(n+1)/2 distinct cosines (15 for
the humanoid), which is the graph compression the paper obtains by hand.

Coriolis matrix from the same form: in absolute angles, C_theta[i, j] = K[i, j] sin(theta_i -
theta_j) thetad_j, and C(q, qd) = U C_theta U^T; then dB/dt - 2C is skew-symmetric.
Gravity: G = U G_theta with G_theta[i] = g w_i cos(theta_i), w_i = sum_l m_l A[l, i].
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import PlanarChain


def _upper_ones(n: int):
    return jnp.triu(jnp.ones((n, n)))


def _angle_differences(q):
    """cos(theta_i - theta_j) and sin(theta_i - theta_j), (n, n) each, from n cosines and n sines
    (outer products: 2n transcendental evaluations instead of 2n^2, which matters inside the
    compressed derivative sweeps)."""
    theta = kin.absolute_angles(q)
    c, s = jnp.cos(theta), jnp.sin(theta)
    return jnp.outer(c, c) + jnp.outer(s, s), jnp.outer(s, c) - jnp.outer(c, s)


def lever_inertia(model: PlanarChain):
    """K = sum_l m_l A[l]^T A[l], shape (n, n); constant for given parameters."""
    A = kin.com_lever(model)
    return (A.T * jnp.asarray(model.m)) @ A


def lever_mass(model: PlanarChain):
    """w_i = sum_l m_l A[l, i]: the mass-weighted lever of theta_i, shape (n,)."""
    return jnp.asarray(model.m) @ kin.com_lever(model)


def rotational_inertia(model: PlanarChain):
    """sum_l I_l: entry (r, s) = sum of i_l over links l >= max(r, s)."""
    tail = jnp.flip(jnp.cumsum(jnp.flip(jnp.asarray(model.inertia))))  # tail[k] = sum_{l>=k} i_l
    idx = jnp.maximum(jnp.arange(model.n)[:, None], jnp.arange(model.n)[None, :])
    return tail[idx]


def inertia_matrix(model: PlanarChain, q):
    """B(q), shape (n, n): pattern form of Sec. II-C."""
    cos_diff, _ = _angle_differences(q)
    U = _upper_ones(model.n)
    return U @ (lever_inertia(model) * cos_diff) @ U.T + rotational_inertia(model)


def coriolis_matrix(model: PlanarChain, q, qd):
    """C(q, qd), shape (n, n), with dB/dt - 2C skew-symmetric."""
    _, sin_diff = _angle_differences(q)
    thetad = kin.absolute_angles(qd)
    U = _upper_ones(model.n)
    return U @ (lever_inertia(model) * sin_diff * thetad[None, :]) @ U.T


def coriolis_vector(model: PlanarChain, q, qd):
    """C(q, qd) qd, shape (n,), without forming C: U (K o S) thetad^2."""
    _, sin_diff = _angle_differences(q)
    thetad = kin.absolute_angles(qd)
    return kin.to_relative_gradient((lever_inertia(model) * sin_diff) @ thetad**2)


def gravity_vector(model: PlanarChain, q):
    """G(q) = dV/dq, shape (n,)."""
    theta = kin.absolute_angles(q)
    return kin.to_relative_gradient(model.g * lever_mass(model) * jnp.cos(theta))


def potential_energy(model: PlanarChain, foot, q):
    """V(q) = sum_l m_l g y_COM_l."""
    return model.g * jnp.dot(jnp.asarray(model.m), kin.com_positions(model, foot, q)[:, 1])


def kinetic_energy(model: PlanarChain, q, qd):
    """T = 1/2 sum_l (m_l |v_COM_l|^2 + i_l omega_l^2), from the COM Jacobians (not from B)."""
    v = kin.com_jacobians(model, q) @ qd  # (n, 2)
    omega = kin.absolute_angles(qd)
    return 0.5 * (jnp.dot(jnp.asarray(model.m), jnp.sum(v**2, axis=-1)) + jnp.dot(jnp.asarray(model.inertia), omega**2))


def generalized_forces(model: PlanarChain, q, u, f_contact, active):
    """Q(q, qd, u) of (2) for given contact forces.

    u: (n,) joint torques; f_contact: (k, 2) forces (f_t, f_n) at the joints listed in
    ``active`` (k indices in 1..n, a static tuple); returns (n,).
    """
    if len(active) == 0:
        return u
    J = kin.joint_jacobians(model, q)[jnp.asarray(active) - 1]  # (k, 2, n)
    return u + jnp.einsum("kdj,kd->j", J, f_contact)


def dynamics_residual(model: PlanarChain, q, qd, qdd, u, f_contact, active):
    """B qdd + C qd + G - Q, shape (n,): zero along solutions of (1)."""
    return (
        inertia_matrix(model, q) @ qdd
        + coriolis_vector(model, q, qd)
        + gravity_vector(model, q)
        - generalized_forces(model, q, u, f_contact, active)
    )


def pseudo_static_residual(model: PlanarChain, q, u, f_contact, active):
    """G(q) - Q(q, qd, u) of the pseudo-static model (8); qd enters only through f_contact."""
    return gravity_vector(model, q) - generalized_forces(model, q, u, f_contact, active)
