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
one positive eigenvalue per padded row, which is subtracted. The small dense D_k are LU-factored
(partial pivoting) inside the scan for the solves; their inertia is counted afterwards, in one
batch over the stages, by orthogonal tridiagonalisation D_k = Q_k T_k Q_k^T (LAPACK sytrd) and a
Sturm sequence on T_k (the LDL^T pivots of a tridiagonal matrix, as in LAPACK's dstebz): exact in
the sense of Sylvester, backward stable, and cheaper than eigenvalues. No n x n matrix is formed.
A single-stage problem (all stages 0) is one dense block.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.scipy.linalg import lu_factor, lu_solve


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
    hess_t1: np.ndarray      # (nnz_h,) flat target of K[r, c] for hessian entry (r, c)
    hess_t2: np.ndarray      # (nnz_h,) flat target of the mirrored entry K[c, r] (or trash)
    jac_t1: np.ndarray       # (nnz_j,) flat target of K[y_j, x_i]
    jac_t2: np.ndarray       # (nnz_j,) flat target of K[x_i, y_j] (or trash)
    var_diag_t: np.ndarray   # (n,) flat target of K[x_i, x_i]
    con_diag_t: np.ndarray   # (m,) flat target of K[y_j, y_j]
    pad_diag_t: np.ndarray   # (n_pad,)

    @property
    def n_pad(self) -> int:
        return int(self.pad_pos.size)

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
    nb = int(max(1, (nvar + ncon).max()))
    # local positions: variables first, then constraints, then padding
    var_loc = np.zeros(n, np.int64)
    con_loc = np.zeros(m, np.int64)
    fill = np.zeros(S, np.int64)
    for i in range(n):
        var_loc[i] = fill[vs[i]]
        fill[vs[i]] += 1
    for j in range(m):
        con_loc[j] = fill[cs[j]]
        fill[cs[j]] += 1
    pad_stage = np.concatenate([np.full(nb - fill[k], k) for k in range(S)]).astype(np.int64)
    pad_loc = np.concatenate([np.arange(fill[k], nb) for k in range(S)]).astype(np.int64)

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
    return KKTStructure(
        n=n, m=m, S=S, nb=nb,
        var_pos=vs * nb + var_loc, con_pos=cs * nb + con_loc, pad_pos=pad_stage * nb + pad_loc,
        hess_t1=h1, hess_t2=h2, jac_t1=j1, jac_t2=j2,
        var_diag_t=vs * nbb + var_loc * (nb + 1), con_diag_t=cs * nbb + con_loc * (nb + 1),
        pad_diag_t=pad_stage * nbb + pad_loc * (nb + 1),
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
                            jnp.ones(st.n_pad)])
    flat = flat.at[idx].add(vals)
    A = flat[: S * nb * nb].reshape(S, nb, nb)
    B = flat[S * nb * nb: 2 * S * nb * nb].reshape(S, nb, nb)
    return A, B


class Factor(NamedTuple):
    lu: jax.Array       # (S, nb, nb) LU factors of the pivot blocks D_k
    piv: jax.Array      # (S, nb)
    L: jax.Array        # (S, nb, nb) L_{k+1,k} = B_k D_k^{-1}
    npos: jax.Array     # inertia of K (padding removed)
    nneg: jax.Array
    nzero: jax.Array    # zero (or non-finite) pivots: K numerically singular


def _sturm_inertia(D, rel_zero_tol):
    """Counts (neg, zero) of eigenvalues of symmetric blocks D (S, nb, nb), batched.

    T_k = Q_k^T D_k Q_k tridiagonal (orthogonal similarity); the pivots q_i of T_k's LDL^T,
    q_1 = d_1, q_i = d_i - e_{i-1}^2 / q_{i-1}, have the signs of T_k's eigenvalues (Sylvester).
    """
    S, nb, _ = D.shape
    bad = ~jnp.all(jnp.isfinite(D), axis=(1, 2))
    D = jnp.where(bad[:, None, None], 0.0, D)
    # symmetric equilibration (a congruence: inertia unchanged) so that graded IPM matrices
    # (entries from 1e-10 to 1e10) keep their small eigenvalues' signs through the reduction
    for _ in range(3):
        r = jnp.sqrt(jnp.max(jnp.abs(D), axis=2))
        r = jnp.where(r > 0, r, 1.0)
        D = D / r[:, :, None] / r[:, None, :]
    if nb == 1:
        q = D[:, 0, 0][None, :]
        e2 = jnp.zeros((1, S))
        tnorm = jnp.abs(D[:, 0, 0])
    else:
        _, d, e, _ = lax.linalg.tridiagonal(D, lower=True)
        e2 = jnp.concatenate([jnp.zeros((S, 1)), e ** 2], axis=1).T   # (nb, S)
        q = d.T
        tnorm = jnp.maximum(jnp.max(jnp.abs(d), axis=1), jnp.max(jnp.abs(e), axis=1))
    # rounding level of the orthogonal reduction itself: ~ eps ||D_k||
    tiny_abs = jnp.maximum(10.0 * jnp.finfo(float).eps * tnorm, jnp.finfo(float).tiny)

    def step(qprev, inp):
        di, e2i = inp
        t = e2i / qprev
        qi = di - t
        # zero pivot: |q_i| at the level of the rounding error of its own computation; it is
        # counted as zero and continued past with a tiny negative value (as in LAPACK dstebz)
        tiny = jnp.maximum(rel_zero_tol * (jnp.abs(di) + jnp.abs(t)), tiny_abs)
        zero = jnp.abs(qi) <= tiny
        qn = jnp.where(zero, -tiny, qi)
        return qn, (qi < -tiny, zero)

    _, (neg, zero) = lax.scan(step, jnp.ones(S), (q, e2))
    nneg = jnp.sum(neg, axis=0)
    nzero = jnp.sum(zero, axis=0) + nb * bad
    return jnp.sum(jnp.where(bad, 0, nneg)), jnp.sum(nzero)


def factor(st: KKTStructure, A, B, rel_zero_tol: float = 1e-13) -> Factor:
    """Block LDL^T of K by a forward ``lax.scan`` over the stages; inertia of K included."""

    def body(C, ab):
        a, b = ab
        Dk = a - C
        Dk = 0.5 * (Dk + Dk.T)
        lu, piv = lu_factor(Dk)
        X = lu_solve((lu, piv), b.T)          # D_k^{-1} B_k^T
        Cn = b @ X
        return 0.5 * (Cn + Cn.T), (Dk, lu, piv, X.T)

    C0 = jnp.zeros((st.nb, st.nb), dtype=A.dtype)
    _, (D, lu, piv, L) = lax.scan(body, C0, (A, B))
    nneg, nzero = _sturm_inertia(D, rel_zero_tol)
    npos = st.S * st.nb - nneg - nzero - st.n_pad
    return Factor(lu, piv, L, npos, nneg, nzero)


def _solve_vec(fac: Factor, r):
    """Solve K u = r for a stage-blocked vector r (S, nb) with the block LDL^T."""
    L = fac.L

    def fwd(zprev_L, inp):
        rk, Lprev = inp
        zk = rk - Lprev @ zprev_L
        return zk, zk

    Lprev = jnp.concatenate([jnp.zeros_like(L[:1]), L[:-1]], axis=0)
    _, z = lax.scan(fwd, jnp.zeros_like(r[0]), (r, Lprev))
    w = jax.vmap(lambda lu, piv, zk: lu_solve((lu, piv), zk))(fac.lu, fac.piv, z)

    def bwd(unext, inp):
        wk, Lk = inp
        uk = wk - Lk.T @ unext
        return uk, uk

    _, u = lax.scan(bwd, jnp.zeros_like(r[0]), (w, L), reverse=True)
    return u


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


def solve(st: KKTStructure, fac: Factor, A, B, rx, rc, refinement_steps: int = 1):
    """(dx, dy) solving K [dx; dy] = [rx; rc], with ``refinement_steps`` of iterative refinement."""
    r = to_blocks(st, rx, rc)
    u = _solve_vec(fac, r)
    for _ in range(refinement_steps):
        u = u + _solve_vec(fac, r - matvec(A, B, u))
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
