"""IPOPT's feasibility-restoration phase (IPOPT paper, Sec. 3.3): the l1 restoration problem

    min  rho sum(p + n) + eta/2 ||D_R (x - x_R)||^2   s.t.  c(x, s) - p + n = 0,  p, n >= 0

(eta = resto_proximity_weight sqrt(mu), D_R = diag(1/max(1, |x_R|))), solved by the same
iteration: the functions here are the restoration problem seen through the original one (its
objective gradient, constraint residual, merit and the p, n multipliers), so the iteration
switches between both by ``Resto.on`` and one traced factorisation serves both. Also here: the
entry (p, n from (33)), the return test to the original problem and its multiplier reset.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.solvers.ipm.barrier import barrier_phi
from jaxhumanoid.solvers.ipm.filter import filter_ok
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import Context, constr_resid, slacks
from jaxhumanoid.solvers.ipm.state import Iterate, Prob, Resto, State, fresh_globalization, resto_off
from jaxhumanoid.solvers.ipm.step import clip_mult, dual_ratios, max_abs, smallest


def prox_weight(o: IPMOptions, R: Resto, mu):
    """eta D_R^2 (n,) of the restoration objective (0 outside the restoration phase: dr = 0)."""
    return o.resto_proximity_weight * jnp.sqrt(mu) * R.dr


def objective_grad(o: IPMOptions, R: Resto, grad, x, mu):
    """Gradient in x (n,) of the problem being solved: eta D_R^2 (x - x_R) in the restoration
    phase, else grad f."""
    return jnp.where(R.on, prox_weight(o, R, mu) * (x - R.xR), grad)


def resto_resid(P: Prob, R: Resto, g, s, pv, nv):
    """c(x, s) - p + n in the restoration phase (p, n on the non-free rows), else c(x, s)."""
    return constr_resid(P, g, s) + jnp.where(R.on & ~P.free, nv - pv, 0.0)


def pn_barrier_grad(o: IPMOptions, R: Resto, rr, mu):
    """Gradients (m,) of the restoration barrier function in p and n: rho - mu/p + kappa_d mu."""
    rho = o.resto_penalty_parameter
    gp = jnp.where(rr, rho - mu / R.p + o.kappa_d * mu, 0.0)
    gn = jnp.where(rr, rho - mu / R.n + o.kappa_d * mu, 0.0)
    return gp, gn


def merit(o: IPMOptions, P: Prob, R: Resto, f, g, x, s, pv, nv, mu):
    """(theta, phi) of the problem being solved: the barrier problem (3), or in the
    restoration phase theta = ||c(x, s) - p + n||_1 and phi = the barrier function of
    rho sum(p + n) + eta/2 ||D_R (x - x_R)||^2 (bounds of x, s, p, n)."""
    rr = R.on & ~P.free
    theta = jnp.sum(jnp.abs(resto_resid(P, R, g, s, pv, nv)))
    f_r = o.resto_penalty_parameter * jnp.sum(jnp.where(rr, pv + nv, 0.0)) + 0.5 * jnp.sum(
        prox_weight(o, R, mu) * (x - R.xR) ** 2
    )
    pn = jnp.where(rr, pv, 1.0), jnp.where(rr, nv, 1.0)
    bar_pn = jnp.sum(jnp.where(rr, -mu * (jnp.log(pn[0]) + jnp.log(pn[1])) + o.kappa_d * mu * (pn[0] + pn[1]), 0.0))
    phi = barrier_phi(P, jnp.where(R.on, f_r, f), x, s, mu, o.kappa_d) + bar_pn
    return theta, phi


def pn_dual_steps(R: Resto, rr, dp, dn, mu):
    """Steps (m,) of the multipliers of p >= 0, n >= 0 from the linearised complementarity (11)."""
    dzp = jnp.where(rr, (mu - R.zp * R.p - R.zp * dp) / R.p, 0.0)
    dzn = jnp.where(rr, (mu - R.zn * R.n - R.zn * dn) / R.n, 0.0)
    return dzp, dzn


def pn_take_step(o: IPMOptions, R: Resto, rr, a_pr, a_du, dp, dn, dzp, dzn, mu) -> Resto:
    """p, n and their multipliers after an accepted step (primal a_pr, dual a_du, safeguard (16))."""
    p_n = jnp.where(rr, R.p + a_pr * dp, R.p)
    n_n = jnp.where(rr, R.n + a_pr * dn, R.n)
    return R._replace(
        fresh=jnp.zeros((), bool),
        p=p_n,
        n=n_n,
        zp=clip_mult(o, R.zp + a_du * dzp, p_n, rr, mu),
        zn=clip_mult(o, R.zn + a_du * dzn, n_n, rr, mu),
    )


def enter_restoration(ctx: Context, P: Prob, S: State, mu, theta_k, phi_k) -> State:
    """Start the l1 restoration problem at the current x, s (IPOPT's initialisation: p, n
    from (33) so that c - p + n = 0, their multipliers mu_R/p, mu_R/n, y = 0, bound
    multipliers min(rho, z), mu_R = max(mu, ||c||_inf), a fresh filter). The outer filter
    (already holding the current iterate) and regularisation are stashed for the return."""
    o, it = ctx.o, S.it
    rows = ~P.free
    rho = o.resto_penalty_parameter
    c0 = jnp.where(rows, constr_resid(P, S.ev.g, it.s), 0.0)
    inf0 = jnp.max(jnp.abs(c0), initial=0.0)
    mu_r = jnp.maximum(mu, inf0)
    a = mu_r / (2.0 * rho) - 0.5 * c0
    nv = a + jnp.sqrt(a * a + c0 * mu_r / (2.0 * rho))
    pv = c0 + nv
    nv, pv = jnp.where(rows, nv, 1.0), jnp.where(rows, pv, 1.0)
    R = Resto(
        on=jnp.ones((), bool),
        fresh=jnp.ones((), bool),
        p=pv,
        n=nv,
        zp=jnp.where(rows, mu_r / pv, 0.0),
        zn=jnp.where(rows, mu_r / nv, 0.0),
        xR=it.x,
        dr=jnp.where(P.fixed, 0.0, 1.0 / jnp.maximum(1.0, jnp.abs(it.x)) ** 2),
        s0=it.s,
        z0=(it.zl, it.zu, it.vl, it.vu),
        mu_orig=mu,
        theta_ref=theta_k,
        phi_ref=phi_k,
        inf_ref=inf0,
        outer=S.gl,
    )
    it_r = Iterate(
        x=it.x,
        s=it.s,
        y=jnp.zeros(ctx.m),
        zl=jnp.minimum(rho, it.zl),
        zu=jnp.minimum(rho, it.zu),
        vl=jnp.minimum(rho, it.vl),
        vu=jnp.minimum(rho, it.vu),
    )
    return S._replace(
        it=it_r,
        rs=R,
        mu=mu_r,
        n_acceptable=jnp.zeros((), jnp.int32),
        gl=fresh_globalization(o.filter_size, o.theta_min_fact, o.resto_theta_max_fact),
    )


def restoration_done(o: IPMOptions, P: Prob, R: Resto, f, g, x, s):
    """IPOPT's return test: the original infeasibility reduced by kappa_resto and the point
    acceptable to the outer filter and to the iterate where the restoration started."""
    c = constr_resid(P, g, s)
    inf = jnp.max(jnp.abs(c), initial=0.0)
    theta = jnp.sum(jnp.abs(c))
    phi = barrier_phi(P, f, x, s, R.mu_orig, o.kappa_d)
    in_filter = filter_ok(R.outer, theta, phi) & jnp.isfinite(phi)
    progress = (theta <= (1 - o.gamma_theta) * R.theta_ref) | (phi <= R.phi_ref - o.gamma_phi * R.theta_ref)
    enough = inf <= jnp.maximum(o.kappa_resto * R.inf_ref, jnp.minimum(o.tol, o.constr_viol_tol))
    return enough & in_filter & progress


def leave_restoration(ctx: Context, P: Prob, S: State) -> State:
    """Back to the original problem at the restoration's x, s: the bound multipliers take one
    Newton step for complementarity, as if the whole restoration had been one primal step
    (reset to 1 if any exceeds bound_mult_reset_threshold), and y = 0 (IPOPT's defaults)."""
    o = ctx.o
    R, it = S.rs, S.it
    mu = R.mu_orig
    tau = jnp.maximum(o.tau_min, 1.0 - mu)
    old = slacks(P, R.xR, R.s0)
    new = slacks(P, it.x, it.s)
    bounded = (P.hxl, P.hxu, P.hsl, P.hsu)
    dz = [jnp.where(msk, ((a - b) * z + mu) / a - z, 0.0) for z, a, b, msk in zip(R.z0, old, new, bounded)]
    a_du = smallest(*(dual_ratios(z, d, msk, tau) for z, d, msk in zip(R.z0, dz, bounded)))
    z = [z0 + a_du * d for z0, d in zip(R.z0, dz)]
    too_big = max_abs(*z) > o.bound_mult_reset_threshold
    z = [jnp.where(too_big, jnp.where(msk, 1.0, 0.0), v) for v, msk in zip(z, bounded)]
    it_o = Iterate(x=it.x, s=it.s, y=jnp.zeros(ctx.m), zl=z[0], zu=z[1], vl=z[2], vu=z[3])
    return S._replace(it=it_o, rs=resto_off(R), mu=mu, gl=R.outer, n_acceptable=jnp.zeros((), jnp.int32))
