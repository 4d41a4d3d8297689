"""Structure-exploiting solution of the IPM's augmented (KKT) system with exact inertia.

The reduced primal-dual system solved at every iteration (IPOPT paper, eq. (13) after the slack
step has been eliminated, see ``algorithm.py``) is

    [ W + Sigma_x + delta_w I     J^T  ] [dx]   [r_x]
    [ J                          -D_c  ] [dy] = [r_c] ,       D_c = diag(d_c) >= 0,

with W (n x n) the Hessian of the Lagrangian, J (m x n) the constraint Jacobian. The unknowns are
ordered stage by stage, ``[x_0, y_0, x_1, y_1, ...]`` with ``x_k`` the variables and ``y_k`` the
multipliers of the constraints of stage k (``NLP.var_stage`` / ``NLP.con_stage``). Each stage is
padded to a common block size ``nb`` with decoupled identity rows, so K is block-tridiagonal with
S diagonal blocks A_k and sub-diagonal blocks B_k = K[stage k+1, stage k].

Elimination order 1, 2, ..., S-1, 0 (an arrowhead order: block 0 is a border, eliminated last):

    D_1 = A_1,   D_{k+1} = A_{k+1} - B_k D_k^{-1} B_k^T,   L_{k+1,k} = B_k D_k^{-1}   (lax.while_loop)
    X_1 = B_0^T, X_{k+1} = -X_k D_k^{-1} B_k^T,          L_{0,k} = X_k D_k^{-1}
    D_0 = A_0 - sum_k X_k D_k^{-1} X_k^T

By Sylvester's law of inertia, inertia(K) = sum_k inertia(D_k); the padding contributes exactly
one eigenvalue of known sign per padded row, which is subtracted. Measures that keep the block
elimination (which cannot pivot across stages) accurate and cheap on IPM matrices:

- K is first symmetrically equilibrated (Ruiz, a diagonal congruence: inertia unchanged). Near
  the end of a solve Sigma spans 1e-17 .. 1e18, and without it the solves lose every digit.
- The border is the end stage whose equality rows outnumber its variables: with a fixed initial
  state, interval 0 has more equality rows than stage-0 variables, so A_0 is singular although K
  is not; as the border it receives the Schur complements of all other blocks first. (Before,
  the whole order was reversed, the Riccati direction; on the humanoid NLPs that left half of
  the pivot blocks off the fast path below, and the synthetic matrix of scripts/bench_kkt.py
  with the wrong inertia and a backward error of 1e-10 after 10 refinement steps.) The coupling
  X_k lives on the few rows ``b_rows`` of block k, and is not stored: the solves apply it by
  r-dimensional recursions.
- Solves use adaptive iterative refinement on the equilibrated residual (IPOPT's rule).

Each block is laid out as [variables | constraints] (split at a static size). A pivot block
D_k = [[P, Q^T], [Q, R]] is first tried on a quasi-definite fast path that certifies inertia
(nbx, nb - nbx, 0) with Cholesky factorisations only, after the congruence
T = [[I, 0], [gamma (I - gamma R)^{-1} Q, I]] (``_quasidefinite_block``): an augmented-Lagrangian
term makes P positive definite where it is indefinite only along directions the constraints pin
down, which is the case of the humanoid's joint-angle Hessian (constraint curvature). Blocks
where it fails are equilibrated and eigen-decomposed (``lax.cond``): the signs of the
eigenvalues give the exact inertia and the decomposition gives D_k^{-1}. Either way D_k^{-1} is
kept as N_k diag(+-1) N_k^T, never formed (an nb^3 product per block), and the solves are
matrix-vector products. B_k is nonzero only in a few local
rows/columns (the variables shared by neighbouring stages), and the Schur update uses just
those; when the fill reaches only primal rows, R is the diagonal -D_c and the fill-independent
part of the fast path is done for all blocks at once outside the loop (``_qd_diag_pre``). No
n x n matrix is formed. A single-stage problem (all stages 0) is one dense block (the border).
The IPM's inertia-correction trials stop eliminating once the blocks done already rule out
inertia (n, m, 0) (``factor(..., early_exit=True)``, bound in ``_negative_caps``): on T1's stage 2
at N = 100 (425 iterations), 80 of 866 trial factorisations stopped early, skipping 34-89 of the
101 blocks; a trial short of the right inertia by a few eigenvalues still runs to the end.
Without an exit the factorisation costs what it did as a scan (interleaved: 7.40 against 7.49
ms); a singular trial 6.37 against 10.45 ms.

Cost (scripts/bench_kkt.py --baseline-kkt, T1 stage 2 at N = 100: S = 101, nb = 44; shared
2-core machine at load 2.3-3.2, timings interleaved with the previous eigh-based version): factor
20-36 -> 8-15 ms, refined solve 2.7-3.2 -> 2.1-2.5 ms; pivot blocks off the fast path 48-101 ->
0-21 of 101 (0-8 where K has the inertia the IPM accepts); the IPM's T1 stage-2 iteration
(scripts/bench_ipm.py per_iteration, 40 iterations) 59 -> 33 ms.
"""

from __future__ import annotations

import dataclasses
import functools
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


def build_structure(n, m, var_stage, con_stage, hess_rows, hess_cols, jac_rows, jac_cols,
                    order: str = "auto") -> KKTStructure:
    """Precompute (numpy, once per NLP) the block layout and all scatter targets.

    ``order``: which end of the stage chain becomes block 0, the border block that is eliminated
    last (see ``factor``). "auto" puts there the end stage whose variables fall shortest of its
    constraints (the structurally singular one of an optimal-control problem with a fixed
    initial state); "forward" keeps stage 0 first, "backward" reverses the stages.
    Raises ValueError if an entry couples stages more than one apart (K not block-tridiagonal).
    """
    var_stage = np.asarray(var_stage, dtype=np.int64).reshape(-1)
    con_stage = np.asarray(con_stage, dtype=np.int64).reshape(-1)
    if var_stage.size != n or con_stage.size != m:
        raise ValueError(f"var_stage/con_stage must have sizes n={n}, m={m}, got "
                         f"{var_stage.size}, {con_stage.size}")
    if order not in ("auto", "forward", "backward"):
        raise ValueError(f"order must be 'auto', 'forward' or 'backward', got {order!r}")
    vs, cs, S = _compress_stages(var_stage, con_stage) if n + m else (var_stage, con_stage, 1)
    nvar = np.bincount(vs, minlength=S)
    ncon = np.bincount(cs, minlength=S)
    # Orientation: block 0 is eliminated last (it is the border of an arrowhead elimination
    # order 1, 2, ..., S-1, 0), so it receives the Schur complements of all other blocks. A
    # block whose equality rows outnumber its variables is singular on its own although K is not
    # (a fixed initial state: interval 0's rows act on stage 1's variables); it must be that
    # border. On the humanoid NLPs this (forward) direction also keeps nearly every other pivot
    # block quasi-definite, unlike the reverse (Riccati) direction, see ``factor``.
    if order == "backward" or (order == "auto" and nvar[-1] - ncon[-1] < nvar[0] - ncon[0]):
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
    N: jax.Array        # (S, nb, nb) and (S, nb): the inverses of the pivot blocks D_k of the
    sgn: jax.Array      # equilibrated K as D_k^{-1} = N_k diag(sgn_k) N_k^T, sgn_k = +-1; [0] is
                        # the border block's (eliminated last, see ``factor``)
    L: jax.Array        # (S, r, nb) rows b_rows of L_{k+1,k} = B_k D_k^{-1} (the others are
                        # zero); [0] is zero (block 0 is the border, see ``factor``)
    npos: jax.Array     # inertia of K (padding removed)
    nneg: jax.Array
    nzero: jax.Array    # numerically zero (or non-finite) eigenvalues: K singular
    d: jax.Array        # (S, nb) symmetric equilibration: the factors are of diag(d) K diag(d)


# gamma of the congruence of the quasi-definite pivot path (``_quasidefinite_block``), for
# equilibrated blocks (entries <= 1). On T1's stage-2 KKT matrices (N = 100, scripts/bench_kkt.py)
# 30 keeps the most blocks on the fast path (97-100 of 100; 1-96 with gamma = 0); a larger gamma
# only costs digits (D^{-1} is formed from terms of size gamma^2).
QD_GAMMA = 30.0


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
    rel_zero_tol * max|w| counted as zero, and D_k^{-1} = N diag(sign w) N^T, N = R Q |w|^{-1/2}.
    Returns (N, sign w, [nneg, nzero, path = 2]) (path as ``pivot_paths``).
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


def _apply_inv(N, sgn, v):
    """D^{-1} v = N (sgn * N^T v) for factored pivot inverses (``Factor.N``, ``Factor.sgn``): one
    block (nb, nb) or all blocks at once (S, nb, nb)."""
    return jnp.einsum("...ij,...j->...i", N, sgn * jnp.einsum("...ji,...j->...i", N, v))


def _tri_inv(L):
    """Inverse of a lower-triangular matrix (LAPACK trsm; measured faster on XLA:CPU than a
    recursive blocked inverse built from matrix products)."""
    return solve_triangular(L, jnp.eye(L.shape[-1], dtype=L.dtype), lower=True)


def _quasidefinite_block(Dk, nbx, gamma=QD_GAMMA):
    """Fast path with exact inertia: D_k = [[P, Q^T], [Q, R]] (primal part first, P nbx x nbx).

    The congruence T = [[I, 0], [G Q, I]] with G = gamma (I - gamma R)^{-1} (T unit triangular,
    so inertia(T^T D_k T) = inertia(D_k), Sylvester) gives

        T^T D_k T = [[P~, Q~^T], [Q~, R]],   P~ = P + Q^T (2G + G R G) Q,   Q~ = (I + R G) Q.

    With M = I - gamma R: Q~ = M^{-1} Q and P~ = P + gamma (Q^T M^{-1} Q + Q~^T Q~). Three Cholesky
    factorisations, of M, of P~ and of -(R - Q~ P~^{-1} Q~^T), all succeeding certify inertia(D_k) =
    (nbx, nb - nbx, 0) exactly (for G = 0 this is the plain quasi-definite test). The
    augmented-Lagrangian term gamma Q^T Q makes P~ positive definite where P is indefinite only
    along directions the constraints pin down (the Hessian of the joint angles, which comes from
    constraint curvature); on the dual rows of inequalities (R << 0) G tends to -R^{-1} and the
    transformation is the Schur complement of R. Then

        D_k^{-1} = T (T^T D_k T)^{-1} T^T = N1 N1^T - N2 N2^T,
        N1 = [I; E] Lp^{-T},   N2 = ([0; I] - [I; E] P~^{-1} Q~^T) Ls^{-T},   E = G Q = gamma Q~,

    (Lp, Ls the Cholesky factors of P~ and of minus the Schur complement). Returns ([N1, N2], ok):
    D_k^{-1} = [N1, N2] diag(I, -I) [N1, N2]^T.
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
    V = Lmi @ Q                                   # Q^T M^{-1} Q = V^T V
    Qt = Lmi.T @ V                                # Q~ = M^{-1} Q
    Pt = P + gamma * (V.T @ V + Qt.T @ Qt)
    Lpi = _tri_inv(jnp.linalg.cholesky(0.5 * (Pt + Pt.T)))
    W = Qt @ Lpi.T
    Sc = W @ W.T - R                              # minus the Schur complement
    Lsi = _tri_inv(jnp.linalg.cholesky(0.5 * (Sc + Sc.T)))
    Gp = Lpi.T @ W.T                              # P~^{-1} Q~^T  (nbx x nc)
    IE = jnp.concatenate([jnp.eye(nbx, dtype=Dk.dtype), gamma * Qt], axis=0)     # [I; E]
    N1 = IE @ Lpi.T
    N2 = (jnp.concatenate([jnp.zeros((nbx, nc), Dk.dtype), eye_c], axis=0) - IE @ Gp) @ Lsi.T
    N = jnp.concatenate([N1, N2], axis=1)
    return N, jnp.all(jnp.isfinite(N))


def _qd_diag_pre(A, nbx, gamma=QD_GAMMA):
    """Fill-independent part of ``_qd_diag_core`` for all blocks at once (batched, outside the
    scan): with R = diag(r) the dual part of a pivot block, M = I - gamma R is diagonal (m >= 1
    for an IPM, R <= 0; m > 0 is its Cholesky test), Q^T (2G + G R G) Q = Q^T diag(h) Q and
    Q~ = M^{-1} Q. Returns (P + Q^T diag(h) Q, NaN where not m > 0; Q~; R)."""
    P = A[:, :nbx, :nbx]
    Q = A[:, nbx:, :nbx]
    r = jnp.diagonal(A, axis1=1, axis2=2)[:, nbx:]
    m = 1.0 - gamma * r
    h = gamma * (1.0 / m + 1.0 / (m * m))
    Pb = P + jnp.einsum("kci,kc,kcj->kij", Q, h, Q)
    Pb = jnp.where(jnp.all(m > 0, axis=1)[:, None, None], Pb, jnp.nan)   # M not positive definite
    Rd = r[:, :, None] * jnp.eye(r.shape[1], dtype=A.dtype)
    return Pb, Q / m[:, :, None], Rd


def _chol(M):
    """Cholesky factor from the lower triangle (no symmetrisation pass; NaN if not positive
    definite, which the callers test)."""
    return lax.linalg.cholesky(M, symmetrize_input=False)


def _qd_diag_core(Pt, Qt, Rd, gamma=QD_GAMMA):
    """``_quasidefinite_block`` for a pivot block whose dual part R (``Rd``, diagonal) has no fill
    (``KKTStructure.b_rows`` all primal), given P~ = ``Pt`` and Q~ = ``Qt`` (``_qd_diag_pre``,
    minus the fill on P~). With Lp Lp^T = P~, W = Q~ Lp^{-T} and Ls Ls^T = W W^T - R (minus the
    Schur complement),

        T^T D_k T = F J F^T,   F = [[Lp, 0], [W, Ls]],   J = diag(I, -I),
        D_k^{-1} = M^T J M,    M = F^{-1} T^T = [[Lp^{-1}], [K21]] [I, E^T] + [[0, 0], [0, Ls^{-1}]],

    with F^{-1} = [[Lp^{-1}, 0], [K21, Ls^{-1}]], K21 = -Ls^{-1} W Lp^{-1}, and T = [[I, 0], [E, I]],
    E = gamma Q~. Written for few XLA operations (each costs ~1-2 us inside the block loop on
    CPU); D_k^{-1} itself is not formed (an nb^3 product, a third of the block's work). Returns
    (N = M^T, ok): ok iff both Cholesky factorisations succeeded (inertia (nbx, nc, 0)); a failed
    one is NaN throughout, and so is then N."""
    nbx, nc = Pt.shape[0], Qt.shape[0]
    Lpi = _tri_inv(_chol(Pt))
    W = jnp.einsum("ij,kj->ik", Qt, Lpi)                      # Q~ Lp^{-T}
    Lsi = _tri_inv(_chol(jnp.einsum("ij,kj->ik", W, W) - Rd))
    G1t = jnp.concatenate([Lpi, -((Lsi @ W) @ Lpi)], axis=0).T   # first block column of F^{-1}, transposed
    N = jnp.concatenate([G1t, gamma * (Qt @ G1t)], axis=0)       # N = M^T
    N = N.at[nbx:, nbx:].add(Lsi.T)
    return N, jnp.isfinite(N[0, 0]) & jnp.isfinite(N[-1, -1])


def _choose_pivot(ok, Nq, build, parts, rel_zero_tol, nneg_fast):
    """(N, sgn, [nneg, nzero, path]): the fast path's factor ``Nq`` where it certified the inertia
    (``ok``; path 0, inertia (nb - nneg_fast, nneg_fast, 0), sgn = [+1.., -1..]), else the
    eigendecomposition of the block ``build(*parts)`` (built only there).

    Under ``vmap`` a ``lax.cond`` with a batched predicate becomes a select that evaluates both
    branches for every member, so every pivot block of every member would be eigen-decomposed
    (measured: a batch of 8 cost 27 ms per member and iteration against 8 ms alone). The batching
    rule keeps the batched fast path when every member's block took it, and otherwise goes member
    by member (``lax.map``), so that only the members that need it are decomposed: in a batch of
    32, some member needs it at most blocks."""
    nb = Nq.shape[-1]
    info_fast = np.array([nneg_fast, 0, 0], np.int64)      # constants: custom_vmap closes over no tracer
    sgn_fast = np.concatenate([np.ones(nb - nneg_fast), -np.ones(nneg_fast)])

    def slow(parts_):
        return _pivot_block(build(*parts_), rel_zero_tol)

    @jax.custom_batching.custom_vmap
    def choose(ok, Nq, parts_):
        return lax.cond(ok, lambda: (Nq, jnp.asarray(sgn_fast), jnp.asarray(info_fast)), lambda: slow(parts_))

    @choose.def_vmap
    def _batched(axis_size, in_batched, ok, Nq, parts_):
        ok, Nq, parts_ = jax.tree.map(lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + a.shape),
                                      (ok, Nq, parts_), tuple(in_batched))
        fast_b = (Nq, jnp.broadcast_to(sgn_fast, (axis_size, nb)), jnp.broadcast_to(info_fast, (axis_size, 3)))

        def mixed():                    # member by member: only those that need it are decomposed
            return lax.map(lambda a: choose(*a), (ok, Nq, parts_))

        return lax.cond(jnp.all(ok), lambda: fast_b, mixed), (True, True, True)

    return choose(ok, Nq, parts)


def _pivot(Dk, nbx, fast, rel_zero_tol):
    """(N, sgn, [nneg, nzero, path]) of one pivot block: path 0 quasi-definite, 2 eigendecomposition."""
    if fast and nbx > 0:
        Nq, ok = _quasidefinite_block(Dk, nbx)
        return _choose_pivot(ok, Nq, lambda D_: D_, (Dk,), rel_zero_tol, Dk.shape[0] - nbx)
    return _pivot_block(Dk, rel_zero_tol)


def _sel(ix):
    """A static slice for a contiguous index range (XLA:CPU: slices instead of gathers and
    scatters inside the scans), else the index array."""
    ix = np.asarray(ix)
    if ix.size and np.array_equal(ix, np.arange(ix[0], ix[0] + ix.size)):
        return slice(int(ix[0]), int(ix[0]) + int(ix.size))
    return ix


def _sel2(a, b):
    sa, sb = _sel(a), _sel(b)
    if isinstance(sa, slice) and isinstance(sb, slice):
        return sa, sb
    return np.ix_(np.asarray(a), np.asarray(b))


def _equilibrate_compact(st: KKTStructure, A, B, passes: int = 2):
    """``equilibrate`` + ``scale_blocks`` with fewer passes over the data (XLA:CPU: every
    elementwise pass over the (S, nb, nb) blocks costs ~0.2 ms): |A| is formed once, and of B
    only the structurally nonzero part B[:, b_rows, b_cols] (S, r, c) is touched.
    Returns (d, scaled A, scaled compact B)."""
    rb, cb = _sel(st.b_rows), _sel(st.b_cols)
    S_, nb = A.shape[0], A.shape[1]
    aA = jnp.abs(A)
    Bc = B[:, rb][:, :, cb]
    aB = jnp.abs(Bc)
    d = jnp.ones((S_, nb), A.dtype)
    for i in range(passes):
        if i == 0:
            ra, br, bc = jnp.max(aA, axis=2), jnp.max(aB, axis=2), jnp.max(aB, axis=1)
        else:                               # max_j |d_i K_ij d_j| = d_i max_j |K_ij| d_j
            dn = jnp.concatenate([d[1:], jnp.ones_like(d[:1])], axis=0)
            ra = d * jnp.max(aA * d[:, None, :], axis=2)
            br = dn[:, rb] * jnp.max(aB * d[:, None, cb], axis=2)      # rows of block k+1
            bc = d[:, cb] * jnp.max(aB * dn[:, rb, None], axis=1)      # columns of block k
        rmax = ra.at[:, cb].max(bc)
        rmax = rmax.at[1:, rb].max(br[:-1])
        d = d / jnp.sqrt(jnp.where((rmax > 0) & jnp.isfinite(rmax), rmax, 1.0))
    dn = jnp.concatenate([d[1:], jnp.ones_like(d[:1])], axis=0)
    return d, A * (d[:, :, None] * d[:, None, :]), Bc * (dn[:, rb, None] * d[:, None, cb])


def _matvec(st: KKTStructure, A, B, u):
    """``matvec`` using only the structurally nonzero part of B."""
    rb, cb = _sel(st.b_rows), _sel(st.b_cols)
    Bc = B[:-1, rb][:, :, cb]
    y = jnp.einsum("kij,kj->ki", A, u)
    y = y.at[1:, rb].add(jnp.einsum("kij,kj->ki", Bc, u[:-1, cb]))
    return y.at[:-1, cb].add(jnp.einsum("kji,kj->ki", Bc, u[1:, rb]))


@jax.custom_batching.custom_vmap
def _all_true(b):
    """``b``; under ``vmap`` one unbatched flag, all(b). With a batched predicate a ``while_loop``
    selects its whole carry (the factor arrays) per member at every step, and a ``lax.cond`` runs
    both branches: the early exit of ``factor`` stops only once every member has decided (the
    others' blocks are factored: the same decisions)."""
    return b


@_all_true.def_vmap
def _all_true_batched(axis_size, in_batched, b):
    return (jnp.all(b) if in_batched[0] else b), False


def _negative_caps(st: KKTStructure) -> np.ndarray:
    """(S,) the most negative eigenvalues the leading blocks 1..k (entry k; padding included) can
    have when K has inertia (n, m, 0), for ``factor``'s early exit.

    Haynsworth: nneg(K) = nneg(H) + nneg(S_H) with H the blocks 1..k and S_H its Schur complement
    in K. When no B_j has dual rows (``b_rows`` all primal, the constraints of stage j act on no
    variable of stage j - 1), S_H restricted to blocks k+1..S-1 is the saddle-point matrix
    [[W', A^T], [A, -D_c]] of their own constraints A, D_c >= 0 (only W' holds fill), which has
    at least as many negative eigenvalues as rows unless some y != 0 has A^T y = 0 = D_c y, and then
    K [0; y] = 0: K singular. With the decoupled -1 of block 0's dual padding,
    nneg(H) <= m + n_pad_neg - (S-1-k) (nb - nbx) - pad_0 = k (nb - nbx) + m_0 (m_0 the constraints of
    block 0). Otherwise only nneg(H) <= nneg(K) holds."""
    total = st.m + st.n_pad_neg
    if st.S == 1 or not np.all(st.b_rows < st.nbx):
        return np.full(st.S, total, np.int64)
    m0 = int(np.sum(st.con_pos // st.nb == 0))
    return np.minimum(np.arange(st.S, dtype=np.int64) * (st.nb - st.nbx) + m0, total)


@functools.partial(jax.jit, static_argnames=("st", "rel_zero_tol", "fast", "early_exit"))
def _factor(st: KKTStructure, A, B, rel_zero_tol, fast, early_exit=False):
    # jitted with the structure static (hashed by identity): repeated calls, and the several
    # call sites in one IPM trace, reuse one traced and compiled factorisation
    d, A, Bs = _equilibrate_compact(st, A, B)     # Bs: (S, r, c) nonzero part of the B_k
    if rel_zero_tol is None:
        rel_zero_tol = 10.0 * st.nb * float(np.finfo(np.float64).eps)
    nbx, nb, S = st.nbx, st.nb, st.S
    rb, cb = _sel(st.b_rows), _sel(st.b_cols)
    rr = _sel2(st.b_rows, st.b_rows)

    # the fill of blocks 1.. reaches only rows b_rows; if those are all primal, the dual part of
    # their pivot blocks is the diagonal -D_c (the (2,2) block of K is diagonal) and the fast
    # path's fill-independent work is done for all blocks at once, outside the loop
    diag_r = fast and 0 < nbx < nb and bool(np.all(st.b_rows < nbx))
    pre = _qd_diag_pre(A, nbx) if diag_r else ()

    neg_cap = jnp.asarray(_negative_caps(st))
    pos_cap = st.n + st.n_pad_pos

    def decided(cnt, k):
        """The inertia of blocks 1..k (counts, padding included) rules out inertia (n, m, 0)."""
        return (cnt[2] > 0) | (cnt[0] > pos_cap) | (cnt[1] > neg_cap[k])

    def block(Ak, C_):
        D_ = Ak.at[rr].add(-C_)
        return 0.5 * (D_ + D_.T)

    def skipped():                  # a pivot block left by the early exit: no eigenvalues, path 3
        return jnp.zeros((nb, nb), A.dtype), jnp.ones((nb,), A.dtype), jnp.array([0, 0, 3], jnp.int64)

    def counts(info):               # (npos, nneg, nzero) of a pivot block from its info vector
        return jnp.stack([nb - info[0] - info[1], info[0], info[1]]) * (info[2] != 3)

    def eliminate(k, C, X):
        """Pivot block k (fill C on rows b_rows, border coupling (-1)^k X_k): its factor, inertia
        info, L_{k+1,k} rows b_rows, and the fill passed on (C, X of block k+1)."""
        bs = Bs[k]
        if diag_r:
            pb, qt, rd = (v[k] for v in pre)
            Nq, okq = _qd_diag_core(pb.at[rr].add(-C), qt, rd)
            Nk, sk, info = _choose_pivot(okq, Nq, block, (A[k], C), rel_zero_tol, nb - nbx)
        else:
            Nk, sk, info = _pivot(block(A[k], C), nbx, fast, rel_zero_tol)
        Lk = ((bs @ Nk[cb]) * sk) @ Nk.T                    # B_k D_k^{-1} on rows b_rows (r x nb)
        Cn = jnp.einsum("ij,kj->ik", Lk[:, cb], bs)         # B_k D_k^{-1} B_k^T (lower part read)
        Xn = jnp.einsum("ar,sr->as", X, Lk[:, rb])          # X_{k+1} = -X_k D_k^{-1} B_k^T
        return Cn, Xn, Nk, sk, Lk, info

    cnt, dead = jnp.zeros(3, jnp.int64), jnp.zeros((), bool)
    if S > 1:
        r_ = st.b_rows.size
        X1 = jnp.zeros((r_, nb), A.dtype).at[:, cb].set(Bs[0]).T   # B_0^T: block 0 is the border
        C0 = jnp.zeros((r_, r_), dtype=A.dtype)
        # blocks not eliminated (early exit) keep these
        N_s, sg_s, info_s = (jnp.broadcast_to(a, (S - 1,) + a.shape) for a in skipped())
        outs = (N_s, sg_s, jnp.zeros((S - 1, r_, nb), A.dtype), jnp.zeros((S - 1, nb, r_), A.dtype), info_s)

        # a while loop, not a scan with a lax.cond per block (whose branch outputs cost 3-5% of a
        # factorisation on T1's stage 2): it stops once the blocks done rule out (n, m, 0)
        def go_on(c):
            k, dead = c[0], c[4]
            return (k < S) & ~_all_true(dead) if early_exit else k < S

        def step(c):
            k, C, X, cnt, dead, outs = c
            Cn, Xn, Nk, sk, Lk, info = eliminate(k, C, X)
            outs = tuple(o.at[k - 1].set(v) for o, v in zip(outs, (Nk, sk, Lk, X, info)))
            cnt = cnt + counts(info)
            return k + 1, Cn, Xn, cnt, dead | (early_exit & decided(cnt, k)), outs

        _, _, _, cnt, dead, (Nf, sg, Lk, X, info) = lax.while_loop(
            go_on, step, (jnp.ones((), jnp.int32), C0, X1, cnt, dead, outs))
        XN = jnp.einsum("kar,krj->kaj", X, Nf[:, rb])
        Z = jnp.einsum("kaj,kj,kbj->ab", XN, sg, XN)        # sum_k X_k D_k^{-1}[rb, rb] X_k^T
        D0 = A[0] - Z
    else:
        D0 = A[0]
    D0 = 0.5 * (D0 + D0.T)

    def border():
        return _pivot(D0, nbx, fast, rel_zero_tol)

    # ``dead`` already holds the decision on blocks 1..S-1
    N0, sg0, info0 = lax.cond(_all_true(dead), skipped, border) if early_exit else border()
    npos, nneg, nzero = cnt + counts(info0)
    if S > 1:
        Nf, sg = jnp.concatenate([N0[None], Nf], axis=0), jnp.concatenate([sg0[None], sg], axis=0)
        L = jnp.concatenate([jnp.zeros((1, st.b_rows.size, nb), A.dtype), Lk], axis=0)
        paths = jnp.concatenate([info0[None, 2], info[:, 2]]).astype(jnp.int32)
    else:
        Nf, sg, L = N0[None], sg0[None], jnp.zeros((1, st.b_rows.size, nb), A.dtype)
        paths = info0[None, 2].astype(jnp.int32)
    return Factor(Nf, sg, L, npos - st.n_pad_pos, nneg - st.n_pad_neg, nzero, d), paths


def factor(st: KKTStructure, A, B, rel_zero_tol: float | None = None, fast: bool = True,
           early_exit: bool = False) -> Factor:
    """Block LDL^T of K with the exact inertia of K.

    K is first equilibrated (``equilibrate``). The blocks are eliminated in the order 1, 2, ...,
    S-1 (``lax.while_loop``) and then 0: block 0 is a border (arrowhead elimination), coupled to the
    others only through the fill X_k, on the rows ``b_rows`` of block k, that block 0 receives
    as they are eliminated. With D_k = A_k - B_{k-1} D_{k-1}^{-1} B_{k-1}^T (k >= 1),

        X_1 = B_0^T,   X_{k+1} = -X_k D_k^{-1} B_k^T,   D_0 = A_0 - sum_k X_k D_k^{-1} X_k^T,

    and inertia(K) = sum_k inertia(D_k) (Sylvester). Each pivot block is first tried on the
    quasi-definite fast path (``_quasidefinite_block``: Cholesky factorisations only); blocks
    where it fails are eigen-decomposed (``lax.cond``), so the inertia is exact in both cases.
    ``fast=False`` eigen-decomposes every block.

    ``early_exit``: stop eliminating (the block loop ends; pivot path 3 for the blocks left) as
    soon as the blocks done so far show that the inertia is not (n, m, 0): a zero eigenvalue,
    more positive ones than n, or more negative ones than those blocks can hold
    (``_negative_caps``). The counts are then those of the blocks done, which decide the IPM's
    inertia correction (``inertia_ok`` false; ``nzero > 0`` when the deciding block was
    singular), and the factor must not be used to solve. For the IPM's inertia-correction
    trials, about half of which are rejected.
    """
    return _factor(st, A, B, rel_zero_tol=rel_zero_tol, fast=fast, early_exit=early_exit)[0]


def pivot_paths(st: KKTStructure, A, B, fast: bool = True, early_exit: bool = False):
    """(S,) how each pivot block was factored: 0 quasi-definite (Cholesky), 2 eigendecomposition,
    3 skipped (``early_exit``). Entry 0 is the border block. For diagnostics and benchmarks."""
    return _factor(st, A, B, rel_zero_tol=None, fast=fast, early_exit=early_exit)[1]


def _solve_vec(st: KKTStructure, fac: Factor, X1t, r):
    """Solve K u = r for a stage-blocked vector r (S, nb) with the factors of diag(d) K diag(d).

    Elimination order 1, ..., S-1, 0 (``factor``). The border couplings X_k = X_1 (-T_1) ...
    (-T_{k-1}), T_k = (L_{k+1,k}[:, b_rows])^T (r x r), are not stored: the sums they enter are
    evaluated by Horner-type recursions on r-vectors. ``X1t`` = X_1^T = equilibrated
    B_0[b_rows] (``_border_coupling``). The scans run over all S blocks (block 0's entries are
    dummies, L[0] = 0), so that no (S-1)-slices of the factor arrays are copied."""
    rb = _sel(st.b_rows)
    nr = st.b_rows.size
    r = fac.d * r
    L = fac.L

    def dinv(v):                          # D_k^{-1} v_k, all k at once
        return _apply_inv(fac.N, fac.sgn, v)

    if st.S == 1:
        return fac.d * dinv(r)

    def fwd(q, inp):                      # z_k = r_k - L_{k,k-1} z_{k-1}  (q = L_{k,k-1} z_{k-1})
        rk, Lk = inp
        zk = rk.at[rb].add(-q)
        return Lk @ zk, zk

    _, z = lax.scan(fwd, jnp.zeros((nr,), r.dtype), (r, L))
    w = dinv(z)
    T = L[:, :, rb]                       # (S, r, r): T_k^T

    def horner(h, inp):                   # h_k = w_k[rb] - T_k h_{k+1};  sum_k X_k w_k[rb] = X_1 h_1
        wk, Tkt = inp
        hk = wk[rb] - jnp.einsum("ji,j->i", Tkt, h)
        return hk, hk

    _, hs = lax.scan(horner, jnp.zeros((nr,), r.dtype), (w, T), reverse=True)
    v0 = r[0] - jnp.einsum("rn,r->n", X1t, hs[1])
    u0 = _apply_inv(fac.N[0], fac.sgn[0], v0)

    def gfwd(g, Tkt):                     # g_k = X_k^T u_0:  g_{k+1} = -T_k^T g_k
        return -(Tkt @ g), g

    _, g = lax.scan(gfwd, X1t @ u0, T[1:])
    gp = jnp.zeros_like(r).at[1:, rb].set(g)
    wc = w - dinv(gp)

    def bwd(unext, inp):                  # u_k = w_k - D_k^{-1} X_k^T u_0 - L_{k+1,k}^T u_{k+1}
        wk, Lk = inp
        uk = wk - jnp.einsum("ri,r->i", Lk, unext[rb])
        return uk, uk

    _, u = lax.scan(bwd, jnp.zeros_like(r[0]), (wc, L), reverse=True)
    return fac.d * u.at[0].set(u0)


def _border_coupling(st: KKTStructure, fac: Factor, B):
    """X_1^T = rows b_rows of the equilibrated B_0 (r x nb)."""
    if st.S == 1:
        return jnp.zeros((st.b_rows.size, st.nb), B.dtype)
    rb = _sel(st.b_rows)
    return B[0][rb] * fac.d[1][rb][:, None] * fac.d[0][None, :]


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
          residual_ratio_max: float = 1e-10, with_residual: bool = False):
    """(dx, dy) solving K [dx; dy] = [rx; rc] with adaptive iterative refinement (as IPOPT's
    min/max_refinement_steps, residual_ratio_max): u_{i+1} = u_i + K^{-1}(r - K u_i) until the
    residual of the equilibrated system, ||d (r - K u)||_inf / (||u / d||_inf + ||d r||_inf), is at
    most ``residual_ratio_max`` (after at least ``min_steps`` and at most ``max_steps`` refinements).
    ``with_residual``: also return ||r - K u||_inf of the returned solution (the refinement's last
    residual, so no extra product)."""
    dx, dy, res = _solve(st, fac, A, B, rx, rc, min_steps, max_steps, residual_ratio_max)
    return (dx, dy, res) if with_residual else (dx, dy)


@functools.partial(jax.jit, static_argnames=("st",))
def _solve(st, fac, A, B, rx, rc, min_steps, max_steps, residual_ratio_max):
    r = to_blocks(st, rx, rc)
    dr = jnp.max(jnp.abs(fac.d * r))
    X1t = _border_coupling(st, fac, B)

    def ratio(u, res):
        return jnp.max(jnp.abs(fac.d * res)) / jnp.maximum(jnp.max(jnp.abs(u / fac.d)) + dr, 1e-300)

    def cond(c):
        _, res, t = c
        return (t <= max_steps) & ((t <= min_steps) | (ratio(c[0], res) > residual_ratio_max))

    def body(c):
        u, res, t = c
        u = u + _solve_vec(st, fac, X1t, res)
        return u, r - _matvec(st, A, B, u), t + 1

    # one traced solve: the first pass (t = 0) is the plain solve, the others refine
    u, res, _ = lax.while_loop(cond, body, (jnp.zeros_like(r), r, jnp.zeros((), jnp.int32)))
    return (*from_blocks(st, u), jnp.max(jnp.abs(res)))


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
