"""Factorisation of one symmetric pivot block D_k (nb x nb) with its exact inertia.

Every path returns ``(N, sgn, info)``: D_k^{-1} = N diag(sgn) N^T with N (nb, nb), sgn (nb,) in
{+1, -1}, and info = [nneg, nzero, path] (int64), path 0 for the quasi-definite fast path and 2 for
the eigendecomposition (3, a block left unfactored, is ``elimination``'s). D_k^{-1} is never
formed: the elimination and the solves only need products with N and N^T.

A block is laid out as [[P, Q^T], [Q, R]], P (nbx, nbx) on the variables, R (nc, nc) on the
constraints, nc = nb - nbx. The fast path (``quasidefinite_block``) applies the congruence

    T = [[I, 0], [G Q, I]],   G = gamma (I - gamma R)^{-1},

and certifies inertia (nbx, nc, 0) by three Cholesky factorisations (of I - gamma R, of the
transformed primal block P~ and of minus its Schur complement). T is unit triangular, so
inertia(T^T D_k T) = inertia(D_k) (Sylvester) and the certificate is exact. It is valid wherever
those factorisations exist, and they do where P is indefinite only along directions the
constraints pin down: P~ = P + gamma Q^T Q + ... carries an augmented-Lagrangian term. The
humanoid's joint-angle Hessian (constraint curvature) is of that kind. Where a Cholesky
factorisation fails (NaN), the block is eigen-decomposed (``eigen_pivot``), whose signs give the
inertia of any block.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.linalg import solve_triangular

# gamma of the congruence of the quasi-definite pivot path, for equilibrated blocks (entries
# <= 1): large enough to make P~ definite on the humanoid's blocks, and not larger, since
# D^{-1} is formed from terms of size gamma^2 and a larger gamma only costs digits.
QD_GAMMA = 30.0


def eigen_pivot(Dk, rel_zero_tol):
    """Inverse and inertia of one symmetric pivot block by eigendecomposition (path 2).

    Symmetric equilibration R D_k R (R = diag(1/sqrt(max_j |D_ij|)), a congruence, so the inertia
    is unchanged, Sylvester) brings graded IPM blocks to unit scale; then R D_k R = Q diag(w) Q^T
    (LAPACK syevd) gives the inertia as the signs of w, with |w| <= rel_zero_tol * max|w| counted
    as zero, and D_k^{-1} = N diag(sign w) N^T, N = R Q |w|^{-1/2} (zero eigenvalues replaced by
    +-tol). A block with a non-finite entry reports nb zero eigenvalues.
    Returns (N (nb, nb), sign w (nb,), [nneg, nzero, 2]).
    """
    ok = jnp.all(jnp.isfinite(Dk))
    Dk = jnp.where(ok, Dk, 0.0)
    r = jnp.sqrt(jnp.max(jnp.abs(Dk), axis=1))
    r = jnp.where(r > 0, 1.0 / r, 1.0)
    w, Q = jnp.linalg.eigh(Dk * r[:, None] * r[None, :])
    tol = rel_zero_tol * jnp.maximum(jnp.max(jnp.abs(w)), jnp.finfo(float).tiny)
    zero = jnp.abs(w) <= tol
    nneg = jnp.where(ok, jnp.sum((w < 0) & ~zero), 0)
    nzero = jnp.where(ok, jnp.sum(zero), w.shape[0])
    w_safe = jnp.where(zero, jnp.where(w < 0, -tol, tol), w)
    N = Q * r[:, None] / jnp.sqrt(jnp.abs(w_safe))
    return N, jnp.sign(w_safe), jnp.stack([nneg, nzero, jnp.full((), 2)]).astype(jnp.int64)


def apply_inv(N, sgn, v):
    """D^{-1} v = N (sgn * N^T v) for factored pivot inverses: one block (N (nb, nb), sgn and v
    (nb,)) or all blocks at once (leading axis S)."""
    return jnp.einsum("...ij,...j->...i", N, sgn * jnp.einsum("...ji,...j->...i", N, v))


def _tri_inv(L):
    """Inverse of a lower-triangular matrix (LAPACK trsm against the identity)."""
    return solve_triangular(L, jnp.eye(L.shape[-1], dtype=L.dtype), lower=True)


def _chol(M):
    """Cholesky factor from the lower triangle (no symmetrisation pass; NaN if not positive
    definite, which the callers test)."""
    return lax.linalg.cholesky(M, symmetrize_input=False)


def quasidefinite_block(Dk, nbx, gamma=QD_GAMMA):
    """Fast path with exact inertia: D_k = [[P, Q^T], [Q, R]] (nb x nb, primal part first, P nbx x nbx).

    The congruence T = [[I, 0], [G Q, I]] with G = gamma (I - gamma R)^{-1} gives

        T^T D_k T = [[P~, Q~^T], [Q~, R]],   P~ = P + Q^T (2G + G R G) Q,   Q~ = (I + R G) Q.

    With M = I - gamma R: Q~ = M^{-1} Q and P~ = P + gamma (Q^T M^{-1} Q + Q~^T Q~). Three Cholesky
    factorisations, of M, of P~ and of -(R - Q~ P~^{-1} Q~^T), all succeeding certify inertia(D_k) =
    (nbx, nb - nbx, 0) exactly (for G = 0 this is the plain quasi-definite test). On the dual rows
    of inequalities (R << 0) G tends to -R^{-1} and the transformation is the Schur complement of
    R. Then

        D_k^{-1} = T (T^T D_k T)^{-1} T^T = N1 N1^T - N2 N2^T,
        N1 = [I; E] Lp^{-T},   N2 = ([0; I] - [I; E] P~^{-1} Q~^T) Ls^{-T},   E = G Q = gamma Q~,

    (Lp, Ls the Cholesky factors of P~ and of minus the Schur complement). Returns
    (N = [N1, N2] (nb, nb), ok): D_k^{-1} = N diag(I, -I) N^T where ok (all of N finite).
    """
    nb = Dk.shape[0]
    P = Dk[:nbx, :nbx]
    if nbx == nb:
        N = _tri_inv(jnp.linalg.cholesky(P)).T
        return N, jnp.all(jnp.isfinite(N))
    Q = Dk[nbx:, :nbx]
    R = Dk[nbx:, nbx:]
    nc = nb - nbx
    eye_c = jnp.eye(nc, dtype=Dk.dtype)
    Lmi = _tri_inv(jnp.linalg.cholesky(eye_c - gamma * R))
    V = Lmi @ Q  # Q^T M^{-1} Q = V^T V
    Qt = Lmi.T @ V  # Q~ = M^{-1} Q
    Pt = P + gamma * (V.T @ V + Qt.T @ Qt)
    Lpi = _tri_inv(jnp.linalg.cholesky(0.5 * (Pt + Pt.T)))
    W = Qt @ Lpi.T
    Sc = W @ W.T - R  # minus the Schur complement
    Lsi = _tri_inv(jnp.linalg.cholesky(0.5 * (Sc + Sc.T)))
    Gp = Lpi.T @ W.T  # P~^{-1} Q~^T  (nbx x nc)
    IE = jnp.concatenate([jnp.eye(nbx, dtype=Dk.dtype), gamma * Qt], axis=0)  # [I; E]
    N1 = IE @ Lpi.T
    N2 = (jnp.concatenate([jnp.zeros((nbx, nc), Dk.dtype), eye_c], axis=0) - IE @ Gp) @ Lsi.T
    N = jnp.concatenate([N1, N2], axis=1)
    return N, jnp.all(jnp.isfinite(N))


def qd_diag_pre(A, nbx, gamma=QD_GAMMA):
    """Fill-independent part of ``qd_diag_core`` for all blocks A (S, nb, nb) at once (batched,
    outside the block loop).

    With R = diag(r) the dual part of a pivot block, M = I - gamma R is diagonal (m >= 1 for an
    IPM, R <= 0; m > 0 is its Cholesky test), Q^T (2G + G R G) Q = Q^T diag(h) Q and Q~ = M^{-1} Q.
    Returns (P + Q^T diag(h) Q (S, nbx, nbx), NaN where not m > 0; Q~ (S, nc, nbx); R (S, nc, nc)).
    """
    P = A[:, :nbx, :nbx]
    Q = A[:, nbx:, :nbx]
    r = jnp.diagonal(A, axis1=1, axis2=2)[:, nbx:]
    m = 1.0 - gamma * r
    h = gamma * (1.0 / m + 1.0 / (m * m))
    Pb = P + jnp.einsum("kci,kc,kcj->kij", Q, h, Q)
    Pb = jnp.where(jnp.all(m > 0, axis=1)[:, None, None], Pb, jnp.nan)  # M not positive definite
    Rd = r[:, :, None] * jnp.eye(r.shape[1], dtype=A.dtype)
    return Pb, Q / m[:, :, None], Rd


def qd_diag_core(Pt, Qt, Rd, gamma=QD_GAMMA):
    """``quasidefinite_block`` for a pivot block whose dual part R (``Rd``, diagonal) has no fill
    (``KKTStructure.b_rows`` all primal), given P~ = ``Pt`` (nbx, nbx) and Q~ = ``Qt`` (nc, nbx)
    (``qd_diag_pre``, with the fill subtracted from P~). With Lp Lp^T = P~, W = Q~ Lp^{-T} and
    Ls Ls^T = W W^T - R (minus the Schur complement),

        T^T D_k T = F J F^T,   F = [[Lp, 0], [W, Ls]],   J = diag(I, -I),
        D_k^{-1} = M^T J M,    M = F^{-1} T^T = [[Lp^{-1}], [K21]] [I, E^T] + [[0, 0], [0, Ls^{-1}]],

    with F^{-1} = [[Lp^{-1}, 0], [K21, Ls^{-1}]], K21 = -Ls^{-1} W Lp^{-1}, and T = [[I, 0], [E, I]],
    E = gamma Q~. Written for few XLA operations, as it runs inside the block loop; D_k^{-1}
    itself is not formed (an nb^3 product). Returns (N = M^T (nb, nb), ok): ok iff both Cholesky
    factorisations succeeded (inertia (nbx, nc, 0)); a failed one is NaN throughout, and so is
    then N."""
    nbx = Pt.shape[0]
    Lpi = _tri_inv(_chol(Pt))
    W = jnp.einsum("ij,kj->ik", Qt, Lpi)  # Q~ Lp^{-T}
    Lsi = _tri_inv(_chol(jnp.einsum("ij,kj->ik", W, W) - Rd))
    G1t = jnp.concatenate([Lpi, -((Lsi @ W) @ Lpi)], axis=0).T  # first block column of F^{-1}, transposed
    N = jnp.concatenate([G1t, gamma * (Qt @ G1t)], axis=0)  # N = M^T
    N = N.at[nbx:, nbx:].add(Lsi.T)
    return N, jnp.isfinite(N[0, 0]) & jnp.isfinite(N[-1, -1])


def choose_pivot(ok, Nq, build, parts, rel_zero_tol, nneg_fast):
    """(N, sgn, [nneg, nzero, path]): the fast path's factor ``Nq`` where it certified the inertia
    (``ok``; path 0, inertia (nb - nneg_fast, nneg_fast, 0), sgn = [+1.., -1..]), else the
    eigendecomposition of the block ``build(*parts)`` (built only there).

    Under ``vmap`` a ``lax.cond`` with a batched predicate becomes a select that evaluates both
    branches for every member, so every pivot block of every member would be eigen-decomposed.
    The batching rule keeps the batched fast path when every member's block took it, and
    otherwise goes member by member (``lax.map``), so that only the members that need it are
    decomposed."""
    nb = Nq.shape[-1]
    info_fast = np.array([nneg_fast, 0, 0], np.int64)  # constants: custom_vmap closes over no tracer
    sgn_fast = np.concatenate([np.ones(nb - nneg_fast), -np.ones(nneg_fast)])

    def slow(parts_):
        return eigen_pivot(build(*parts_), rel_zero_tol)

    @jax.custom_batching.custom_vmap
    def choose(ok, Nq, parts_):
        return lax.cond(ok, lambda: (Nq, jnp.asarray(sgn_fast), jnp.asarray(info_fast)), lambda: slow(parts_))

    @choose.def_vmap
    def _batched(axis_size, in_batched, ok, Nq, parts_):
        ok, Nq, parts_ = jax.tree.map(
            lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + a.shape), (ok, Nq, parts_), tuple(in_batched)
        )
        fast_b = (Nq, jnp.broadcast_to(sgn_fast, (axis_size, nb)), jnp.broadcast_to(info_fast, (axis_size, 3)))

        def mixed():  # member by member: only those that need it are decomposed
            return lax.map(lambda a: choose(*a), (ok, Nq, parts_))

        return lax.cond(jnp.all(ok), lambda: fast_b, mixed), (True, True, True)

    return choose(ok, Nq, parts)


def pivot(Dk, nbx, fast, rel_zero_tol):
    """(N, sgn, [nneg, nzero, path]) of one pivot block Dk (nb, nb): the quasi-definite fast path
    (path 0) where it applies and ``fast``, else the eigendecomposition (path 2)."""
    if fast and nbx > 0:
        Nq, ok = quasidefinite_block(Dk, nbx)
        return choose_pivot(ok, Nq, lambda D_: D_, (Dk,), rel_zero_tol, Dk.shape[0] - nbx)
    return eigen_pivot(Dk, rel_zero_tol)
