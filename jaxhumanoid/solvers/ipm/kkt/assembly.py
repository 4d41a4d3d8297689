"""KKT blocks from NLP values, their diagonal updates, equilibration and block products.

K = [[W + diag(diag_x), J^T], [J, diag(diag_c)]] is held as the diagonal blocks A (S, nb, nb) and
the sub-diagonal blocks B (S, nb, nb) of the stage layout (``structure``): B[k] couples block
k+1 (rows) with block k (columns), B[S-1] = 0. Vectors are stage-blocked, shape (S, nb).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.solvers.ipm.kkt.structure import KKTStructure, static_index


def assemble(st: KKTStructure, hess_vals, jac_vals, diag_x, diag_c):
    """Blocks (A, B) of K = [[W + diag(diag_x), J^T], [J, diag(diag_c)]] (diag_c = -D_c).

    hess_vals (nnz_h,) on the lower-triangle pattern, jac_vals (nnz_j,), diag_x (n,), diag_c (m,);
    the padding rows get their +-1. Returns A, B of shape (S, nb, nb)."""
    S, nb = st.S, st.nb
    flat = jnp.zeros(2 * S * nb * nb + 1, dtype=jnp.result_type(float))
    idx = np.concatenate([st.hess_t1, st.hess_t2, st.jac_t1, st.jac_t2, st.var_diag_t, st.con_diag_t, st.pad_diag_t])
    vals = jnp.concatenate(
        [
            hess_vals,
            hess_vals,
            jac_vals,
            jac_vals,
            diag_x,
            diag_c,
            jnp.asarray(st.pad_sign, dtype=jnp.result_type(float)),
        ]
    )
    flat = flat.at[idx].add(vals)
    A = flat[: S * nb * nb].reshape(S, nb, nb)
    B = flat[S * nb * nb : 2 * S * nb * nb].reshape(S, nb, nb)
    return A, B


def add_diagonal(st: KKTStructure, A, diag_x, diag_c):
    """A + the diagonal entries diag_x (n,) on the variables and diag_c (m,) on the constraints,
    padding untouched (the inertia correction's delta_w I and -delta_c I)."""
    flat = A.reshape(-1)
    flat = flat.at[st.var_diag_t].add(diag_x).at[st.con_diag_t].add(diag_c)
    return flat.reshape(A.shape)


def equilibrate(A, B, passes: int = 2):
    """Symmetric Ruiz scaling d (S, nb): row/column i of K divided by sqrt(max_j |K_ij|), repeated.

    Near the end of an IPM solve Sigma spans many orders of magnitude; the block elimination (no
    pivoting across stages) then loses every digit unless K is equilibrated first. A diagonal
    congruence leaves the inertia unchanged (Sylvester)."""
    S_, nb = A.shape[0], A.shape[1]
    d = jnp.ones((S_, nb), A.dtype)
    for _ in range(passes):
        As, Bs = scale_blocks(A, B, d)
        aB = jnp.abs(Bs)
        rmax = jnp.maximum(jnp.max(jnp.abs(As), axis=2), jnp.max(aB, axis=1))  # A_k rows, B_k^T rows
        rmax = rmax.at[1:].max(jnp.max(aB[:-1], axis=2))  # B_{k-1} rows
        d = d / jnp.sqrt(jnp.where((rmax > 0) & jnp.isfinite(rmax), rmax, 1.0))
    return d


def scale_blocks(A, B, d):
    """Blocks of diag(d) K diag(d); B[k] couples block k+1 (rows) with block k (columns)."""
    dn = jnp.concatenate([d[1:], jnp.ones_like(d[:1])], axis=0)
    return A * d[:, :, None] * d[:, None, :], B * dn[:, :, None] * d[:, None, :]


def equilibrate_compact(st: KKTStructure, A, B, passes: int = 2):
    """``equilibrate`` + ``scale_blocks`` with fewer passes over the data: |A| is formed once, and
    of B only the structurally nonzero part B[:, b_rows, b_cols] (S, r, c) is touched.

    Returns (d (S, nb), scaled A (S, nb, nb), scaled compact B (S, r, c))."""
    rb, cb = static_index(st.b_rows), static_index(st.b_cols)
    S_, nb = A.shape[0], A.shape[1]
    aA = jnp.abs(A)
    Bc = B[:, rb][:, :, cb]
    aB = jnp.abs(Bc)
    d = jnp.ones((S_, nb), A.dtype)
    for i in range(passes):
        if i == 0:
            ra, br, bc = jnp.max(aA, axis=2), jnp.max(aB, axis=2), jnp.max(aB, axis=1)
        else:  # max_j |d_i K_ij d_j| = d_i max_j |K_ij| d_j
            dn = jnp.concatenate([d[1:], jnp.ones_like(d[:1])], axis=0)
            ra = d * jnp.max(aA * d[:, None, :], axis=2)
            br = dn[:, rb] * jnp.max(aB * d[:, None, cb], axis=2)  # rows of block k+1
            bc = d[:, cb] * jnp.max(aB * dn[:, rb, None], axis=1)  # columns of block k
        rmax = ra.at[:, cb].max(bc)
        rmax = rmax.at[1:, rb].max(br[:-1])
        d = d / jnp.sqrt(jnp.where((rmax > 0) & jnp.isfinite(rmax), rmax, 1.0))
    dn = jnp.concatenate([d[1:], jnp.ones_like(d[:1])], axis=0)
    return d, A * (d[:, :, None] * d[:, None, :]), Bc * (dn[:, rb, None] * d[:, None, cb])


def matvec(A, B, u):
    """K u for the block-tridiagonal K given by (A, B), u of shape (S, nb)."""
    y = jnp.einsum("kij,kj->ki", A, u)
    low = jnp.einsum("kij,kj->ki", B[:-1], u[:-1])  # B_k u_k into block k+1
    up = jnp.einsum("kji,kj->ki", B[:-1], u[1:])  # B_k^T u_{k+1} into block k
    y = y.at[1:].add(low)
    y = y.at[:-1].add(up)
    return y


def matvec_compact(st: KKTStructure, A, B, u):
    """``matvec`` using only the structurally nonzero part B[:, b_rows, b_cols]."""
    rb, cb = static_index(st.b_rows), static_index(st.b_cols)
    Bc = B[:-1, rb][:, :, cb]
    y = jnp.einsum("kij,kj->ki", A, u)
    y = y.at[1:, rb].add(jnp.einsum("kij,kj->ki", Bc, u[:-1, cb]))
    return y.at[:-1, cb].add(jnp.einsum("kji,kj->ki", Bc, u[1:, rb]))


def to_blocks(st: KKTStructure, rx, rc):
    """The stage-blocked vector (S, nb) of [rx (n,); rc (m,)], zero on the padding."""
    v = jnp.zeros(st.size, dtype=jnp.result_type(rx, rc, float))
    v = v.at[st.var_pos].set(rx).at[st.con_pos].set(rc)
    return v.reshape(st.S, st.nb)


def from_blocks(st: KKTStructure, u):
    """(ux (n,), uc (m,)) of a stage-blocked vector u (S, nb): the inverse of ``to_blocks``."""
    u = u.reshape(-1)
    return u[st.var_pos], u[st.con_pos]


def dense_matrix(st: KKTStructure, A, B):
    """The full stage-ordered K (S nb x S nb, padding included) as a dense numpy array: for
    tests only."""
    S, nb = st.S, st.nb
    K = np.zeros((S * nb, S * nb))
    A = np.asarray(A)
    B = np.asarray(B)
    for k in range(S):
        K[k * nb : (k + 1) * nb, k * nb : (k + 1) * nb] = A[k]
        if k + 1 < S:
            K[(k + 1) * nb : (k + 2) * nb, k * nb : (k + 1) * nb] = B[k]
            K[k * nb : (k + 1) * nb, (k + 1) * nb : (k + 2) * nb] = B[k].T
    return K
