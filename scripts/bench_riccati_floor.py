"""Benchmark: what a Riccati-style KKT factorisation can cost on this hardware, next to the IPM's.

    OMP_NUM_THREADS=1 python scripts/bench_riccati_floor.py [--repeats 50] [--out results/bench_riccati_floor.json]
                                                            [--data /tmp/bench_kkt_data.npz]

A Riccati recursion over the node states x_k = (q_k, qd_k) of A,F+C works, per interval k, on
z = (x_k, u_k, f_k, x_{k+1}) with the interval's Lagrangian Hessian H_k, its inequality rows G_k
(barrier diagonal Sigma_k), its contact-law rows (f_k = F_k z_other) and its dynamics rows (6)
D_k (D_k[:, x_{k+1}] = E_k invertible):

    Ht   = H_k + G_k^T Sigma_k G_k                       inequalities condensed into the Hessian
    H1   = T1^T Ht T1,  T1: f_k = F_k z_other            the law's forces substituted
    X_k  = -E_k^{-1} D_k[:, (x_k, u_k)]                  x_{k+1} = X_k (x_k, u_k) by the dynamics
    H2   = [I; X_k]^T (H1 + diag(0, P_{k+1})) [I; X_k]   (x_k, u_k) block
    L L^T = H2_uu,  P_k = H2_xx - H2_xu H2_uu^{-1} H2_ux (the recursion; L fails = wrong inertia)

Everything but the last two lines is independent of P_{k+1}, so it can run for all intervals at once
before the recursion. The stage data are synthetic (well-conditioned, random) at the sizes of T1's
stage-2 NLP at N = 100; only the arithmetic is timed, without equilibration, regularisation,
inertia fall-backs, the forward and backward solves or iterative refinement. Timed side by side in
alternation, with plain block-tridiagonal Cholesky factorisations (blocks of the block LDL^T's size,
the condensed one's and the state's) and the project's block LDL^T (``kkt.factor``, and factor +
refined solve) on T1's real stage-2 KKT matrix near IPOPT's 30th iterate (``bench_kkt.py``'s data).
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

import jax
import jax.numpy as jnp
import numpy as np
from _bench import show_table, write
from bench_kkt import make_data
from bench_kkt_methods import alternate
from jax import lax
from jax.scipy.linalg import solve_triangular

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.strategy.problem import build_problem


def stage_sizes(N: int) -> dict:
    """Per-interval sizes of T1's A,F+C stage-2 NLP."""
    lay = build_problem("T1", "A,F+C,2S", N=N).layout
    n = lay.n_links
    return {"N": N, "nx": 2 * n, "nu": n, "nf": lay.n_f, "ni": lay.n_con - 2 * n - lay.n_f}


def synthetic(sz: dict, seed: int = 0):
    """(H, G, Sigma, F, D): random stage data, H_k positive definite, E_k well conditioned."""
    rng = np.random.default_rng(seed)
    N, nx, nu, nf, ni = (sz[k] for k in ("N", "nx", "nu", "nf", "ni"))
    nz = 2 * nx + nu + nf
    a = rng.normal(size=(N, nz, nz))
    H = a @ a.transpose(0, 2, 1) + nz * np.eye(nz)
    G = rng.normal(size=(N, ni, nz))
    Sig = np.exp(rng.uniform(-5, 5, size=(N, ni)))
    F = rng.normal(size=(N, nf, nz - nf))
    D = rng.normal(size=(N, nx, nz))
    D[:, :, nz - nx :] += 5 * np.eye(nx)
    return tuple(jnp.asarray(v) for v in (H, G, Sig, F, D))


def riccati(sz: dict, batched: bool):
    """The factorisation of the module docstring; ``batched``: the P-independent work for all
    intervals at once (``vmap``) before the recursion, else inside it."""
    nx, nu, nf = sz["nx"], sz["nu"], sz["nf"]
    nz = 2 * nx + nu + nf
    fs = np.arange(nx + nu, nx + nu + nf)
    other = np.setdiff1d(np.arange(nz), fs)
    no, nxu = other.size, nx + nu
    T1_base = np.zeros((nz, no))
    T1_base[other, np.arange(no)] = 1.0

    def local(Hk, Gk, Sk, Fk, Dk):
        Ht = Hk + (Gk.T * Sk) @ Gk
        T1 = jnp.asarray(T1_base).at[fs].set(Fk)
        H1 = T1.T @ Ht @ T1
        D1 = Dk @ T1
        X = -jnp.linalg.solve(D1[:, nxu:], D1[:, :nxu])
        T2 = jnp.concatenate([jnp.eye(nxu), X], axis=0)
        return T2.T @ H1 @ T2, X

    def recursion(P, H2, X):
        H2 = H2 + X.T @ P @ X
        L = jnp.linalg.cholesky(H2[nx:, nx:])
        K = solve_triangular(L, H2[nx:, :nx], lower=True)
        Pn = H2[:nx, :nx] - K.T @ K
        return 0.5 * (Pn + Pn.T), (L, K)

    if batched:

        def fac(*data):
            H2, X = jax.vmap(local)(*data)
            return lax.scan(lambda P, a: recursion(P, *a), jnp.zeros((nx, nx)), (H2, X), reverse=True)

    else:

        def fac(*data):
            def step(P, a):
                H2, X = local(*a)
                return recursion(P, H2, X)

            return lax.scan(step, jnp.zeros((nx, nx)), data, reverse=True)

    return jax.jit(fac)


def block_cholesky(N: int, nb: int, seed: int = 0):
    """(function, data) of a plain block-tridiagonal Cholesky factorisation of N SPD blocks."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(N, nb, nb))
    A = jnp.asarray(a @ a.transpose(0, 2, 1) + 3 * nb * np.eye(nb))
    B = jnp.asarray(0.1 * rng.normal(size=(N, nb, nb)))

    @jax.jit
    def fac(A, B):
        def step(Lp, ab):
            W = solve_triangular(Lp, ab[1].T, lower=True)
            Lk = jnp.linalg.cholesky(ab[0] - W.T @ W)
            return Lk, Lk

        return lax.scan(step, jnp.linalg.cholesky(A[0]), (A[1:], B[1:]))

    return fac, (A, B)


def project_factor(D: dict):
    """(factor, factor + refined solve) of ``kkt`` on T1's KKT matrix near IPOPT's 30th iterate,
    with IPOPT's first nonzero shifts (delta_w, delta_c) = (1e-4, 1e-9); and nb."""
    n, m = int(D["n"]), int(D["m"])
    pat = [D[k] for k in ("var_stage", "con_stage", "hess_rows", "hess_cols", "jac_rows", "jac_cols")]
    st = kkt.build_structure(n, m, *pat)
    hv, jv, dx, dc = (jnp.asarray(D[f"it30_{k}"]) for k in ("hess", "jac", "dx", "dc"))
    A, B = kkt.assemble(st, hv, jv, dx + 1e-4, dc - 1e-9)
    r = np.random.default_rng(0).standard_normal(n + m)
    rx, rc = jnp.asarray(r[:n]), jnp.asarray(r[n:])
    fac = jax.jit(lambda A, B: kkt.factor(st, A, B))
    return (lambda: fac(A, B)), (lambda: kkt.solve(st, fac(A, B), A, B, rx, rc)), st.nb


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--N", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--data", default="/tmp/bench_kkt_data.npz")
    ap.add_argument("--out", default="results/bench_riccati_floor.json")
    args = ap.parse_args()
    sz = stage_sizes(args.N)
    data = synthetic(sz)
    ric, ric_b = riccati(sz, batched=False), riccati(sz, batched=True)
    p_a, p_b = ric(*data)[0], ric_b(*data)[0]
    agree = float(jnp.max(jnp.abs(p_a - p_b)) / jnp.max(jnp.abs(p_a)))
    project, project_solve, nb = project_factor(make_data(args.data))
    fns = {
        "riccati: local work in the recursion": lambda: ric(*data),
        "riccati: local work batched first": lambda: ric_b(*data),
    }
    for size in (nb, 32, sz["nx"]):
        f, d = block_cholesky(args.N + 1, size)
        fns[f"block-tridiagonal Cholesky, blocks of {size}"] = lambda f=f, d=d: f(*d)
    fns["kkt.factor (block LDL^T), T1 stage 2"] = project
    fns["kkt.factor + refined solve, T1 stage 2"] = project_solve
    ms = alternate(fns, args.repeats)
    table = "| factorisation | median ms |\n|---|---|\n" + "\n".join(f"| {k} | {v:.3f} |" for k, v in ms.items())
    show_table(table, None)
    write({"sizes": sz, "block_ldl_nb": nb, "P0_rel_diff_batched": agree, "median_ms": ms}, args.out)


if __name__ == "__main__":
    main()
