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

A plan that sits on these edges keeps its foot only when it is executed exactly: the optimum puts
the centre of pressure on the toe, the reaction on the friction cone and the load at zero wherever
that lowers the cost, and any deviation crosses an edge in about half the directions. A
``FootMargin`` tightens the rows by physical distances to the edge,

    f_n0 - load M g                                            (5a) a minimum foot load, in body weights
    (1 - friction) mu f_n0 -/+ f_t0                            (5b) a fraction of the friction cone kept unused
    (a0f - cop) f_n0 + u_1,  (a0b - cop) f_n0 - u_1            (5c) the centre of pressure cop metres inside the sole

the same margins ``strategy.posture.find_equilibrium`` demands of a start posture. All zero is (5).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.dynamics import lever_mass
from jaxhumanoid.model.params import FootParams, PlanarChain
from jaxhumanoid.pytree import pytree_dataclass

FOOT_CONSTRAINT_NAMES = ("f_n0", "mu f_n0 - f_t0", "mu f_n0 + f_t0", "a0f f_n0 + u_1", "a0b f_n0 - u_1")
MARGIN_FIELDS = {"load": "M g", "friction": "of mu", "cop": "m"}


@pytree_dataclass
class FootMargin:
    """How far inside the edges of (5) a plan keeps the foot (module docstring).

    load: minimum f_n0 in body weights M g, in [0, 1); friction: the fraction of the friction
    cone kept unused, in [0, 1); cop: distance (m) of the centre of pressure from toe and heel,
    in [0, (a0f + a0b) / 2) (``check_foot_margin`` checks it against a foot).
    """

    load: float = 0.0
    friction: float = 0.0
    cop: float = 0.0

    def __post_init__(self):
        for name in MARGIN_FIELDS:
            value = getattr(self, name)
            ok = not isinstance(value, bool) and isinstance(value, (int, float)) and 0 <= value < 1
            if not ok:
                raise ValueError(
                    f"FootMargin.{name}: expected a number in [0, 1) ({MARGIN_FIELDS[name]}), got {value!r}"
                )
            object.__setattr__(self, name, float(value))

    @property
    def is_zero(self) -> bool:
        return self.load == 0.0 and self.friction == 0.0 and self.cop == 0.0


def check_foot_margin(margin, foot: FootParams) -> FootMargin:
    """``margin`` (a FootMargin, or None for none) checked against the sole of ``foot``."""
    margin = FootMargin() if margin is None else margin
    if not isinstance(margin, FootMargin):
        raise ValueError(f"foot_margin: expected a FootMargin or None, got {type(margin).__name__}")
    half = 0.5 * (float(foot.a0f) + float(foot.a0b))
    if margin.cop >= half:
        raise ValueError(
            f"FootMargin.cop: expected a distance in [0, {half:.4g}) m (half the sole a0f + a0b), got {margin.cop!r}"
        )
    return margin


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


def foot_constraints(foot: FootParams, mu, f_c0, u1, margin: FootMargin | None = None, weight=0.0):
    """The five products of (5), each >= 0 when the foot stays steady, tightened by ``margin``
    (None: none) with ``weight`` = M g (N) the unit of its load. Shape (5,)."""
    f_t0, f_n0 = f_c0[0], f_c0[1]
    if margin is None:
        return jnp.stack([f_n0, mu * f_n0 - f_t0, mu * f_n0 + f_t0, foot.a0f * f_n0 + u1, foot.a0b * f_n0 - u1])
    mu_m, a0f, a0b = (1.0 - margin.friction) * mu, foot.a0f - margin.cop, foot.a0b - margin.cop
    return jnp.stack(
        [f_n0 - margin.load * weight, mu_m * f_n0 - f_t0, mu_m * f_n0 + f_t0, a0f * f_n0 + u1, a0b * f_n0 - u1]
    )
