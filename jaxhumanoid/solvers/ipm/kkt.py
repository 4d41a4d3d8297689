"""Structure-exploiting solution of the IPM's augmented (KKT) system with exact inertia.

The reduced primal-dual system solved at every iteration (IPOPT paper, eq. (13) after the slack
step has been eliminated, see ``algorithm.py``) is

    [ W + Sigma_x + delta_w I     J^T  ] [dx]   [r_x]
    [ J                          -D_c  ] [dy] = [r_c] ,       D_c = diag(d_c) >= 0,

with W (n x n) the Hessian of the Lagrangian, J (m x n) the constraint Jacobian. The unknowns are
ordered stage by stage, ``[x_0, y_0, x_1, y_1, ...]`` with ``x_k`` the variables and ``y_k`` the
multipliers of the constraints of stage k (``NLP.var_stage`` / ``NLP.con_stage``). Each stage is
padded to a common block size ``nb`` with decoupled identity rows, so K is block-tridiagonal with
S diagonal blocks A_k and sub-diagonal blocks B_k = K[stage k+1, stage k]:

    K = L diag(D_0, ..., D_{S-1}) L^T,   D_0 = A_0,   D_{k+1} = A_{k+1} - B_k D_k^{-1} B_k^T,
    L_{k+1,k} = B_k D_k^{-1}                                          (block LDL^T, lax.scan)

By Sylvester's law of inertia, inertia(K) = sum_k inertia(D_k); the padding contributes exactly
one eigenvalue of known sign per padded row, which is subtracted. Three measures keep the block
elimination (which cannot pivot across stages) accurate on IPM matrices:

- K is first symmetrically equilibrated (Ruiz, a diagonal congruence: inertia unchanged). Near
  the end of a solve Sigma spans 1e-17 .. 1e18, and without it the solves lose every digit.
- The stage order is reversed when the first pivot block would be structurally singular: with a
  fixed initial state, interval 0 has more equality rows than stage-0 variables, and D_0 = A_0
  is singular although K is not. Eliminating from the last stage (the Riccati direction) gives
  that block the Schur complement of its neighbour first.
- Solves use adaptive iterative refinement on the equilibrated residual (IPOPT's rule).

Each block is laid out as [variables | constraints] (split at a static size), so that the pivot
blocks D_k are first tried as quasi-definite matrices (Cholesky of the primal part and of minus
the Schur complement; then the inertia is known exactly and D_k^{-1} follows from triangular
inverses and products). Blocks where that fails are equilibrated and eigen-decomposed: the signs
of the eigenvalues give the exact inertia and the decomposition gives D_k^{-1}, so the solves
are matrix-vector products. B_k is nonzero only in a few local rows/columns (the variables
shared by neighbouring stages), and the Schur update uses just those. No n x n matrix is formed.
A single-stage problem (all stages 0) is one dense block.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.linalg import solve_triangular


@dataclasses.dataclass(frozen=True, eq=False)
class KKTStructure:
    """Static scatter maps from NLP sparsity patterns to the padded block-tridiagonal layout.

    Flat targets index the concatenation ``[A.ravel(), B.ravel(), trash]`` of the diagonal blocks
    A (S, nb, nb), sub-diagonal blocks B (S, nb, nb; B[S-1] stays zero) and one trash slot.
    """

    n: int
    m: int
    S: int
    nb: int
    var_pos: np.ndarray      # (n,) position of variable i in the stage-ordered vector (S*nb)
    con_pos: np.ndarray      # (m,) position of constraint multiplier j
    pad_pos: np.ndarray      # (n_pad,) padding positions
    pad_sign: np.ndarray     # (n_pad,) +1 for padding in the primal part, -1 in the dual part
    nbx: int                 # primal part of every block: local positions [0, nbx)
    hess_t1: np.ndarray      # (nnz_h,) flat target of K[r, c] for hessian entry (r, c)
    hess_t2: np.ndarray      # (nnz_h,) flat target of the mirrored entry K[c, r] (or trash)
    jac_t1: np.ndarray       # (nnz_j,) flat target of K[y_j, x_i]
    jac_t2: np.ndarray       # (nnz_j,) flat target of K[x_i, y_j] (or trash)
    var_diag_t: np.ndarray   # (n,) flat target of K[x_i, x_i]
    con_diag_t: np.ndarray   # (m,) flat target of K[y_j, y_j]
    pad_diag_t: np.ndarray   # (n_pad,)
    b_rows: np.ndarray       # local rows that are structurally nonzero in some B_k (sorted)
    b_cols: np.ndarray       # local columns that are structurally nonzero in some B_k

    @property
    def n_pad(self) -> int:
        return int(self.pad_pos.size)

    @property
    def n_pad_pos(self) -> int:
        return int(np.sum(self.pad_sign > 0))

    @property
    def n_pad_neg(self) -> int:
        return int(np.sum(self.pad_sign < 0))

    @property
    def size(self) -> int:
        return self.S * self.nb


def _compress_stages(var_stage, con_stage):
    """Map the stage ids used to 0..S-1 (keeping order)."""
    ids = np.unique(np.concatenate([np.asarray(var_stage), np.asarray(con_stage)]).astype(np.int64))
    remap = {int(s): k for k, s in enumerate(ids)}
    vs = np.array([remap[int(s)] for s in var_stage], dtype=np.int64)
    cs = np.array([remap[int(s)] for s in con_stage], dtype=np.int64)
    return vs, cs, max(len(ids), 1)


def build_structure(n, m, var_stage, con_stage, hess_rows, hess_cols, jac_rows, jac_cols) -> KKTStructure:
    """Precompute (numpy, once per NLP) the block layout and all scatter targets.

    Raises ValueError if an entry couples stages more than one apart (K not block-tridiagonal).
    """
    var_stage = np.asarray(var_stage, dtype=np.int64).reshape(-1)
    con_stage = np.asarray(con_stage, dtype=np.int64).reshape(-1)
    if var_stage.size != n or con_stage.size != m:
        raise ValueError(f"var_stage/con_stage must have sizes n={n}, m={m}, got "
                         f"{var_stage.size}, {con_stage.size}")
    vs, cs, S = _compress_stages(var_stage, con_stage) if n + m else (var_stage, con_stage, 1)
    nvar = np.bincount(vs, minlength=S)
    ncon = np.bincount(cs, minlength=S)
    # Elimination direction: a pivot block whose equality rows outnumber its variables is singular
    # although K is not (an optimal-control problem with a fixed initial state: interval 0's rows
    # act on stage 1's variables). Eliminating from the other end (Riccati direction) gives that
    # block the Schur complement of its neighbour first. Start at the end with the larger surplus.
    if nvar[-1] - ncon[-1] > nvar[0] - ncon[0]:
        vs, cs = S - 1 - vs, S - 1 - cs
        nvar, ncon = nvar[::-1], ncon[::-1]
    # local layout of a block: [variables, primal padding | constraints, dual padding], split at
    # the static nbx = max_k n_k so that the fast path can factor the primal part first
    nbx = int(nvar.max()) if n else 0
    nbc = int(ncon.max()) if m else 0
    if nbx + nbc == 0:
        nbx = 1
    nb = nbx + nbc
    var_loc = np.zeros(n, np.int64)
    con_loc = np.zeros(m, np.int64)
    fx = np.zeros(S, np.int64)
    fc = np.zeros(S, np.int64)
    for i in range(n):
        var_loc[i] = fx[vs[i]]
        fx[vs[i]] += 1
    for j in range(m):
        con_loc[j] = nbx + fc[cs[j]]
        fc[cs[j]] += 1
    pad_stage = np.concatenate([np.full(nbx - fx[k], k) for k in range(S)]
                               + [np.full(nbc - fc[k], k) for k in range(S)]).astype(np.int64)
    pad_loc = np.concatenate([np.arange(fx[k], nbx) for k in range(S)]
                             + [np.arange(nbx + fc[k], nb) for k in range(S)]).astype(np.int64)
    pad_sign = np.concatenate([np.ones(int(np.sum(nbx - fx)))] + [-np.ones(int(np.sum(nbc - fc)))])

    nbb = nb * nb
    off_b = S * nbb
    trash = 2 * S * nbb

    def target(sr, lr, sc, lc):
        """Flat target of K[(sr, lr), (sc, lc)] if stored (lower part across stages), else trash."""
        sr, lr, sc, lc = map(np.asarray, (sr, lr, sc, lc))
        t = np.full(sr.shape, trash, np.int64)
        same = sr == sc
        t[same] = sr[same] * nbb + lr[same] * nb + lc[same]
        below = sr == sc + 1
        t[below] = off_b + sc[below] * nbb + lr[below] * nb + lc[below]
        if np.any(np.abs(sr - sc) > 1):
            raise ValueError("KKT structure: an entry couples stages more than one apart; the "
                             "stage-ordered KKT matrix must be block-tridiagonal")
        return t

    hr = np.asarray(hess_rows, np.int64)
    hc = np.asarray(hess_cols, np.int64)
    if np.any(hr < hc):
        raise ValueError("NLP.hess_rows/hess_cols must describe the lower triangle (row >= col)")
    h1 = target(vs[hr], var_loc[hr], vs[hc], var_loc[hc])
    h2 = target(vs[hc], var_loc[hc], vs[hr], var_loc[hr])
    h2 = np.where(hr == hc, trash, h2)
    jr = np.asarray(jac_rows, np.int64)
    jc = np.asarray(jac_cols, np.int64)
    j1 = target(cs[jr], con_loc[jr], vs[jc], var_loc[jc])
    j2 = target(vs[jc], var_loc[jc], cs[jr], con_loc[jr])
    # exactly the stored ones among (t1, t2) must be kept; for cross-stage entries one is trash
    # The couplings B_k touch few local rows/columns (the states shared by neighbouring stages):
    # the Schur update B_k D_k^{-1} B_k^T only needs those, see ``factor``.
    tb = np.concatenate([h1, h2, j1, j2])
    tb = tb[(tb >= off_b) & (tb < trash)] - off_b
    b_rows = np.unique((tb % nbb) // nb).astype(np.int64)
    b_cols = np.unique(tb % nb).astype(np.int64)
    if b_rows.size == 0:
        b_rows = b_cols = np.zeros(1, np.int64)
    return KKTStructure(
        n=n, m=m, S=S, nb=nb,
        var_pos=vs * nb + var_loc, con_pos=cs * nb + con_loc, pad_pos=pad_stage * nb + pad_loc,
        pad_sign=pad_sign, nbx=nbx,
        hess_t1=h1, hess_t2=h2, jac_t1=j1, jac_t2=j2,
        var_diag_t=vs * nbb + var_loc * (nb + 1), con_diag_t=cs * nbb + con_loc * (nb + 1),
        pad_diag_t=pad_stage * nbb + pad_loc * (nb + 1),
        b_rows=b_rows, b_cols=b_cols,
    )


def structure_of(nlp) -> KKTStructure:
    """KKTStructure of an ``NLP`` (cached on the instance)."""
    cached = getattr(nlp, "_kkt_structure_cache", None)
    if cached is None:
        cached = build_structure(nlp.n, nlp.m, nlp.var_stage, nlp.con_stage, nlp.hess_rows,
                                 nlp.hess_cols, nlp.jac_rows, nlp.jac_cols)
        object.__setattr__(nlp, "_kkt_structure_cache", cached)
    return cached


def assemble(st: KKTStructure, hess_vals, jac_vals, diag_x, diag_c):
    """Blocks (A, B) of K = [[W + diag(diag_x), J^T], [J, diag(diag_c)]] (diag_c = -D_c)."""
    S, nb = st.S, st.nb
    flat = jnp.zeros(2 * S * nb * nb + 1, dtype=jnp.result_type(float))
    idx = np.concatenate([st.hess_t1, st.hess_t2, st.jac_t1, st.jac_t2, st.var_diag_t,
                          st.con_diag_t, st.pad_diag_t])
    vals = jnp.concatenate([hess_vals, hess_vals, jac_vals, jac_vals, diag_x, diag_c,
                            jnp.asarray(st.pad_sign, dtype=jnp.result_type(float))])
    flat = flat.at[idx].add(vals)
    A = flat[: S * nb * nb].reshape(S, nb, nb)
    B = flat[S * nb * nb: 2 * S * nb * nb].reshape(S, nb, nb)
    return A, B


def add_diagonal(st: KKTStructure, A, diag_x, diag_c):
    """A + the diagonal entries diag_x (variables) and diag_c (constraints), padding untouched."""
    flat = A.reshape(-1)
    flat = flat.at[st.var_diag_t].add(diag_x).at[st.con_diag_t].add(diag_c)
    return flat.reshape(A.shape)


class Factor(NamedTuple):
    Dinv: jax.Array     # (S, nb, nb) inverses of the pivot blocks D_k of the equilibrated K
    L: jax.Array        # (S, r, nb) rows b_rows of L_{k+1,k} = B_k D_k^{-1} (the others are zero)
    npos: jax.Array     # inertia of K (padding removed)
    nneg: jax.Array
    nzero: jax.Array    # numerically zero (or non-finite) eigenvalues: K singular
    d: jax.Array        # (S, nb) symmetric equilibration: the factors are of diag(d) K diag(d)


def equilibrate(A, B, passes: int = 2):
    """Symmetric Ruiz scaling d (S, nb): row/column i of K divided by sqrt(max_j |K_ij|), repeated.

    Near the end of an IPM solve Sigma spans 1e-17 .. 1e18; the block elimination (no pivoting
    across stages) then loses every digit unless K is equilibrated first. A diagonal congruence
    leaves the inertia unchanged (Sylvester)."""
    S_, nb = A.shape[0], A.shape[1]
    d = jnp.ones((S_, nb), A.dtype)
    for _ in range(passes):
        As, Bs = scale_blocks(A, B, d)
        aB = jnp.abs(Bs)
        rmax = jnp.maximum(jnp.max(jnp.abs(As), axis=2), jnp.max(aB, axis=1))    # A_k rows, B_k^T rows
        rmax = rmax.at[1:].max(jnp.max(aB[:-1], axis=2))                          # B_{k-1} rows
        d = d / jnp.sqrt(jnp.where((rmax > 0) & jnp.isfinite(rmax), rmax, 1.0))
    return d


def scale_blocks(A, B, d):
    """Blocks of diag(d) K diag(d); B[k] couples block k+1 (rows) with block k (columns)."""
    dn = jnp.concatenate([d[1:], jnp.ones_like(d[:1])], axis=0)
    return A * d[:, :, None] * d[:, None, :], B * dn[:, :, None] * d[:, None, :]


def _pivot_block(Dk, rel_zero_tol):
    """Inverse and inertia of one symmetric pivot block.

    Symmetric equilibration R D_k R (R = diag(1/sqrt(max_j |D_ij|)), a congruence, so the inertia
    is unchanged, Sylvester) brings graded IPM blocks (entries 1e-10 .. 1e10) to unit scale; then
    R D_k R = Q diag(w) Q^T (LAPACK syevd) gives the inertia as the signs of w, with |w| below
    rel_zero_tol * max|w| counted as zero, and D_k^{-1} = (R Q) diag(1/w) (R Q)^T.
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
    Qr = Q * r[:, None]
    Dinv = (Qr / w_safe) @ Qr.T
    return Dinv, nneg, nzero


def _tri_inv(L):
    """Inverse of a lower-triangular matrix (LAPACK trsm; measured faster on XLA:CPU than a
    recursive blocked inverse built from matrix products)."""
    return solve_triangular(L, jnp.eye(L.shape[-1], dtype=L.dtype), lower=True)


def _quasidefinite_block(Dk, nbx):
    """Fast path: D_k = [[P, Q^T], [Q, R]] (primal part first) with P > 0 and -(R - Q P^{-1} Q^T) > 0
    checked by two Cholesky factorisations; then inertia(D_k) = (nbx, nb - nbx, 0) exactly
    (Sylvester) and D_k^{-1} follows from the block formula. Returns (Dinv, ok)."""
    nb = Dk.shape[0]
    P = Dk[:nbx, :nbx]
    Lp = jnp.linalg.cholesky(P)
    Lpi = _tri_inv(Lp)
    Pinv = Lpi.T @ Lpi
    if nbx == nb:
        return Pinv, jnp.all(jnp.isfinite(Pinv))
    Q = Dk[nbx:, :nbx]
    R = Dk[nbx:, nbx:]
    W = Q @ Lpi.T
    Sc = W @ W.T - R                      # minus the Schur complement
    Ls = jnp.linalg.cholesky(0.5 * (Sc + Sc.T))
    Lsi = _tri_inv(Ls)
    Scinv = Lsi.T @ Lsi
    G = Pinv @ Q.T
    GS = G @ Scinv
    Dinv = jnp.concatenate([jnp.concatenate([Pinv - GS @ G.T, GS], axis=1),
                            jnp.concatenate([GS.T, -Scinv], axis=1)], axis=0)
    return Dinv, jnp.all(jnp.isfinite(Dinv))


def factor(st: KKTStructure, A, B, rel_zero_tol: float | None = None, fast: bool = True) -> Factor:
    """Block LDL^T of K by a forward ``lax.scan`` over the stages; inertia of K included.

    K is first equilibrated (``equilibrate``). Each pivot block then tries the quasi-definite fast
    path (two Choleskys); only blocks where it fails (indefinite primal part, or singular) are
    eigen-decomposed (``lax.cond``), so the inertia is exact in both cases.
    """
    d = equilibrate(A, B)
    A, B = scale_blocks(A, B, d)
    if rel_zero_tol is None:
        rel_zero_tol = 10.0 * st.nb * float(np.finfo(np.float64).eps)
    nbx, nb = st.nbx, st.nb

    def slow(Dk):
        return _pivot_block(Dk, rel_zero_tol)

    rb, cb = st.b_rows, st.b_cols
    rr, cc = np.ix_(rb, rb), np.ix_(cb, cb)

    def body(C, ab):
        a, b = ab
        Dk = a.at[rr].add(-C)
        Dk = 0.5 * (Dk + Dk.T)
        if fast and nbx > 0:
            Dinv_f, ok = _quasidefinite_block(Dk, nbx)
            Dinv, nneg, nzero = lax.cond(
                ok, lambda D_: (Dinv_f, jnp.asarray(nb - nbx, jnp.int64), jnp.zeros((), jnp.int64)),
                lambda D_: tuple(v.astype(jnp.int64) if v.ndim == 0 else v for v in slow(D_)), Dk)
        else:
            Dinv, nneg, nzero = slow(Dk)
        bs = b[np.ix_(rb, cb)]                 # the nonzero part of B_k
        Cn = bs @ Dinv[cc] @ bs.T              # B_k D_k^{-1} B_k^T on rows/columns b_rows
        return 0.5 * (Cn + Cn.T), (Dinv, bs @ Dinv[cb], nneg, nzero)

    C0 = jnp.zeros((rb.size, rb.size), dtype=A.dtype)
    _, (Dinv, L, nneg, nzero) = lax.scan(body, C0, (A, B))
    nneg = jnp.sum(nneg)
    nzero = jnp.sum(nzero)
    npos = st.S * st.nb - nneg - nzero - st.n_pad_pos
    return Factor(Dinv, L, npos, nneg - st.n_pad_neg, nzero, d)


def _solve_vec(st: KKTStructure, fac: Factor, r):
    """Solve K u = r for a stage-blocked vector r (S, nb) with the block LDL^T of diag(d) K diag(d)."""
    L = fac.L
    r = fac.d * r

    rb = st.b_rows

    def fwd(zprev, inp):
        rk, Lprev = inp
        zk = rk.at[rb].add(-(Lprev @ zprev))
        return zk, zk

    Lprev = jnp.concatenate([jnp.zeros_like(L[:1]), L[:-1]], axis=0)
    _, z = lax.scan(fwd, jnp.zeros_like(r[0]), (r, Lprev))
    w = jnp.einsum("kij,kj->ki", fac.Dinv, z)

    def bwd(unext, inp):
        wk, Lk = inp
        uk = wk - Lk.T @ unext[rb]
        return uk, uk

    _, u = lax.scan(bwd, jnp.zeros_like(r[0]), (w, L), reverse=True)
    return fac.d * u


def matvec(A, B, u):
    """K u for the block-tridiagonal K given by (A, B), u of shape (S, nb)."""
    y = jnp.einsum("kij,kj->ki", A, u)
    low = jnp.einsum("kij,kj->ki", B[:-1], u[:-1])     # B_k u_k into block k+1
    up = jnp.einsum("kji,kj->ki", B[:-1], u[1:])       # B_k^T u_{k+1} into block k
    y = y.at[1:].add(low)
    y = y.at[:-1].add(up)
    return y


def to_blocks(st: KKTStructure, rx, rc):
    v = jnp.zeros(st.size, dtype=jnp.result_type(rx, rc, float))
    v = v.at[st.var_pos].set(rx).at[st.con_pos].set(rc)
    return v.reshape(st.S, st.nb)


def from_blocks(st: KKTStructure, u):
    u = u.reshape(-1)
    return u[st.var_pos], u[st.con_pos]


def solve(st: KKTStructure, fac: Factor, A, B, rx, rc, min_steps: int = 1, max_steps: int = 10,
          residual_ratio_max: float = 1e-10):
    """(dx, dy) solving K [dx; dy] = [rx; rc] with adaptive iterative refinement (as IPOPT's
    min/max_refinement_steps, residual_ratio_max): u_{i+1} = u_i + K^{-1}(r - K u_i) until the
    residual of the equilibrated system, ||d (r - K u)||_inf / (||u / d||_inf + ||d r||_inf), is at
    most ``residual_ratio_max`` (after at least ``min_steps`` and at most ``max_steps`` refinements)."""
    r = to_blocks(st, rx, rc)
    dr = jnp.max(jnp.abs(fac.d * r))

    def ratio(u, res):
        return jnp.max(jnp.abs(fac.d * res)) / jnp.maximum(jnp.max(jnp.abs(u / fac.d)) + dr, 1e-300)

    def cond(c):
        _, res, t = c
        return (t <= max_steps) & ((t <= min_steps) | (ratio(c[0], res) > residual_ratio_max))

    def body(c):
        u, res, t = c
        u = u + _solve_vec(st, fac, res)
        return u, r - matvec(A, B, u), t + 1

    # one traced solve: the first pass (t = 0) is the plain solve, the others refine
    u, _, _ = lax.while_loop(cond, body, (jnp.zeros_like(r), r, jnp.zeros((), jnp.int32)))
    return from_blocks(st, u)


def inertia_ok(st: KKTStructure, fac: Factor):
    """True where K has inertia (n, m, 0), as required by Algorithm IC of the IPOPT paper."""
    return (fac.npos == st.n) & (fac.nneg == st.m) & (fac.nzero == 0)


def dense_matrix(st: KKTStructure, A, B):
    """The full stage-ordered K (padding included) as a dense array: for tests only."""
    S, nb = st.S, st.nb
    K = np.zeros((S * nb, S * nb))
    A = np.asarray(A)
    B = np.asarray(B)
    for k in range(S):
        K[k * nb:(k + 1) * nb, k * nb:(k + 1) * nb] = A[k]
        if k + 1 < S:
            K[(k + 1) * nb:(k + 2) * nb, k * nb:(k + 1) * nb] = B[k]
            K[k * nb:(k + 1) * nb, (k + 1) * nb:(k + 2) * nb] = B[k].T
    return K
