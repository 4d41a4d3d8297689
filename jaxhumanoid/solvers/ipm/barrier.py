"""The barrier problem (3) and the monotone barrier-parameter update (7) (IPOPT paper, Sec. 2.1).

    phi_mu(x, s) = f(x) - mu sum ln(x - xl) - mu sum ln(xu - x) - mu sum ln(s - gl) - mu sum ln(gu - s)
                   + kappa_d mu (distance to the bound of one-sided variables and slacks, Sec. 3.7)

with IPOPT 3.14's kappa_d (option ``kappa_d``, 1e-5; the paper's is 1e-4).

mu decreases by mu+ = max(mu_min, min(kappa_mu mu, mu^theta_mu)) whenever the barrier problem's
optimality error E_mu (5) is below kappa_eps mu, down to IPOPT's floor
mu_min = min(tol, compl_inf_tol) / (kappa_eps + 1).
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
from jax import lax

from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import slacks
from jaxhumanoid.solvers.ipm.state import Prob

MAX_MU_UPDATES = 20  # barrier updates in one iteration at most


def barrier_phi(P: Prob, f, x, s, mu, kappa_d):
    """phi_mu of (3) plus the one-sided linear damping (Sec. 3.7), a scalar."""
    dxl, dxu, dsl, dsu = slacks(P, x, s)
    logs = (
        jnp.sum(jnp.where(P.hxl, jnp.log(dxl), 0.0))
        + jnp.sum(jnp.where(P.hxu, jnp.log(dxu), 0.0))
        + jnp.sum(jnp.where(P.hsl, jnp.log(dsl), 0.0))
        + jnp.sum(jnp.where(P.hsu, jnp.log(dsu), 0.0))
    )
    damp = (
        jnp.sum(jnp.where(P.hxl & ~P.hxu, dxl, 0.0))
        + jnp.sum(jnp.where(P.hxu & ~P.hxl, dxu, 0.0))
        + jnp.sum(jnp.where(P.hsl & ~P.hsu, dsl, 0.0))
        + jnp.sum(jnp.where(P.hsu & ~P.hsl, dsu, 0.0))
    )
    return f - mu * logs + kappa_d * mu * damp


def barrier_grad(P: Prob, grad, x, s, mu, kappa_d):
    """(grad_x phi_mu (n,), grad_s phi_mu (m,)) given grad f."""
    dxl, dxu, dsl, dsu = slacks(P, x, s)
    kd = kappa_d * mu
    gx = (
        grad
        - jnp.where(P.hxl, mu / dxl, 0.0)
        + jnp.where(P.hxu, mu / dxu, 0.0)
        + jnp.where(P.hxl & ~P.hxu, kd, 0.0)
        - jnp.where(P.hxu & ~P.hxl, kd, 0.0)
    )
    gs = (
        -jnp.where(P.hsl, mu / dsl, 0.0)
        + jnp.where(P.hsu, mu / dsu, 0.0)
        + jnp.where(P.hsl & ~P.hsu, kd, 0.0)
        - jnp.where(P.hsu & ~P.hsl, kd, 0.0)
    )
    return jnp.where(P.fixed, 0.0, gx), jnp.where(P.hsl | P.hsu, gs, 0.0)


def mu_floor(o: IPMOptions, P: Prob):
    """IPOPT's smallest barrier parameter, min(tol, compl_inf_tol) / (kappa_eps + 1), with
    compl_inf_tol in the scaled problem's units."""
    return jnp.minimum(o.tol, o.compl_inf_tol * P.sf) / (o.kappa_eps + 1.0)


def next_mu(o: IPMOptions, mu, mu_min):
    """One monotone decrease (7): max(mu_min, min(kappa_mu mu, mu^theta_mu))."""
    return jnp.maximum(mu_min, jnp.minimum(o.kappa_mu * mu, mu**o.theta_mu))


def update_mu(o: IPMOptions, mu, mu_min, barrier_error: Callable, force, frozen):
    """Step A-3: decrease mu while E_mu(mu) = ``barrier_error(mu)`` <= kappa_eps mu (or once when
    ``force``), above the floor, at most MAX_MU_UPDATES times, never when ``frozen``.

    Returns (mu, number of decreases)."""

    def cond(c):
        mu_, cnt, force_ = c
        return (
            ((barrier_error(mu_) <= o.kappa_eps * mu_) | force_)
            & (mu_ > mu_min * (1 + 1e-12))
            & (cnt < MAX_MU_UPDATES)
            & ~frozen
        )

    def body(c):
        mu_, cnt, _ = c
        return next_mu(o, mu_, mu_min), cnt + 1, jnp.zeros((), bool)

    mu, nupd, _ = lax.while_loop(cond, body, (mu, jnp.zeros((), jnp.int32), force))
    return mu, nupd
