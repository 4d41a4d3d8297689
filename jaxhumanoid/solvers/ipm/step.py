"""The primal-dual Newton step of the interior-point method (IPOPT paper, Sec. 2.1 and 3).

The step solves (13), the augmented system with Sigma_x = Z_l (X - X_l)^-1 + Z_u (X_u - X)^-1
(and Sigma_s alike) and the regularisation (delta_w, delta_c) of Algorithm IC (``inertia``):

    [ W + Sigma_x + delta_w I      J^T     ] [dx]     [ grad_x phi_mu + J^T y ]
    [        J            -D_c - delta_c I ] [dy] = - [        c(x, s)        ]

in which the slack step (and, in the restoration phase, the p and n steps) are eliminated into
the constraint diagonal D_c. The bound-multiplier steps follow from the linearised
complementarity (11); the step length from the fraction to the boundary (15); the multipliers
are kept within the safeguard (16). Also here: the least-squares multiplier estimate of the
starting point (Sec. 3.6).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.solvers.ipm.kkt import condensed
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import Context, masks, slacks
from jaxhumanoid.solvers.ipm.state import Evals, Iterate, Prob


def refinement(o: IPMOptions):
    """Iterative refinement settings of ``kkt.solve`` (keyword arguments)."""
    return dict(
        min_steps=o.min_refinement_steps, max_steps=o.max_refinement_steps, residual_ratio_max=o.residual_ratio_max
    )


def sigmas(P: Prob, it: Iterate):
    """Diagonals Sigma_x (n,) and Sigma_s (m,) of the primal-dual barrier Hessian."""
    dxl, dxu, dsl, dsu = slacks(P, it.x, it.s)
    sig_x = jnp.where(P.hxl, it.zl / dxl, 0.0) + jnp.where(P.hxu, it.zu / dxu, 0.0)
    sig_s = jnp.where(P.hsl, it.vl / dsl, 0.0) + jnp.where(P.hsu, it.vu / dsu, 0.0)
    return sig_x, sig_s


def kkt_parts(P: Prob, rr, sig_x, sig_s, sig_p, sig_n, dw, dc):
    """Diagonals of the reduced system for given regularisation. The slack step and, in the
    restoration phase (rows ``rr``), the p and n steps are eliminated: each adds
    1/(Sigma + delta_w) to minus the constraint diagonal of its row (a positive pivot, so the
    inertia is unchanged).

    Returns ((1/(Sigma_s + dw), 1/(Sigma_p + dw), 1/(Sigma_n + dw)) (m,) each, diag_x (n,),
    diag_c (m,))."""
    ineq_b = P.hsl | P.hsu
    inv_s = jnp.where(ineq_b, 1.0 / (sig_s + dw), 0.0)
    inv_p = jnp.where(rr, 1.0 / (sig_p + dw), 0.0)
    inv_n = jnp.where(rr, 1.0 / (sig_n + dw), 0.0)
    diag_x = jnp.where(P.fixed, 1.0, sig_x + dw)
    diag_c = jnp.where(P.free, -1.0, -(dc + inv_s + inv_p + inv_n))
    return (inv_s, inv_p, inv_n), diag_x, diag_c


def assemble_base(ctx: Context, P: Prob, Wvals, jac):
    """The KKT blocks with a zero diagonal (IC trials only change the diagonal)."""
    h_mask, jac_mask = masks(ctx, P)
    return kkt.assemble(ctx.st, Wvals * h_mask, jac * jac_mask, jnp.zeros(ctx.n), jnp.zeros(ctx.m))


def factorize(ctx: Context, P: Prob, rr, base, sigs, dw, dc):
    """Factor K = ``base`` plus the diagonal of the regularisation (dw, dc).

    Returns (A, B, factor, the eliminated rows' inverse pivots)."""
    sig_x, sig_s, sig_p, sig_n = sigs
    invs, diag_x, diag_c = kkt_parts(P, rr, sig_x, sig_s, sig_p, sig_n, dw, dc)
    A, B = kkt.add_diagonal(ctx.st, base[0], diag_x, diag_c), base[1]
    return A, B, factor_kkt(ctx, A, B), invs


def factor_kkt(ctx: Context, A, B):
    """The factorisation of K = (A, B) by the chosen method (``IPMOptions.kkt_method``): a
    ``kkt.Factor`` (block LDL^T, stopping early once the inertia is known to be wrong) or a
    ``kkt.CondensedFactor``; both carry the inertia (npos, nneg, nzero)."""
    if ctx.cst is not None:
        return condensed.factor(ctx.cst, A, B)
    return kkt.factor(ctx.st, A, B, early_exit=True)


def solve_kkt(ctx: Context, fac, A, B, bx, bc):
    """(dx, dy, residual) of K [dx; dy] = [bx; bc] with the factor of ``factor_kkt`` and the
    options' iterative refinement."""
    if ctx.cst is not None:
        return condensed.solve(ctx.cst, fac, A, B, bx, bc, **refinement(ctx.o), with_residual=True)
    return kkt.solve(ctx.st, fac, A, B, bx, bc, **refinement(ctx.o), with_residual=True)


def solve_reduced(ctx: Context, P: Prob, A, B, fac, invs, rx, rs, rp, rn, c):
    """Solve (13) given residuals r_x (grad_x phi + J^T y), r_s (grad_s phi - y), r_p, r_n
    (restoration only: grad phi -/+ y) and the constraint residual c; the eliminated steps
    are recovered from their rows: ds = (dy - r_s)/Sigma_s, dp = (dy - r_p)/Sigma_p,
    dn = -(dy + r_n)/Sigma_n (each Sigma including delta_w).

    Returns (dx (n,), ds, dy, dp, dn (m,), IPOPT's residual ratio of the solve)."""
    inv_s, inv_p, inv_n = invs
    bx = jnp.where(P.fixed, 0.0, -rx)
    bc = jnp.where(P.free, 0.0, -c - inv_s * rs - inv_p * rp + inv_n * rn)
    dx, dy, res = solve_kkt(ctx, fac, A, B, bx, bc)
    # the residual ratio of the reduced system, from the refinement's last residual
    nsol = max_abs(dx, dy)
    nrhs = max_abs(bx, bc)
    ratio = res / jnp.maximum(jnp.minimum(nsol, 1e6 * nrhs) + nrhs, 1e-300)
    ds = jnp.where(P.eq | P.free, 0.0, inv_s * (dy - rs))
    dy = jnp.where(P.free, 0.0, dy)
    return dx, ds, dy, inv_p * (dy - rp), -inv_n * (dy + rn), ratio


def dual_steps(P: Prob, it: Iterate, dx, ds, mu):
    """Bound-multiplier steps (dzl, dzu (n,), dvl, dvu (m,)) from the linearised
    complementarity (11)."""
    dxl, dxu, dsl, dsu = slacks(P, it.x, it.s)
    dzl = jnp.where(P.hxl, (mu - it.zl * dxl - it.zl * dx) / dxl, 0.0)
    dzu = jnp.where(P.hxu, (mu - it.zu * dxu + it.zu * dx) / dxu, 0.0)
    dvl = jnp.where(P.hsl, (mu - it.vl * dsl - it.vl * ds) / dsl, 0.0)
    dvu = jnp.where(P.hsu, (mu - it.vu * dsu + it.vu * ds) / dsu, 0.0)
    return dzl, dzu, dvl, dvu


def flat(vs):
    """The arrays ``vs`` raveled into one vector.

    A maximum, minimum or ``all`` of several vectors is taken as one reduction of their
    concatenation: each reduction of a long vector is two to three kernels of the compiled loop
    body (XLA's CPU compiler splits it into reduce-windows), and compiling kernels is most of the
    IPM's compile time; maxima and minima do not depend on the order, so the values are the same."""
    return jnp.concatenate([jnp.ravel(v) for v in vs])


def max_abs(*vs):
    """max |v_i| over all entries of the vectors ``vs`` (0 if they are empty), one reduction."""
    return jnp.max(jnp.abs(flat(vs)), initial=0.0)


def smallest(*ratios):
    """min(1, every entry of ``ratios``): the step of (15) from the candidates of
    ``boundary_ratios`` and ``dual_ratios``, one reduction."""
    return jnp.min(flat(ratios), initial=1.0)


def boundary_ratios(P: Prob, x, s, dx, ds, tau):
    """The candidates (n,), (n,), (m,), (m,) of the fraction to the boundary (15) for x, s: the
    step to tau times the distance to each finite bound approached, 1 elsewhere."""
    dxl, dxu, dsl, dsu = slacks(P, x, s)
    return (
        jnp.where(P.hxl & (dx < 0), -tau * dxl / jnp.where(dx < 0, dx, -1.0), 1.0),
        jnp.where(P.hxu & (dx > 0), tau * dxu / jnp.where(dx > 0, dx, 1.0), 1.0),
        jnp.where(P.hsl & (ds < 0), -tau * dsl / jnp.where(ds < 0, ds, -1.0), 1.0),
        jnp.where(P.hsu & (ds > 0), tau * dsu / jnp.where(ds > 0, ds, 1.0), 1.0),
    )


def frac_to_boundary(P: Prob, x, s, dx, ds, tau):
    """Largest alpha in (0, 1] keeping x, s strictly inside their bounds, (15)."""
    return smallest(*boundary_ratios(P, x, s, dx, ds, tau))


def dual_ratios(z, dz, mask, tau):
    """The candidates of the fraction to the boundary (15) for a vector bounded below by 0."""
    return jnp.where(mask & (dz < 0), -tau * z / jnp.where(dz < 0, dz, -1.0), 1.0)


def clip_mult(o: IPMOptions, z, d, mask, mu):
    """Safeguard (16) of one multiplier vector: z within [mu/(kappa_sigma d), kappa_sigma mu/d]."""
    ks = o.kappa_sigma
    return jnp.where(mask, jnp.clip(z, mu / (ks * d), ks * mu / d), 0.0)


def kappa_sigma_reset(o: IPMOptions, P: Prob, x, s, zl, zu, vl, vu, mu):
    """Safeguard (16): keep z_i (x_i - xl_i) within [mu/kappa_sigma, kappa_sigma mu]."""
    dxl, dxu, dsl, dsu = slacks(P, x, s)
    return (
        clip_mult(o, zl, dxl, P.hxl, mu),
        clip_mult(o, zu, dxu, P.hxu, mu),
        clip_mult(o, vl, dsl, P.hsl, mu),
        clip_mult(o, vu, dsu, P.hsu, mu),
    )


def ls_multipliers(ctx: Context, P: Prob, it: Iterate, ev: Evals):
    """y (m,) minimising ||grad f + J^T y - z||^2 + ||-y - v||^2 (Sec. 3.6), or 0 if too large."""
    ineq_b = P.hsl | P.hsu
    jac_mask = masks(ctx, P)[1]
    diag_c = jnp.where(P.free, -1.0, jnp.where(ineq_b, -1.0, 0.0))
    A, B = kkt.assemble(ctx.st, jnp.zeros(ctx.hr.size), ev.jac * jac_mask, jnp.ones(ctx.n), diag_c)
    fac = kkt.factor(ctx.st, A, B, fast=False)
    a = jnp.where(P.fixed, 0.0, ev.grad - it.zl + it.zu)
    b = jnp.where(ineq_b, -it.vl + it.vu, 0.0)
    _, y = kkt.solve(ctx.st, fac, A, B, -a, -b, **refinement(ctx.o))
    good = (
        kkt.inertia_ok(ctx.st, fac)
        & jnp.all(jnp.isfinite(y))
        & (jnp.max(jnp.abs(y), initial=0.0) <= ctx.o.constr_mult_init_max)
    )
    return jnp.where(good & ~P.free, y, 0.0)
