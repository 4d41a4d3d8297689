"""Solves with the block factorisation: forward/backward substitution and iterative refinement.

With the factors of K~ = diag(d) K diag(d) (``elimination.Factor``), K u = r is solved as
u = d * K~^{-1} (d * r). The block substitution follows the elimination order 1, ..., S-1, 0;
every product with D_k^{-1} is ``pivot.apply_inv``. Refinement repeats the solve on the
residual r - K u, evaluated with the structurally nonzero part of B only.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax import lax

from jaxhumanoid.solvers.ipm.kkt.assembly import from_blocks, matvec_compact, to_blocks
from jaxhumanoid.solvers.ipm.kkt.elimination import Factor
from jaxhumanoid.solvers.ipm.kkt.pivot import apply_inv
from jaxhumanoid.solvers.ipm.kkt.structure import KKTStructure, static_index


def border_coupling(st: KKTStructure, fac: Factor, B):
    """X_1^T = rows b_rows of the equilibrated B_0 (r, nb); zeros for a single block."""
    if st.S == 1:
        return jnp.zeros((st.b_rows.size, st.nb), B.dtype)
    rb = static_index(st.b_rows)
    return B[0][rb] * fac.d[1][rb][:, None] * fac.d[0][None, :]


def solve_vec(st: KKTStructure, fac: Factor, X1t, r):
    """Solve K u = r for a stage-blocked vector r (S, nb) with the factors of diag(d) K diag(d).

    Elimination order 1, ..., S-1, 0 (``elimination.factor``). With z the forward substitution
    (z_k = r_k - L_{k,k-1} z_{k-1}) and w_k = D_k^{-1} z_k,

        u_0 = D_0^{-1} (r_0 - sum_k X_k w_k[b_rows]),
        u_k = w_k - D_k^{-1} X_k^T u_0 - L_{k+1,k}^T u_{k+1}    (k = S-1, ..., 1).

    The border couplings X_k = X_1 (-T_1) ... (-T_{k-1}), T_k = (L_{k+1,k}[:, b_rows])^T (r x r),
    are not stored: the sums they enter are evaluated by Horner-type recursions on r-vectors.
    ``X1t`` (r, nb) = X_1^T = equilibrated B_0[b_rows] (``border_coupling``). The scans run over
    all S blocks (block 0's entries are dummies, L[0] = 0), so that no (S-1)-slices of the factor
    arrays are copied. Returns u (S, nb)."""
    rb = static_index(st.b_rows)
    nr = st.b_rows.size
    r = fac.d * r
    L = fac.L

    def dinv(v):  # D_k^{-1} v_k, all k at once
        return apply_inv(fac.N, fac.sgn, v)

    if st.S == 1:
        return fac.d * dinv(r)

    def fwd(q, inp):  # z_k = r_k - L_{k,k-1} z_{k-1}  (q = L_{k,k-1} z_{k-1})
        rk, Lk = inp
        zk = rk.at[rb].add(-q)
        return Lk @ zk, zk

    _, z = lax.scan(fwd, jnp.zeros((nr,), r.dtype), (r, L))
    w = dinv(z)
    T = L[:, :, rb]  # (S, r, r): T_k^T

    def horner(h, inp):  # h_k = w_k[rb] - T_k h_{k+1};  sum_k X_k w_k[rb] = X_1 h_1
        wk, Tkt = inp
        hk = wk[rb] - jnp.einsum("ji,j->i", Tkt, h)
        return hk, hk

    _, hs = lax.scan(horner, jnp.zeros((nr,), r.dtype), (w, T), reverse=True)
    v0 = r[0] - jnp.einsum("rn,r->n", X1t, hs[1])
    u0 = apply_inv(fac.N[0], fac.sgn[0], v0)

    def gfwd(g, Tkt):  # g_k = X_k^T u_0:  g_{k+1} = -T_k^T g_k
        return -(Tkt @ g), g

    _, g = lax.scan(gfwd, X1t @ u0, T[1:])
    gp = jnp.zeros_like(r).at[1:, rb].set(g)
    wc = w - dinv(gp)

    def bwd(unext, inp):  # u_k = w_k - D_k^{-1} X_k^T u_0 - L_{k+1,k}^T u_{k+1}
        wk, Lk = inp
        uk = wk - jnp.einsum("ri,r->i", Lk, unext[rb])
        return uk, uk

    _, u = lax.scan(bwd, jnp.zeros_like(r[0]), (wc, L), reverse=True)
    return fac.d * u.at[0].set(u0)


def refinement_ratio(fac: Factor, u, res, dr):
    """IPOPT's residual ratio in the equilibrated system, ||d res||_inf / (||u / d||_inf + dr),
    dr = ||d r||_inf; u, res (S, nb)."""
    return jnp.max(jnp.abs(fac.d * res)) / jnp.maximum(jnp.max(jnp.abs(u / fac.d)) + dr, 1e-300)


def solve(
    st: KKTStructure,
    fac: Factor,
    A,
    B,
    rx,
    rc,
    min_steps: int = 1,
    max_steps: int = 10,
    residual_ratio_max: float = 1e-10,
    with_residual: bool = False,
):
    """(dx (n,), dy (m,)) solving K [dx; dy] = [rx; rc] with adaptive iterative refinement (as
    IPOPT's min/max_refinement_steps, residual_ratio_max): u_{i+1} = u_i + K^{-1}(r - K u_i) until
    ``refinement_ratio`` is at most ``residual_ratio_max`` (after at least ``min_steps`` and at
    most ``max_steps`` refinements). ``with_residual``: also return ||r - K u||_inf of the
    returned solution (the refinement's last residual, so no extra product)."""
    dx, dy, res = _solve(st, fac, A, B, rx, rc, min_steps, max_steps, residual_ratio_max)
    return (dx, dy, res) if with_residual else (dx, dy)


@functools.partial(jax.jit, static_argnames=("st",))
def _solve(st, fac, A, B, rx, rc, min_steps, max_steps, residual_ratio_max):
    r = to_blocks(st, rx, rc)
    dr = jnp.max(jnp.abs(fac.d * r))
    X1t = border_coupling(st, fac, B)
    u, res = refine(
        lambda res: solve_vec(st, fac, X1t, res),
        lambda u: r - matvec_compact(st, A, B, u),
        lambda u, res: refinement_ratio(fac, u, res, dr),
        r,
        min_steps,
        max_steps,
        residual_ratio_max,
    )
    return (*from_blocks(st, u), jnp.max(jnp.abs(res)))


def refine(correct, residual, ratio, r, min_steps, max_steps, residual_ratio_max):
    """IPOPT's adaptive iterative refinement: u_{i+1} = u_i + ``correct``(r - K u_i), the residual
    from ``residual``(u), until ``ratio``(u, residual) <= ``residual_ratio_max`` after at least
    ``min_steps`` and at most ``max_steps`` refinements. One traced solve: the first pass is the
    plain solve (from u = 0), the others refine. Returns (u, its residual)."""

    def cond(c):
        u, res, t = c
        return (t <= max_steps) & ((t <= min_steps) | (ratio(u, res) > residual_ratio_max))

    def body(c):
        u, res, t = c
        u = u + correct(res)
        return u, residual(u), t + 1

    u, res, _ = lax.while_loop(cond, body, (jnp.zeros_like(r), r, jnp.zeros((), jnp.int32)))
    return u, res
