"""Block LDL^T of the equilibrated KKT matrix in arrowhead order, with the exact inertia.

After equilibration (``assembly.equilibrate_compact``) the blocks are eliminated in the order
1, 2, ..., S-1 (a ``lax.while_loop``) and then 0, the border:

    D_1 = A_1,   D_{k+1} = A_{k+1} - B_k D_k^{-1} B_k^T,   L_{k+1,k} = B_k D_k^{-1},
    X_1 = B_0^T, X_{k+1} = -X_k D_k^{-1} B_k^T,            L_{0,k} = X_k D_k^{-1},
    D_0 = A_0 - sum_{k>=1} X_k D_k^{-1} X_k^T.

B_k is nonzero only on the rows ``b_rows`` and columns ``b_cols`` (``structure``), so the fill
C_{k+1} = B_k D_k^{-1} B_k^T is an (r, r) matrix on the rows b_rows of block k+1, L_{k+1,k} is
kept as its rows b_rows (r, nb), and the border coupling X_k (nb, r) lives on the columns
b_rows of block k. By Sylvester's law of inertia, inertia(K) = sum_k inertia(D_k); the padding
rows are decoupled +-1 entries and are subtracted.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxhumanoid.solvers.ipm.kkt.assembly import equilibrate_compact
from jaxhumanoid.solvers.ipm.kkt.pivot import choose_pivot, pivot, qd_diag_core, qd_diag_pre
from jaxhumanoid.solvers.ipm.kkt.structure import KKTStructure, static_index, static_index2


class Factor(NamedTuple):
    N: jax.Array  # (S, nb, nb) and (S, nb): the inverses of the pivot blocks D_k of the
    sgn: jax.Array  # equilibrated K as D_k^{-1} = N_k diag(sgn_k) N_k^T, sgn_k = +-1; [0] is
    # the border block's (eliminated last, see ``factor``)
    L: jax.Array  # (S, r, nb) rows b_rows of L_{k+1,k} = B_k D_k^{-1} (the others are
    # zero); [0] is zero (block 0 is the border, see ``factor``)
    npos: jax.Array  # inertia of K (padding removed)
    nneg: jax.Array
    nzero: jax.Array  # numerically zero (or non-finite) eigenvalues: K singular
    d: jax.Array  # (S, nb) symmetric equilibration: the factors are of diag(d) K diag(d)


class _Scaled(NamedTuple):
    A: jax.Array  # (S, nb, nb) equilibrated diagonal blocks
    Bs: jax.Array  # (S, r, c) equilibrated nonzero part B_k[b_rows, b_cols]
    pre: tuple  # ``qd_diag_pre(A, nbx)`` where the diagonal-R fast path applies, else ()


class _Blocks(NamedTuple):
    """The factors of blocks 1..S-1 at their index k; entry 0 is left for the border block (and
    L[0], X[0] stay zero), so that the factor needs no copy into arrays of S entries."""

    N: jax.Array  # (S, nb, nb) pivot factors
    sgn: jax.Array  # (S, nb)
    L: jax.Array  # (S, r, nb) rows b_rows of L_{k+1,k}
    X: jax.Array  # (S, nb, r) border couplings X_k
    info: jax.Array  # (S, 3) [nneg, nzero, path]


class _Loop(NamedTuple):
    k: jax.Array  # () int32, the next block
    C: jax.Array  # (r, r) fill of block k on the rows b_rows
    X: jax.Array  # (nb, r) border coupling X_k
    cnt: jax.Array  # (3,) int64 (npos, nneg, nzero) of the blocks done, padding included
    dead: jax.Array  # () bool: the blocks done rule out inertia (n, m, 0)
    out: _Blocks


def negative_caps(st: KKTStructure) -> np.ndarray:
    """(S,) the most negative eigenvalues the leading blocks 1..k (entry k; padding included) can
    have when K has inertia (n, m, 0), for ``factor``'s early exit.

    Haynsworth: nneg(K) = nneg(H) + nneg(S_H), H the blocks 1..k and S_H its Schur complement in
    K. When every B_j has only primal rows (``b_rows`` < nbx: the constraints of a block act on no
    variable of the block before), the fill of H enters block k+1 on primal rows only, and S_H
    restricted to the blocks k+1..S-1 is a saddle-point matrix [[W', A^T], [A, -D_c]], D_c >= 0,
    whose constraint rows A are those of these blocks (dual padding included). Its quadratic
    form at (x, y) = (-s A^T y, y) is s^2 y^T A W' A^T y - 2 s |A^T y|^2 - y^T D_c y < 0 for small
    s > 0 unless A^T y = 0 = D_c y, so it has at least as many negative eigenvalues as rows
    (Courant-Fischer), or some y != 0 has K [0; y] = 0 and K is singular. Interlacing carries the
    count to S_H, which also holds block 0's decoupled dual padding -1. With nb - nbx dual slots
    per block, m + n_pad_neg = S (nb - nbx), and so

        nneg(H) <= S (nb - nbx) - (S-1-k) (nb - nbx) - (nb - nbx - m_0) = k (nb - nbx) + m_0,

    m_0 the constraints of block 0. Otherwise only nneg(H) <= nneg(K) = m + n_pad_neg holds."""
    total = st.m + st.n_pad_neg
    if st.S == 1 or not np.all(st.b_rows < st.nbx):
        return np.full(st.S, total, np.int64)
    m0 = int(np.sum(st.con_pos // st.nb == 0))
    return np.minimum(np.arange(st.S, dtype=np.int64) * (st.nb - st.nbx) + m0, total)


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


def _skipped(nb, dtype):
    """The entries of a pivot block left by the early exit: no eigenvalues, path 3."""
    return jnp.zeros((nb, nb), dtype), jnp.ones((nb,), dtype), jnp.array([0, 0, 3], jnp.int64)


def _counts(info, nb):
    """(3,) (npos, nneg, nzero) of a pivot block of size nb from its info vector (zero if skipped)."""
    return jnp.stack([nb - info[0] - info[1], info[0], info[1]]) * (info[2] != 3)


def _filled_block(Ak, C, rr):
    """The pivot block D_k = A_k - C on the (b_rows, b_rows) sub-block ``rr``, symmetrised."""
    D_ = Ak.at[rr].add(-C)
    return 0.5 * (D_ + D_.T)


def _eliminate(st: KKTStructure, sc: _Scaled, k, C, X, diag_r, fast, rel_zero_tol):
    """Pivot block k (fill C (r, r) on rows b_rows, border coupling X = X_k (nb, r)).

    Returns (C_{k+1}, X_{k+1}, N_k, sgn_k, rows b_rows of L_{k+1,k} (r, nb), info_k)."""
    nbx, nb = st.nbx, st.nb
    rb, cb = static_index(st.b_rows), static_index(st.b_cols)
    rr = static_index2(st.b_rows, st.b_rows)
    bs = sc.Bs[k]
    if diag_r:
        pb, qt, rd = (v[k] for v in sc.pre)
        Nq, okq = qd_diag_core(pb.at[rr].add(-C), qt, rd)
        Nk, sk, info = choose_pivot(
            okq, Nq, functools.partial(_filled_block, rr=rr), (sc.A[k], C), rel_zero_tol, nb - nbx
        )
    else:
        Nk, sk, info = pivot(_filled_block(sc.A[k], C, rr), nbx, fast, rel_zero_tol)
    Lk = ((bs @ Nk[cb]) * sk) @ Nk.T  # B_k D_k^{-1} on rows b_rows (r x nb)
    Cn = jnp.einsum("ij,kj->ik", Lk[:, cb], bs)  # B_k D_k^{-1} B_k^T (lower part read)
    Xn = jnp.einsum("ar,sr->as", X, Lk[:, rb])  # X_{k+1} = -X_k D_k^{-1} B_k^T
    return Cn, Xn, Nk, sk, Lk, info


def _block_loop(st: KKTStructure, sc: _Scaled, diag_r, fast, rel_zero_tol, early_exit) -> _Loop:
    """Blocks 1..S-1 (S > 1) in a ``lax.while_loop``; with ``early_exit`` it stops once the counts
    of the blocks done rule out inertia (n, m, 0): a zero eigenvalue, more positive ones than
    n (padding included), or more negative ones than ``negative_caps``. The blocks not reached
    keep ``_skipped``'s entries. Returns the final carry."""
    nb, S = st.nb, st.S
    cb = static_index(st.b_cols)
    r_ = st.b_rows.size
    A, Bs = sc.A, sc.Bs
    neg_cap = jnp.asarray(negative_caps(st))
    pos_cap = st.n + st.n_pad_pos

    def decided(cnt, k):
        return (cnt[2] > 0) | (cnt[0] > pos_cap) | (cnt[1] > neg_cap[k])

    X1 = jnp.zeros((r_, nb), A.dtype).at[:, cb].set(Bs[0]).T  # B_0^T: block 0 is the border
    C0 = jnp.zeros((r_, r_), dtype=A.dtype)
    N_s, sg_s, info_s = (jnp.broadcast_to(a, (S,) + a.shape) for a in _skipped(nb, A.dtype))
    out = _Blocks(N=N_s, sgn=sg_s, L=jnp.zeros((S, r_, nb), A.dtype), X=jnp.zeros((S, nb, r_), A.dtype), info=info_s)

    def go_on(c):
        return (c.k < S) & ~_all_true(c.dead) if early_exit else c.k < S

    def step(c):
        k = c.k
        Cn, Xn, Nk, sk, Lk, info = _eliminate(st, sc, k, c.C, c.X, diag_r, fast, rel_zero_tol)
        new = _Blocks(N=Nk, sgn=sk, L=Lk, X=c.X, info=info)
        out = jax.tree.map(lambda o, v: o.at[k].set(v), c.out, new)
        cnt = c.cnt + _counts(info, nb)
        return _Loop(k=k + 1, C=Cn, X=Xn, cnt=cnt, dead=c.dead | (early_exit & decided(cnt, k)), out=out)

    init = _Loop(k=jnp.ones((), jnp.int32), C=C0, X=X1, cnt=jnp.zeros(3, jnp.int64), dead=jnp.zeros((), bool), out=out)
    return lax.while_loop(go_on, step, init)


def _border_schur(st: KKTStructure, A0, blocks: _Blocks):
    """D_0 = A_0 - sum_{k>=1} X_k D_k^{-1} X_k^T (nb, nb), with D_k^{-1} read on (b_rows, b_rows)."""
    rb = static_index(st.b_rows)
    XN = jnp.einsum("kar,krj->kaj", blocks.X[1:], blocks.N[1:, rb])
    Z = jnp.einsum("kaj,kj,kbj->ab", XN, blocks.sgn[1:], XN)  # sum_k X_k D_k^{-1}[rb, rb] X_k^T
    return A0 - Z


@functools.partial(jax.jit, static_argnames=("st", "rel_zero_tol", "fast", "early_exit"))
def _factor(st: KKTStructure, A, B, rel_zero_tol, fast, early_exit=False):
    """(Factor, pivot paths (S,) int32) of K = (A, B); see ``factor``. Jitted with the structure
    static (hashed by identity): repeated calls, and the several call sites in one IPM trace,
    reuse one traced and compiled factorisation."""
    d, A, Bs = equilibrate_compact(st, A, B)  # Bs: (S, r, c) nonzero part of the B_k
    if rel_zero_tol is None:
        rel_zero_tol = 10.0 * st.nb * float(np.finfo(np.float64).eps)
    nbx, nb, S = st.nbx, st.nb, st.S
    # the fill of blocks 1.. reaches only rows b_rows; if those are all primal and the (2,2)
    # block of K is diagonal, the dual part of their pivot blocks is the diagonal -D_c and the fast
    # path's fill-independent work is done for all blocks at once, outside the loop
    diag_r = fast and st.dual_diagonal and 0 < nbx < nb and bool(np.all(st.b_rows < nbx))
    sc = _Scaled(A, Bs, qd_diag_pre(A, nbx) if diag_r else ())
    cnt, dead = jnp.zeros(3, jnp.int64), jnp.zeros((), bool)
    if S > 1:
        c = _block_loop(st, sc, diag_r, fast, rel_zero_tol, early_exit)
        cnt, dead, blocks = c.cnt, c.dead, c.out
        D0 = _border_schur(st, A[0], blocks)
    else:
        D0 = A[0]
    D0 = 0.5 * (D0 + D0.T)

    def border():
        return pivot(D0, nbx, fast, rel_zero_tol)

    # ``dead`` already holds the decision on blocks 1..S-1
    skipped = functools.partial(_skipped, nb, A.dtype)
    N0, sg0, info0 = lax.cond(_all_true(dead), skipped, border) if early_exit else border()
    npos, nneg, nzero = cnt + _counts(info0, nb)
    r_ = st.b_rows.size
    if S > 1:
        Nf, sg = blocks.N.at[0].set(N0), blocks.sgn.at[0].set(sg0)
        L = blocks.L  # L[0] = 0: block 0 is the border
        paths = blocks.info[:, 2].at[0].set(info0[2]).astype(jnp.int32)
    else:
        Nf, sg, L = N0[None], sg0[None], jnp.zeros((1, r_, nb), A.dtype)
        paths = info0[None, 2].astype(jnp.int32)
    fac = Factor(N=Nf, sgn=sg, L=L, npos=npos - st.n_pad_pos, nneg=nneg - st.n_pad_neg, nzero=nzero, d=d)
    return fac, paths


def factor(
    st: KKTStructure, A, B, rel_zero_tol: float | None = None, fast: bool = True, early_exit: bool = False
) -> Factor:
    """Block LDL^T of K = (A, B) (each (S, nb, nb)) with the exact inertia of K.

    K is first equilibrated. The blocks are eliminated in the order 1, 2, ..., S-1 and then 0:
    block 0 is a border (arrowhead elimination), coupled to the others only through the fill
    X_k that it receives as they are eliminated (module docstring), and inertia(K) =
    sum_k inertia(D_k) (Sylvester). Each pivot block is first tried on the quasi-definite fast
    path (Cholesky factorisations only); blocks where it fails are eigen-decomposed, so the
    inertia is exact in both cases (``pivot``). ``fast=False`` eigen-decomposes every block.
    ``rel_zero_tol`` (default 10 nb eps): eigenvalues below it relative to the block's largest
    count as zero.

    ``early_exit``: stop eliminating (the block loop ends; pivot path 3 for the blocks left) as
    soon as the blocks done so far show that the inertia is not (n, m, 0): a zero eigenvalue,
    more positive ones than n, or more negative ones than those blocks can hold
    (``negative_caps``). The counts are then those of the blocks done, which decide the IPM's
    inertia correction (``inertia_ok`` false; ``nzero > 0`` when the deciding block was
    singular), and the factor must not be used to solve. A trial with inertia (n, m, 0) is
    factored exactly as without the exit.
    """
    return _factor(st, A, B, rel_zero_tol=rel_zero_tol, fast=fast, early_exit=early_exit)[0]


def pivot_paths(st: KKTStructure, A, B, fast: bool = True, early_exit: bool = False):
    """(S,) how each pivot block was factored: 0 quasi-definite (Cholesky), 2 eigendecomposition,
    3 skipped (``early_exit``). Entry 0 is the border block. For diagnostics and benchmarks."""
    return _factor(st, A, B, rel_zero_tol=None, fast=fast, early_exit=early_exit)[1]


def inertia_ok(st: KKTStructure, fac: Factor):
    """True where K has inertia (n, m, 0), as required by Algorithm IC of the IPOPT paper."""
    return (fac.npos == st.n) & (fac.nneg == st.m) & (fac.nzero == 0)
