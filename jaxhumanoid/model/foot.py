"""Steady-foot requirements (5), Sec. II-E.

The foot is massless and at rest, so the ground reaction f_c0 = (f_t0, f_n0) equals the force the
foot applies to the chain at the ankle, which the inverse translational dynamics of the chain gives:

    sum_l m_l a_COM_l = f_c0 + sum_{i in F} f_ci + M g_vec,   g_vec = (0, -g)
    =>  f_c0 = sum_l m_l a_COM_l + (0, M g) - sum_i f_ci.

With the COM levers, sum_l m_l a_COM_l = sum_i w_i (thetadd_i e_i^perp - thetad_i^2 e_i), w = lever_mass.
Moment balance of the foot about the ankle (tangential moment arm neglected, as in the paper)
puts the centre of pressure at x_p = u_1 / f_n0, which must lie under the sole [-a0f, a0b]
(toes at -x). The constraints in product form, all >= 0:

    f_n0                    (5a)
    mu f_n0 - f_t0,  mu f_n0 + f_t0          (5b)
    a0f f_n0 + u_1,  a0b f_n0 - u_1          (5c)
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.dynamics import lever_mass
from jaxhumanoid.model.params import FootParams, PlanarChain

FOOT_CONSTRAINT_NAMES = ("f_n0", "mu f_n0 - f_t0", "mu f_n0 + f_t0", "a0f f_n0 + u_1", "a0b f_n0 - u_1")


def momentum_rate(model: PlanarChain, q, qd, qdd):
    """sum_l m_l a_COM_l, shape (2,)."""
    theta = kin.absolute_angles(q)
    thetad = kin.absolute_angles(qd)
    thetadd = kin.absolute_angles(qdd)
    w = lever_mass(model)
    e = jnp.stack([jnp.cos(theta), jnp.sin(theta)], axis=-1)
    e_perp = jnp.stack([-jnp.sin(theta), jnp.cos(theta)], axis=-1)
    return (w * thetadd) @ e_perp - (w * thetad**2) @ e


def foot_reaction(model: PlanarChain, q, qd, qdd, f_contact):
    """Ground reaction on the foot (f_t0, f_n0), shape (2,).

    f_contact: (k, 2) contact forces (f_t, f_n) on the chain (k may be 0).
    """
    weight = jnp.stack([jnp.zeros_like(model.g), model.total_mass * model.g])
    return momentum_rate(model, q, qd, qdd) + weight - jnp.sum(f_contact, axis=0)


def foot_constraints(foot: FootParams, mu, f_c0, u1):
    """The five products of (5), each >= 0 when the foot stays steady. Shape (5,)."""
    f_t0, f_n0 = f_c0[0], f_c0[1]
    return jnp.stack([f_n0, mu * f_n0 - f_t0, mu * f_n0 + f_t0, foot.a0f * f_n0 + u1, foot.a0b * f_n0 - u1])
