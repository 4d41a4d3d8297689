"""Step A-4 of the IPOPT paper's algorithm: the search direction of the problem being solved.

The residuals of (13) are formed from the barrier gradient of the original problem or, in the
restoration phase, of the restoration problem (objective gradient eta D_R^2 (x - x_R), the p and
n terms, constraint residual c(x, s) - p + n), the matrix is factored with inertia correction
(``inertia``) and the reduced system solved (``step.solve_reduced``). The factorisation is kept
for the second-order corrections, which solve with the same matrix and a new c.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxhumanoid.solvers.ipm.barrier import barrier_grad
from jaxhumanoid.solvers.ipm.inertia import Inertia, inertia_corrected_factor
from jaxhumanoid.solvers.ipm.problem import Context, hessian, jt_mult
from jaxhumanoid.solvers.ipm.restoration import objective_grad, pn_barrier_grad, prox_weight, resto_resid
from jaxhumanoid.solvers.ipm.state import Direction, Prob, State
from jaxhumanoid.solvers.ipm.step import flat, sigmas, solve_reduced


class Newton(NamedTuple):
    """The Newton step (13) of one iteration with what the line search reuses."""

    ic: Inertia
    ok: jax.Array  # inertia corrected and the step finite
    d: Direction
    res_ratio: jax.Array  # residual ratio of the solve
    gx: jax.Array  # barrier gradients in x (n,), s, p, n (m,)
    gs: jax.Array
    gp: jax.Array
    gn: jax.Array
    rx: jax.Array  # right-hand sides of (13) besides the constraint residual c
    rs: jax.Array
    rp: jax.Array
    rn: jax.Array
    c: jax.Array  # (m,) constraint residual of the problem being solved


def kkt_factor(ctx: Context, P: Prob, S: State, mu) -> Inertia:
    """The matrix of (13) at S's iterate, factored with inertia correction; ``mu`` enters the
    regularisation delta_c. In the restoration phase the Hessian holds the proximity term
    eta * diag(dr) for S.mu, the barrier parameter before this iteration's update: IPOPT
    evaluates the Hessian before it updates mu (its gradient and merit take the new mu)."""
    it, R = S.it, S.rs
    rr = R.on & ~P.free
    Wvals = hessian(ctx, P, it.x, it.y, R.on)
    sig_x, sig_s = sigmas(P, it)
    prox = prox_weight(ctx.o, R, S.mu)
    sig_p = jnp.where(rr, R.zp / R.p, 0.0)
    sig_n = jnp.where(rr, R.zn / R.n, 0.0)
    return inertia_corrected_factor(
        ctx, P, rr, Wvals, S.ev.jac, sig_x + prox, sig_s, sig_p, sig_n, S.gl.dw_last, mu, S.gl.pert
    )


def residuals(ctx: Context, P: Prob, S: State, mu):
    """The right-hand side of (13) for barrier parameter ``mu``: the barrier gradients
    (gx (n,), gs, gp, gn (m,)), r_x = gx + J^T y, r_s, r_p, r_n and the constraint residual c."""
    it, ev, R = S.it, S.ev, S.rs
    rr = R.on & ~P.free
    gx, gs = barrier_grad(P, objective_grad(ctx.o, R, ev.grad, it.x, mu), it.x, it.s, mu, ctx.o.kappa_d)
    gp, gn = pn_barrier_grad(ctx.o, R, rr, mu)
    rx = gx + jt_mult(ctx, ev.jac, it.y)
    rs = jnp.where(P.hsl | P.hsu, gs - it.y, 0.0)
    rp = jnp.where(rr, gp - it.y, 0.0)
    rn = jnp.where(rr, gn + it.y, 0.0)
    c = resto_resid(P, R, ev.g, it.s, R.p, R.n)
    return gx, gs, gp, gn, rx, rs, rp, rn, c


def newton(ic: Inertia, d: Direction, res_ratio, res) -> Newton:
    """The Newton tuple of direction ``d`` solved with ``ic`` for the residuals ``res``."""
    finite_step = jnp.all(jnp.isfinite(flat([d.dx, d.dy])))
    gx, gs, gp, gn, rx, rs, rp, rn, c = res
    return Newton(
        ic=ic,
        ok=ic.ok & finite_step,
        d=d,
        res_ratio=res_ratio,
        gx=gx,
        gs=gs,
        gp=gp,
        gn=gn,
        rx=rx,
        rs=rs,
        rp=rp,
        rn=rn,
        c=c,
    )


def newton_step(ctx: Context, P: Prob, S: State, ic: Inertia, mu) -> Newton:
    """The Newton direction (13) for barrier parameter ``mu`` with the factored matrix ``ic``."""
    res = residuals(ctx, P, S, mu)
    _, _, _, _, rx, rs, rp, rn, c = res
    dx, ds, dy, dp, dn, res_ratio = solve_reduced(ctx, P, ic.A, ic.B, ic.fac, ic.invs, rx, rs, rp, rn, c)
    return newton(ic, Direction(dx=dx, ds=ds, dy=dy, dp=dp, dn=dn), res_ratio, res)


def search_direction(ctx: Context, P: Prob, S: State, mu) -> Newton:
    """The Newton direction at S's iterate for barrier parameter ``mu`` (factor, then solve)."""
    return newton_step(ctx, P, S, kkt_factor(ctx, P, S, mu), mu)


def corrected_direction(ctx: Context, P: Prob, nw: Newton, c_soc) -> Direction:
    """The second-order correction (Sec. 2.4): (13) with the same matrix and c replaced by c_soc."""
    ic = nw.ic
    dx, ds, dy, dp, dn, _ = solve_reduced(ctx, P, ic.A, ic.B, ic.fac, ic.invs, nw.rx, nw.rs, nw.rp, nw.rn, c_soc)
    return Direction(dx=dx, ds=ds, dy=dy, dp=dp, dn=dn)


def directional_derivative(nw: Newton):
    """grad phi_mu^T d of the barrier function along the direction."""
    d = nw.d
    return jnp.dot(nw.gx, d.dx) + jnp.dot(nw.gs, d.ds) + jnp.dot(nw.gp, d.dp) + jnp.dot(nw.gn, d.dn)
