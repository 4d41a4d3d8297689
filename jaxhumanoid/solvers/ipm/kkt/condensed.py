"""Condensed KKT solve: each stage's local unknowns eliminated first (all stages at once), then
the block recursion of ``elimination`` over the unknowns that link the stages.

The block LDL^T factors one pivot block of all nb unknowns of a stage after the other. Most of a
stage's unknowns are local to it: for the humanoid, the contact forces f_k, the rows of their
law (3)-(4), the steady-foot rows (5) and the clearance rows. The unknowns of stage k (variables
and constraint multipliers) are split into

    U_k, kept: those coupled to stage k-1 (the node state q_k, qd_k; u_k through the torque-rate
        term of (7)), and the rows that no local variable can be paired with (the dynamics (6),
        the inequality rows);
    I_k, interior: the rest.

An unknown of stage k+1 coupled to stage k is in U_{k+1}, so I_k couples only with U_k and
U_{k+1}. With C_k = K[(U_k, U_{k+1}), I_k] (2 nU x nI) and D_k = K[I_k, I_k] (nI x nI),

    K_U = K[U, U] - sum_k C_k D_k^{-1} C_k^T

is again block tridiagonal, on blocks of nU < nb unknowns. The D_k are factored as one batch
(``pivot``'s Cholesky-certified fast path, eigendecomposition where it fails), K_U by
``elimination`` (arrowhead order, inertia read off the recursion), and by Haynsworth's additivity

    inertia(K) = sum_k inertia(D_k) + inertia(K_U)

the inertia is exact. A row is interior only where a greedy structural matching pairs it with an
interior variable of its stage, so that D_k stays regular however small its diagonal: an
equality row has none (or delta_c), and an inequality row's pivot -1/Sigma_s vanishes as it
becomes active. Eliminating such a row through its pivot alone would pass 1/Sigma_s-sized fill to
K_U and lose every digit of the inertia there (measured on the humanoid's KKT matrices). For the
humanoid, the interior is the contact forces and the rows of their law (unit-triangular in f),
and U_k the node state, the torques, the dynamics rows (6) and the inequality rows. Both systems
are Ruiz-equilibrated (K first, then K_U), and solves are refined against the full K.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxhumanoid.solvers.ipm.kkt.assembly import equilibrate_compact, from_blocks, matvec_compact, to_blocks
from jaxhumanoid.solvers.ipm.kkt.elimination import Factor, _all_true, _factor
from jaxhumanoid.solvers.ipm.kkt.pivot import apply_inv, eigen_pivot, quasidefinite_block
from jaxhumanoid.solvers.ipm.kkt.structure import KKTStructure, _compress_stages, build_structure, structure_of
from jaxhumanoid.solvers.ipm.kkt.substitution import border_coupling, refine, solve_vec


@dataclasses.dataclass(frozen=True, eq=False)
class CondensedStructure:
    """Static maps of the condensed solve (numpy, once per NLP).

    Unknowns are numbered as v = [x; y] (n + m); id n + m is a zero slot (padding). Interior
    blocks are laid out [variables, +1 padding | constraints, -1 padding] (nIx + nIc), kept
    blocks in the layout of ``red``. Hashed by identity:
    a static argument of the jitted factorisation and solve."""

    st: KKTStructure  # the full KKT matrix's block layout (input blocks, refinement)
    red: KKTStructure  # the reduced matrix K_U's block layout (dual part not diagonal)
    nIx: int
    I_ids: np.ndarray  # (S, nI) unknown ids of the interior blocks, stage order (n + m: padding)
    I_pad: np.ndarray  # (S, nI) +1 / -1 on padding slots, 0 elsewhere
    U_ids: np.ndarray  # (S, nU) unknown ids of the kept blocks in ``red``'s local order, stage order
    reversed: bool  # ``red`` orders the stages backwards (block b = stage S-1-b)
    g_DI: np.ndarray  # (S, nI, nI) flat gather indices into the equilibrated full K (see _gather)
    g_CI: np.ndarray  # (S, 2 nU, nI)
    g_AU: np.ndarray  # (S, nU, nU)
    g_BU: np.ndarray  # (S, nU, nU) K[U_{k+1}, U_k]
    v_pos: np.ndarray  # (n + m,) position of each unknown in the full layout (S nb)

    @property
    def n(self) -> int:
        return self.st.n

    @property
    def m(self) -> int:
        return self.st.m

    @property
    def S(self) -> int:
        return self.st.S

    @property
    def nI(self) -> int:
        return int(self.I_ids.shape[1])

    @property
    def nU(self) -> int:
        return self.red.nb


class CondensedFactor(NamedTuple):
    NI: jax.Array  # (S, nI, nI) and (S, nI): D_k^{-1} = NI_k diag(sI_k) NI_k^T, stage order
    sI: jax.Array
    CI: jax.Array  # (S, 2 nU, nI) equilibrated couplings C_k
    red: Factor  # block LDL^T of K_U (its own equilibration inside)
    BU: jax.Array  # (S, nU, nU) sub-diagonal blocks of K_U in ``red``'s layout, before its equilibration
    dv: jax.Array  # (n + m,) equilibration of the unknowns: the factors are of diag(dv) K diag(dv)
    npos: jax.Array  # inertia of K
    nneg: jax.Array
    nzero: jax.Array


def coupled(n, m, stage, hess_rows, hess_cols, jac_rows, jac_cols, step: int = -1) -> np.ndarray:
    """(n + m,) True for the unknowns of v = [x; y] with a KKT entry that couples them to an
    unknown of the stage ``step`` away (-1: the stage before, +1: the next). ``stage`` (n + m,)."""
    off = hess_rows != hess_cols
    a = np.concatenate([hess_rows[off], n + jac_rows])
    b = np.concatenate([hess_cols[off], jac_cols])
    out = np.zeros(n + m, bool)
    out[a[stage[a] == stage[b] - step]] = True
    out[b[stage[b] == stage[a] - step]] = True
    return out


def common_roles(stage_of: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``mask`` (over variables, or over rows, with their stages ``stage_of``) extended to every
    member of the same role: among the stages of the most common size, the i-th unknown of each
    stage plays one role (the transcription numbers a stage's unknowns alike), and a role the
    mask marks in most of them is marked in all of them. An end stage whose neighbour is fixed
    (no torque-rate coupling to a fixed u_0, say) then keeps what the others keep, and all
    interior blocks have one size."""
    if stage_of.size == 0:
        return mask
    count = np.bincount(stage_of)
    size = np.bincount(count[count > 0]).argmax()
    order = np.argsort(stage_of, kind="stable")
    loc = np.empty_like(order)
    loc[order] = np.arange(order.size) - np.repeat(np.cumsum(count) - count, count)
    common = count[stage_of] == size
    votes = np.bincount(loc[common], weights=mask[common], minlength=size) / np.sum(count == size)
    return mask | (common & (votes[np.minimum(loc, size - 1)] > 0.5))


def interior_mask(n, m, stage, keep, jac_rows, jac_cols) -> np.ndarray:
    """(n + m,) True for the unknowns of v = [x; y] that are interior to their stage: not to be
    kept (``keep``: those coupled to the stage before, and more), and, for a row, paired by a
    greedy structural matching (rows with the fewest candidates first) with an interior variable
    of its own stage."""
    inner = ~keep
    sel = inner[n + jac_rows] & inner[jac_cols] & (stage[n + jac_rows] == stage[jac_cols])
    cands: dict[int, list[int]] = {}
    for j, i in zip(jac_rows[sel].tolist(), jac_cols[sel].tolist()):
        cands.setdefault(j, []).append(i)
    rows = sorted(np.nonzero(inner[n:])[0].tolist(), key=lambda j: (len(cands.get(j, ())), j))
    used: set[int] = set()
    for j in rows:
        free = [i for i in cands.get(j, ()) if i not in used]
        if free:
            used.add(min(free))
        else:
            inner[n + j] = False
    return inner


def _gather(st: KKTStructure, v_pos, r_ids, c_ids):
    """Flat indices of K[r, c] (unknown ids, broadcast together) into
    [A.ravel(), B compact (S, r, c) .ravel(), 0] of ``equilibrate_compact``'s output; the zero
    slot where an id is padding or the entry lies outside the stored pattern."""
    S, nb = st.S, st.nb
    nbb = nb * nb
    nr, nc = st.b_rows.size, st.b_cols.size
    zero = S * nbb + S * nr * nc
    row_of = np.full(nb, -1)
    row_of[st.b_rows] = np.arange(nr)
    col_of = np.full(nb, -1)
    col_of[st.b_cols] = np.arange(nc)
    pad = np.append(v_pos, -1)
    pr, pc = np.broadcast_arrays(pad[r_ids], pad[c_ids])
    br, lr, bc, lc = pr // nb, pr % nb, pc // nb, pc % nb
    out = np.full(pr.shape, zero, np.int64)
    same = (br == bc) & (pr >= 0) & (pc >= 0)
    out[same] = br[same] * nbb + lr[same] * nb + lc[same]
    for lo, hi, llo, lhi in ((br, bc, lr, lc), (bc, br, lc, lr)):  # K[r, c] = B_{hi}[lo-row, hi-col]
        below = (lo == hi + 1) & (pr >= 0) & (pc >= 0)
        ri, ci = row_of[llo[below]], col_of[lhi[below]]
        ok = (ri >= 0) & (ci >= 0)
        tgt = np.full(ri.shape, zero, np.int64)
        tgt[ok] = S * nbb + (hi[below][ok] * nr + ri[ok]) * nc + ci[ok]
        out[below] = tgt
    return out


def _blocks_of(ids_by_stage: list[np.ndarray], width: int, fill: int) -> np.ndarray:
    out = np.full((len(ids_by_stage), width), fill, np.int64)
    for k, ids in enumerate(ids_by_stage):
        out[k, : ids.size] = ids
    return out


def build_condensed(
    n, m, var_stage, con_stage, hess_rows, hess_cols, jac_rows, jac_cols, st: KKTStructure | None = None
) -> CondensedStructure:
    """The condensed structure of an NLP's KKT matrix (numpy, once per NLP); ``st``: the full
    matrix's block layout where it is built already (``structure_of``)."""
    hr, hc, jr, jc = (np.asarray(a, np.int64).reshape(-1) for a in (hess_rows, hess_cols, jac_rows, jac_cols))
    if st is None:
        st = build_structure(n, m, var_stage, con_stage, hr, hc, jr, jc)
    vs, cs, S = _compress_stages(var_stage, con_stage)
    stage = np.concatenate([vs, cs])
    back = coupled(n, m, stage, hr, hc, jr, jc, -1)
    keep = np.concatenate([common_roles(vs, back[:n]), common_roles(cs, back[n:])])
    inner = interior_mask(n, m, stage, keep, jr, jc)
    empty = np.bincount(stage[~inner], minlength=S) == 0
    if np.any(empty):  # such a stage (the first, say) keeps its unknowns coupled to the next one
        fwd = coupled(n, m, stage, hr, hc, jr, jc, +1)
        inner = interior_mask(n, m, stage, keep | (empty[stage] & fwd), jr, jc)
        lone = np.bincount(stage[~inner], minlength=S) == 0
        inner &= ~lone[stage]  # a stage coupled to no other (a single stage) keeps everything
    ids = np.arange(n + m)
    # the reduced system: kept variables and rows, numbered in order; its own block layout
    uv, uc = ids[:n][~inner[:n]], ids[n:][~inner[n:]] - n
    red = build_structure(uv.size, uc.size, vs[uv], cs[uc], np.arange(uv.size), np.arange(uv.size), [], [])
    nU = red.nb
    u_ids = np.concatenate([uv, n + uc])
    u_pos = np.concatenate([red.var_pos, red.con_pos])
    reversed_ = bool(u_pos[stage[u_ids] == 0][0] // nU != 0)  # stage 0 is not block 0
    U_ids = np.full((S, nU), n + m, np.int64)
    U_ids[stage[u_ids], u_pos % nU] = u_ids
    # interior blocks [variables | constraints], padded
    Ix = [ids[:n][inner[:n] & (vs == k)] for k in range(S)]
    Ic = [ids[n:][inner[n:] & (cs == k)] for k in range(S)]
    nIx, nIc = max(a.size for a in Ix), max(a.size for a in Ic)
    I_ids = np.concatenate([_blocks_of(Ix, nIx, n + m), _blocks_of(Ic, nIc, n + m)], axis=1)
    I_pad = np.where(I_ids == n + m, np.where(np.arange(nIx + nIc) < nIx, 1.0, -1.0), 0.0)
    # the reduced sub-diagonal blocks: rows of the later stage coupled to the earlier one
    # (the fill of I_k reaches U_{k+1} only on unknowns coupled to stage k: back-coupled ones)
    b_rows = np.unique(np.nonzero(np.append(back, False)[U_ids[1:]])[1]) if not reversed_ else np.arange(nU)
    red = dataclasses.replace(
        red, b_rows=b_rows if b_rows.size else np.zeros(1, np.int64), b_cols=np.arange(nU), dual_diagonal=False
    )
    v_pos = np.concatenate([st.var_pos, st.con_pos])
    UU = np.concatenate([U_ids, np.vstack([U_ids[1:], np.full((1, nU), n + m)])], axis=1)  # (U_k, U_{k+1})
    return CondensedStructure(
        st=st,
        red=red,
        nIx=nIx,
        I_ids=I_ids,
        I_pad=I_pad,
        U_ids=U_ids,
        reversed=reversed_,
        g_DI=_gather(st, v_pos, I_ids[:, :, None], I_ids[:, None, :]),
        g_CI=_gather(st, v_pos, UU[:, :, None], I_ids[:, None, :]),
        g_AU=_gather(st, v_pos, U_ids[:, :, None], U_ids[:, None, :]),
        g_BU=_gather(st, v_pos, UU[:, nU:, None], U_ids[:, None, :]),
        v_pos=v_pos,
    )


def condensed_structure_of(nlp) -> CondensedStructure:
    """``build_condensed`` of an NLP, kept in ``nlp.cache`` (one object, one compiled program)."""
    key = ("solvers.ipm.kkt", "condensed")
    if key not in nlp.cache:
        st = structure_of(nlp)
        nlp.cache[key] = build_condensed(
            st.n, st.m, nlp.var_stage, nlp.con_stage, nlp.hess_rows, nlp.hess_cols, nlp.jac_rows, nlp.jac_cols, st
        )
    return nlp.cache[key]


def _orient(cst: CondensedStructure, a):
    """Stage order -> ``red``'s block order (and back: the map is an involution)."""
    return a[::-1] if cst.reversed else a


def _reduced_blocks(cst: CondensedStructure, AU, BU_stage, F):
    """K_U's blocks in ``red``'s layout from K[U_k, U_k] (S, nU, nU), K[U_{k+1}, U_k] and the
    fill F_k = C_k D_k^{-1} C_k^T (S, 2 nU, 2 nU), all in stage order."""
    nU = cst.nU
    A = AU - F[:, :nU, :nU]
    A = A.at[1:].add(-F[:-1, nU:, nU:])
    Bs = BU_stage - F[:, nU:, :nU]  # stage k+1 rows, stage k columns; [S-1] is zero
    if cst.reversed:  # block b couples block b+1 = stage S-2-b (rows) with stage S-1-b
        Bs = jnp.concatenate([jnp.swapaxes(Bs[:-1], 1, 2)[::-1], jnp.zeros_like(Bs[:1])], axis=0)
    flat = A[::-1].reshape(-1) if cst.reversed else A.reshape(-1)
    flat = flat.at[cst.red.pad_diag_t].add(jnp.asarray(cst.red.pad_sign))
    return flat.reshape(A.shape), Bs


def _local_pivots(DI, nIx, fast, tol):
    """``pivot`` of every local block D_k (S, nI, nI) at once: the quasi-definite fast path for
    all, and, unless every block (of every member of a ``vmap`` batch) took it, the
    eigendecomposition for all, kept where the fast path failed. (``pivot``'s own batching rule
    does not nest inside an outer ``vmap``.)"""
    S, nI = DI.shape[0], DI.shape[1]
    info_fast = jnp.broadcast_to(jnp.array([nI - nIx, 0, 0], jnp.int64), (S, 3))
    sgn_fast = jnp.broadcast_to(jnp.concatenate([jnp.ones(nIx), -jnp.ones(nI - nIx)]), (S, nI))
    eigen = jax.vmap(lambda D_: eigen_pivot(D_, tol))
    if not (fast and nIx > 0):
        return eigen(DI)
    Nq, ok = jax.vmap(lambda D_: quasidefinite_block(D_, nIx))(DI)

    def mixed():
        Ne, se, ie = eigen(DI)
        return (
            jnp.where(ok[:, None, None], Nq, Ne),
            jnp.where(ok[:, None], sgn_fast, se),
            jnp.where(ok[:, None], info_fast, ie),
        )

    return lax.cond(_all_true(jnp.all(ok)), lambda: (Nq, sgn_fast, info_fast), mixed)


class LocalElimination(NamedTuple):
    NI: jax.Array  # (S, nI, nI), (S, nI): D_k^{-1} = NI_k diag(sI_k) NI_k^T, stage order
    sI: jax.Array
    info: jax.Array  # (S, 3) [nneg, nzero, path] of each D_k (``pivot``)
    CI: jax.Array  # (S, 2 nU, nI) equilibrated couplings C_k
    A_red: jax.Array  # (S, nU, nU) K_U's diagonal and sub-diagonal blocks in ``red``'s layout
    B_red: jax.Array
    dv: jax.Array  # (n + m,) equilibration of the unknowns


@functools.partial(jax.jit, static_argnames=("cst", "rel_zero_tol", "fast"))
def eliminate_local(cst: CondensedStructure, A, B, rel_zero_tol=None, fast=True) -> LocalElimination:
    """The first step of ``factor``: K equilibrated, every stage's D_k factored (one batch) and
    K_U = K[U, U] - sum_k C_k D_k^{-1} C_k^T formed."""
    d, As, Bc = equilibrate_compact(cst.st, A, B)
    flat = jnp.concatenate([As.reshape(-1), Bc.reshape(-1), jnp.zeros(1, As.dtype)])
    tol_I = 10.0 * cst.nI * float(np.finfo(np.float64).eps) if rel_zero_tol is None else rel_zero_tol
    DI = flat[cst.g_DI] + jnp.asarray(cst.I_pad)[:, :, None] * jnp.eye(cst.nI)
    CI = flat[cst.g_CI]
    if cst.nI:
        NI, sI, info = _local_pivots(0.5 * (DI + jnp.swapaxes(DI, 1, 2)), cst.nIx, fast, tol_I)
    else:  # nothing local to eliminate: K_U is K
        NI, sI, info = DI, jnp.zeros((cst.S, 0), As.dtype), jnp.zeros((cst.S, 3), jnp.int64)
    CN = jnp.einsum("kun,kni->kui", CI, NI)
    F = jnp.einsum("kui,ki,kvi->kuv", CN, sI, CN)
    A_red, B_red = _reduced_blocks(cst, flat[cst.g_AU], flat[cst.g_BU], F)
    return LocalElimination(NI=NI, sI=sI, info=info, CI=CI, A_red=A_red, B_red=B_red, dv=d.reshape(-1)[cst.v_pos])


@functools.partial(jax.jit, static_argnames=("cst", "rel_zero_tol", "fast"))
def _factor_condensed(cst: CondensedStructure, A, B, rel_zero_tol=None, fast=True):
    loc = eliminate_local(cst, A, B, rel_zero_tol, fast)
    red, _ = _factor(cst.red, loc.A_red, loc.B_red, rel_zero_tol, fast)
    n_pos_pad = int(np.sum(cst.I_pad > 0))
    n_neg_pad = int(np.sum(cst.I_pad < 0))
    nneg_I = jnp.sum(loc.info[:, 0]) - n_neg_pad
    nzero_I = jnp.sum(loc.info[:, 1])
    npos_I = cst.S * cst.nI - jnp.sum(loc.info[:, 0]) - nzero_I - n_pos_pad
    return CondensedFactor(
        NI=loc.NI,
        sI=loc.sI,
        CI=loc.CI,
        red=red,
        BU=loc.B_red,
        dv=loc.dv,
        npos=red.npos + npos_I,
        nneg=red.nneg + nneg_I,
        nzero=red.nzero + nzero_I,
    )


def factor(cst: CondensedStructure, A, B, rel_zero_tol: float | None = None, fast: bool = True) -> CondensedFactor:
    """Condensed factorisation of K = (A, B) (the full layout ``cst.st``, each (S, nb, nb)) with
    the exact inertia of K in ``npos``, ``nneg``, ``nzero`` (``elimination.inertia_ok`` applies).
    ``fast``, ``rel_zero_tol``: as in ``elimination.factor``."""
    return _factor_condensed(cst, A, B, rel_zero_tol=rel_zero_tol, fast=fast)


def solve_scaled(cst: CondensedStructure, cf: CondensedFactor, X1t, r):
    """u (n + m,) solving diag(dv) K diag(dv) u = r (n + m,), the equilibrated system.

    Interior first, w_k = D_k^{-1} r_{I_k}; the kept unknowns from K_U u_U = r_U - sum_k C_k w_k
    (``substitution.solve_vec``); then u_{I_k} = D_k^{-1} (r_{I_k} - C_k^T (u_{U_k}, u_{U_{k+1}}))."""
    nU = cst.nU
    rp = jnp.append(r, 0.0)
    rI = rp[cst.I_ids]
    cw = jnp.einsum("kui,ki->ku", cf.CI, apply_inv(cf.NI, cf.sI, rI))
    rU = rp[cst.U_ids] - cw[:, :nU]
    rU = rU.at[1:].add(-cw[:-1, nU:])
    uU = _orient(cst, solve_vec(cst.red, cf.red, X1t, _orient(cst, rU)))
    uUU = jnp.concatenate([uU, jnp.concatenate([uU[1:], jnp.zeros_like(uU[:1])], axis=0)], axis=1)
    uI = apply_inv(cf.NI, cf.sI, rI - jnp.einsum("kui,ku->ki", cf.CI, uUU))
    out = jnp.zeros(cst.n + cst.m + 1, r.dtype).at[cst.I_ids].set(uI).at[cst.U_ids].set(uU)
    return out[:-1]


@functools.partial(jax.jit, static_argnames=("cst",))
def _solve(cst: CondensedStructure, cf: CondensedFactor, A, B, rx, rc, min_steps, max_steps, residual_ratio_max):
    st = cst.st
    r = jnp.concatenate([rx, rc])
    rs = cf.dv * r
    dr = jnp.max(jnp.abs(rs))
    X1t = border_coupling(cst.red, cf.red, cf.BU)

    def resid(u):
        return r - jnp.concatenate(from_blocks(st, matvec_compact(st, A, B, to_blocks(st, u[: st.n], u[st.n :]))))

    def ratio(u, res):  # IPOPT's residual ratio in the equilibrated system
        return jnp.max(jnp.abs(cf.dv * res)) / jnp.maximum(jnp.max(jnp.abs(u / cf.dv)) + dr, 1e-300)

    def correct(res):
        return cf.dv * solve_scaled(cst, cf, X1t, cf.dv * res)

    u, res = refine(correct, resid, ratio, r, min_steps, max_steps, residual_ratio_max)
    return u[: st.n], u[st.n :], jnp.max(jnp.abs(res))


def solve(
    cst: CondensedStructure,
    cf: CondensedFactor,
    A,
    B,
    rx,
    rc,
    min_steps: int = 1,
    max_steps: int = 10,
    residual_ratio_max: float = 1e-10,
    with_residual: bool = False,
):
    """(dx (n,), dy (m,)) solving K [dx; dy] = [rx; rc] with the condensed factors and adaptive
    iterative refinement against the full K = (A, B); the arguments as ``substitution.solve``."""
    dx, dy, res = _solve(cst, cf, A, B, rx, rc, min_steps, max_steps, residual_ratio_max)
    return (dx, dy, res) if with_residual else (dx, dy)
