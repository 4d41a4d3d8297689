"""Static block layout of the KKT matrix: stage ordering, padding and scatter targets (numpy).

The unknowns ``[x; y]`` (n variables, m constraint multipliers) are ordered stage by stage,
``[x_0, y_0, x_1, y_1, ...]`` after ``NLP.var_stage`` / ``NLP.con_stage``, and every stage is
padded to a common block size ``nb = nbx + nbc`` laid out as

    [ variables, primal padding (nbx) | constraints, dual padding (nbc) ],

nbx (nbc) the most variables (constraints) of any stage. K is then block-tridiagonal with S
diagonal blocks A_k (nb x nb) and sub-diagonal blocks B_k = K[stage k+1, stage k]. A padded row
is a decoupled diagonal entry +1 (primal part) or -1 (dual part): one eigenvalue of known sign.
"""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class KKTStructure:
    """Static scatter maps from NLP sparsity patterns to the padded block-tridiagonal layout.

    Flat targets index the concatenation ``[A.ravel(), B.ravel(), trash]`` of the diagonal blocks
    A (S, nb, nb), sub-diagonal blocks B (S, nb, nb; B[S-1] stays zero) and one trash slot.
    Hashed by identity (``eq=False``): it is a static argument of the jitted factorisation and
    solve, so one structure object means one compiled program.
    """

    n: int
    m: int
    S: int
    nb: int
    var_pos: np.ndarray  # (n,) position of variable i in the stage-ordered vector (S*nb)
    con_pos: np.ndarray  # (m,) position of constraint multiplier j
    pad_pos: np.ndarray  # (n_pad,) padding positions
    pad_sign: np.ndarray  # (n_pad,) +1 for padding in the primal part, -1 in the dual part
    nbx: int  # primal part of every block: local positions [0, nbx)
    hess_t1: np.ndarray  # (nnz_h,) flat target of K[r, c] for hessian entry (r, c)
    hess_t2: np.ndarray  # (nnz_h,) flat target of the mirrored entry K[c, r] (or trash)
    jac_t1: np.ndarray  # (nnz_j,) flat target of K[y_j, x_i]
    jac_t2: np.ndarray  # (nnz_j,) flat target of K[x_i, y_j] (or trash)
    var_diag_t: np.ndarray  # (n,) flat target of K[x_i, x_i]
    con_diag_t: np.ndarray  # (m,) flat target of K[y_j, y_j]
    pad_diag_t: np.ndarray  # (n_pad,)
    b_rows: np.ndarray  # (r,) local rows that are structurally nonzero in some B_k (sorted)
    b_cols: np.ndarray  # (c,) local columns that are structurally nonzero in some B_k
    # the (2,2) block of K is diagonal (-D_c): true of an NLP's KKT matrix, not of a condensed one
    dual_diagonal: bool = True

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


def _orient(vs, cs, S, order):
    """Stage ids and (S,) counts of variables / constraints per block, with the stage chain
    reversed where ``order`` asks for it (see ``build_structure``)."""
    nvar = np.bincount(vs, minlength=S)
    ncon = np.bincount(cs, minlength=S)
    if order == "backward" or (order == "auto" and nvar[-1] - ncon[-1] < nvar[0] - ncon[0]):
        vs, cs = S - 1 - vs, S - 1 - cs
        nvar, ncon = nvar[::-1], ncon[::-1]
    return vs, cs, nvar, ncon


def _local_layout(vs, cs, S, nbx, nb):
    """Local positions in a block [variables, primal padding | constraints, dual padding].

    Returns var_loc (n,), con_loc (m,), and for the padding rows pad_stage, pad_loc and pad_sign
    (n_pad,): primal padding of all blocks first, then dual padding."""
    var_loc = np.zeros(vs.size, np.int64)
    con_loc = np.zeros(cs.size, np.int64)
    fx = np.zeros(S, np.int64)
    fc = np.zeros(S, np.int64)
    for i in range(vs.size):
        var_loc[i] = fx[vs[i]]
        fx[vs[i]] += 1
    for j in range(cs.size):
        con_loc[j] = nbx + fc[cs[j]]
        fc[cs[j]] += 1
    nbc = nb - nbx
    pad_stage = np.concatenate(
        [np.full(nbx - fx[k], k) for k in range(S)] + [np.full(nbc - fc[k], k) for k in range(S)]
    ).astype(np.int64)
    pad_loc = np.concatenate(
        [np.arange(fx[k], nbx) for k in range(S)] + [np.arange(nbx + fc[k], nb) for k in range(S)]
    ).astype(np.int64)
    pad_sign = np.concatenate([np.ones(int(np.sum(nbx - fx)))] + [-np.ones(int(np.sum(nbc - fc)))])
    return var_loc, con_loc, pad_stage, pad_loc, pad_sign


def _scatter_target(S, nb, sr, lr, sc, lc):
    """Flat target of K[(sr, lr), (sc, lc)] (stage, local position of row and column) where it is
    stored: in A_sr if sr == sc, in B_sc if sr == sc + 1; else the trash slot (the upper part
    across stages, which K holds only as B^T). Raises ValueError for |sr - sc| > 1."""
    nbb = nb * nb
    off_b = S * nbb
    trash = 2 * S * nbb
    sr, lr, sc, lc = map(np.asarray, (sr, lr, sc, lc))
    t = np.full(sr.shape, trash, np.int64)
    same = sr == sc
    t[same] = sr[same] * nbb + lr[same] * nb + lc[same]
    below = sr == sc + 1
    t[below] = off_b + sc[below] * nbb + lr[below] * nb + lc[below]
    if np.any(np.abs(sr - sc) > 1):
        raise ValueError(
            "KKT structure: an entry couples stages more than one apart; the "
            "stage-ordered KKT matrix must be block-tridiagonal"
        )
    return t


def _coupling_support(targets, S, nb):
    """Sorted local rows and columns holding a structural nonzero of some B_k, from the flat
    targets of all entries; the Schur update B_k D_k^{-1} B_k^T needs only those."""
    nbb = nb * nb
    off_b = S * nbb
    tb = np.concatenate(targets)
    tb = tb[(tb >= off_b) & (tb < 2 * S * nbb)] - off_b
    b_rows = np.unique((tb % nbb) // nb).astype(np.int64)
    b_cols = np.unique(tb % nb).astype(np.int64)
    if b_rows.size == 0:
        b_rows = b_cols = np.zeros(1, np.int64)
    return b_rows, b_cols


def build_structure(
    n, m, var_stage, con_stage, hess_rows, hess_cols, jac_rows, jac_cols, order: str = "auto"
) -> KKTStructure:
    """Precompute (numpy, once per NLP) the block layout and all scatter targets.

    ``order``: which end of the stage chain becomes block 0, the border block that is eliminated
    last (arrowhead order 1, 2, ..., S-1, 0, see ``elimination.factor``), so it receives the
    Schur complements of all other blocks. "auto" puts there the end stage whose variables fall
    shortest of its constraints: a block whose equality rows outnumber its variables is singular
    on its own although K is not (a fixed initial state: interval 0's rows act on stage 1's
    variables). "forward" keeps stage 0 first, "backward" reverses the stages.
    ``hess_rows``/``hess_cols`` describe the lower triangle of W.
    Raises ValueError on inconsistent sizes, an unknown ``order``, an upper-triangle Hessian
    entry, or an entry coupling stages more than one apart (K not block-tridiagonal).
    """
    var_stage = np.asarray(var_stage, dtype=np.int64).reshape(-1)
    con_stage = np.asarray(con_stage, dtype=np.int64).reshape(-1)
    if var_stage.size != n or con_stage.size != m:
        raise ValueError(f"var_stage/con_stage must have sizes n={n}, m={m}, got {var_stage.size}, {con_stage.size}")
    if order not in ("auto", "forward", "backward"):
        raise ValueError(f"order must be 'auto', 'forward' or 'backward', got {order!r}")
    vs, cs, S = _compress_stages(var_stage, con_stage) if n + m else (var_stage, con_stage, 1)
    vs, cs, nvar, ncon = _orient(vs, cs, S, order)
    # the static split nbx = max_k n_k lets the fast pivot path factor the primal part first
    nbx = int(nvar.max()) if n else 0
    nbc = int(ncon.max()) if m else 0
    if nbx + nbc == 0:
        nbx = 1
    nb = nbx + nbc
    var_loc, con_loc, pad_stage, pad_loc, pad_sign = _local_layout(vs, cs, S, nbx, nb)
    trash = 2 * S * nb * nb

    hr = np.asarray(hess_rows, np.int64)
    hc = np.asarray(hess_cols, np.int64)
    if np.any(hr < hc):
        raise ValueError("NLP.hess_rows/hess_cols must describe the lower triangle (row >= col)")
    h1 = _scatter_target(S, nb, vs[hr], var_loc[hr], vs[hc], var_loc[hc])
    h2 = _scatter_target(S, nb, vs[hc], var_loc[hc], vs[hr], var_loc[hr])
    h2 = np.where(hr == hc, trash, h2)
    jr = np.asarray(jac_rows, np.int64)
    jc = np.asarray(jac_cols, np.int64)
    # of (t1, t2) exactly the stored ones are kept; for cross-stage entries one is trash
    j1 = _scatter_target(S, nb, cs[jr], con_loc[jr], vs[jc], var_loc[jc])
    j2 = _scatter_target(S, nb, vs[jc], var_loc[jc], cs[jr], con_loc[jr])
    b_rows, b_cols = _coupling_support([h1, h2, j1, j2], S, nb)
    nbb = nb * nb
    return KKTStructure(
        n=n,
        m=m,
        S=S,
        nb=nb,
        var_pos=vs * nb + var_loc,
        con_pos=cs * nb + con_loc,
        pad_pos=pad_stage * nb + pad_loc,
        pad_sign=pad_sign,
        nbx=nbx,
        hess_t1=h1,
        hess_t2=h2,
        jac_t1=j1,
        jac_t2=j2,
        var_diag_t=vs * nbb + var_loc * (nb + 1),
        con_diag_t=cs * nbb + con_loc * (nb + 1),
        pad_diag_t=pad_stage * nbb + pad_loc * (nb + 1),
        b_rows=b_rows,
        b_cols=b_cols,
    )


_CACHE_KEY = ("solvers.ipm.kkt", "structure")


def structure_of(nlp) -> KKTStructure:
    """KKTStructure of an ``NLP``, kept in ``nlp.cache``: one object per NLP, so that the jitted
    factorisation and solve (static in the structure, hashed by identity) compile once."""
    if _CACHE_KEY not in nlp.cache:
        nlp.cache[_CACHE_KEY] = build_structure(
            nlp.n, nlp.m, nlp.var_stage, nlp.con_stage, nlp.hess_rows, nlp.hess_cols, nlp.jac_rows, nlp.jac_cols
        )
    return nlp.cache[_CACHE_KEY]


def static_index(ix):
    """A static slice for a contiguous index range (XLA:CPU: slices instead of gathers and
    scatters inside the loops), else the index array."""
    ix = np.asarray(ix)
    if ix.size and np.array_equal(ix, np.arange(ix[0], ix[0] + ix.size)):
        return slice(int(ix[0]), int(ix[0]) + int(ix.size))
    return ix


def static_index2(a, b):
    """The (a, b) sub-block index: a pair of slices where both ranges are contiguous, else
    ``np.ix_``."""
    sa, sb = static_index(a), static_index(b)
    if isinstance(sa, slice) and isinstance(sb, slice):
        return sa, sb
    return np.ix_(np.asarray(a), np.asarray(b))
