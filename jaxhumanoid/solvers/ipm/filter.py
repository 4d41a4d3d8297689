"""The filter of the line search (IPOPT paper, Sec. 2.3): a set of (theta, phi) pairs that a trial
point must not be dominated by, stored in a ring buffer of ``filter_size`` entries.

A trial (theta, phi) is acceptable to the filter when theta <= theta_max (the initial filter
(21)) and no entry has theta_i <= theta and phi_i <= phi. Augmenting with the current iterate's
(theta_k, phi_k) adds ((1 - gamma_theta) theta_k, phi_k - gamma_phi theta_k), the margins of
(18), as in (22).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.state import Globalization


def filter_ok(G: Globalization, theta, phi):
    """The trial (theta, phi) is below theta_max and not dominated by an entry of G's filter."""
    blocked = (theta >= G.filt_theta) & (phi >= G.filt_phi)
    return (theta <= G.theta_max) & ~jnp.any(blocked)


def filter_add(o: IPMOptions, G: Globalization, theta, phi) -> Globalization:
    """Augment the filter with (theta, phi) and its margins (22); the oldest entry makes room
    when all ``filter_size`` are taken."""
    i = G.filt_n % o.filter_size
    return G._replace(
        filt_theta=G.filt_theta.at[i].set((1 - o.gamma_theta) * theta),
        filt_phi=G.filt_phi.at[i].set(phi - o.gamma_phi * theta),
        filt_n=G.filt_n + 1,
    )


def filter_reset(o: IPMOptions, G: Globalization) -> Globalization:
    """The empty filter (after a barrier update, as IPOPT), theta_min/theta_max kept."""
    return G._replace(
        filt_theta=jnp.full(o.filter_size, jnp.inf),
        filt_phi=jnp.full(o.filter_size, jnp.inf),
        filt_n=jnp.zeros((), jnp.int32),
    )
