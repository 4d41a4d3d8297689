"""Smooth penalty contact (3) and regularised Coulomb friction (4), Sec. II-D.

    f_n(y)      = f0 log2(1 + 2^(-kappa y / f0))                                  (3)
    f_t(y, xd)  = -mu f_n(y) tanh(xd / xhat)                                      (4)

(3) is a base-2 softplus: evaluated as f0 * logaddexp2(0, -kappa y / f0), which neither
overflows for deep penetration (y -> -inf, f_n -> -kappa y) nor underflows to a wrong value
for large gaps (f_n -> f0 2^(-kappa y / f0)).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain


def normal_force(contact: ContactParams, y):
    """f_n(y) of (3); y is the normal gap (negative = penetration)."""
    return contact.f0 * jnp.logaddexp2(0.0, -contact.kappa * y / contact.f0)


def friction_force(contact: ContactParams, f_n, xd):
    """f_t of (4) for a normal force f_n and tangential sliding velocity xd."""
    return -contact.mu * f_n * jnp.tanh(xd / contact.xhat)


def contact_forces(model: PlanarChain, foot: FootParams, contact: ContactParams, q, qd, active):
    """Forces (f_t, f_n) at the joints in ``active`` (indices 1..n), shape (k, 2).

    Gap y and sliding velocity xd are those of O_i at (q, qd); in the transcription they are
    evaluated at the collocation midpoints.
    """
    idx = jnp.asarray(active, dtype=jnp.int32) - 1
    y = kin.contact_gaps(model, foot, q)[idx]
    xd = kin.joint_velocities(model, q, qd)[idx, 0]
    f_n = normal_force(contact, y)
    return jnp.stack([friction_force(contact, f_n, xd), f_n], axis=-1)
