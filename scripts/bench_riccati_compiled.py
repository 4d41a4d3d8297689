"""Benchmark: the Riccati factorisation of ``bench_riccati_floor.py`` compiled (C++, called through the
XLA FFI), next to the same arithmetic in JAX, with a forward/backward solve of one right-hand side.

    OMP_NUM_THREADS=1 python scripts/bench_riccati_compiled.py [--N 100] [--repeats 50] [--nb 44]
                     [--batch 8] [--out results/bench_riccati_compiled.json]

``scripts/ffi/riccati_floor.cc`` is compiled on the fly (g++ -O3 -march=native, the block sizes as
compile-time constants) into a temporary directory, registered with ``jax.ffi.register_ffi_target``
and called with ``jax.ffi.ffi_call`` inside ``jax.jit``; the same kernel is also called directly via
ctypes on numpy arrays, which separates XLA's call overhead. On the synthetic stage data of
``bench_riccati_floor.py`` (T1's stage-2 sizes) the problem is

    min sum_k 1/2 z_k^T Ht_k z_k + g_k^T z_k   s.t.  D_k z_k = d_k,  f_k = F_k z_other,k + e_k,

z_k = (x_k, u_k, f_k, x_{k+1}), all node states x_0..x_N free. The factorisation is the Riccati
recursion of ``bench_riccati_floor.py`` (per-interval work inside the recursion); the solve a
backward pass for the linear terms, x_0 = -P_0^{-1} p_0 (Cholesky of P_0) and a forward roll-out
(u_k, x_{k+1}, f_k), without multipliers. Checks, before timing (it fails loudly otherwise): the
JAX solve against a sparse LU solve of the whole KKT system, the compiled P_0, Cholesky factors
(relative max error <= 1e-10) and solution (<= 1e-8: the KKT matrix's 1-norm condition number is
about 1.6e7, cond * eps ~ 4e-9, so a backward-stable solve's forward error may reach ~1e-9; the three
solves differ by 2e-10 to 1e-9) against JAX's, and the plain block-tridiagonal Cholesky with
blocks of ``--nb`` (the block LDL^T's block size at T1's stage 2, N = 100) against
``bench_riccati_floor.block_cholesky``. Then wall and CPU time, median of ``--repeats`` calls of each
function in alternation (random order each round, so that no kernel always follows the same
other one's cache footprint), and with ``--batch`` B > 1 the same under ``vmap`` over B problems
(``vmap_method="sequential"`` for the compiled kernel), per member. Exit code 2 if g++ or the XLA FFI
headers are missing (the compiler: $CXX, else g++). Writes JSON (``--out``) and prints a table.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import ctypes
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
from _bench import alternate, show_table, write
from bench_riccati_floor import block_cholesky, riccati, stage_sizes, synthetic
from jax import lax
from jax.scipy.linalg import cho_solve, lu_factor, lu_solve, solve_triangular
from scipy.sparse.linalg import spsolve

import jaxhumanoid  # noqa: F401  (float64)

SOURCE = pathlib.Path(__file__).parent / "ffi" / "riccati_floor.cc"
TARGETS = {"riccati": "jaxhumanoid_bench_riccati", "block_cholesky": "jaxhumanoid_bench_block_cholesky"}


def build_library(sz: dict, nb: int, workdir: str) -> ctypes.CDLL:
    """Compile ``SOURCE`` at the sizes ``sz`` / ``nb``, load it, register its FFI handlers."""
    cxx = shutil.which(os.environ.get("CXX", "g++"))
    include = pathlib.Path(jax.ffi.include_dir())
    if cxx is None or not (include / "xla" / "ffi" / "api" / "ffi.h").exists():
        print(f"needs g++ (found: {cxx}) and the XLA FFI headers under {include}", file=sys.stderr)
        sys.exit(2)
    lib = pathlib.Path(workdir) / "libriccati_floor.so"
    sizes = [f"-DN{k.upper()}={sz[k]}" for k in ("nx", "nu", "nf", "ni")] + [f"-DNB={nb}"]
    cmd = [cxx, "-std=c++17", "-O3", "-march=native", "-shared", "-fPIC", f"-I{include}", *sizes, str(SOURCE)]
    r = subprocess.run([*cmd, "-o", str(lib)], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"compilation failed:\n{' '.join(cmd)}\n{r.stderr}")
    so = ctypes.CDLL(str(lib))
    jax.ffi.register_ffi_target(TARGETS["riccati"], jax.ffi.pycapsule(so.Riccati), platform="cpu")
    jax.ffi.register_ffi_target(TARGETS["block_cholesky"], jax.ffi.pycapsule(so.BlockCholesky), platform="cpu")
    so.riccati_c.restype = so.block_cholesky_c.restype = ctypes.c_int
    so.riccati_c.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 15 + [ctypes.c_int]
    so.block_cholesky_c.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 3
    return so


def rhs(sz: dict, seed: int = 1):
    """(g, d, e): the linear terms, dynamics and force-law right-hand sides."""
    rng = np.random.default_rng(seed)
    N, nx, nu, nf = (sz[k] for k in ("N", "nx", "nu", "nf"))
    return tuple(jnp.asarray(rng.normal(size=(N, n))) for n in (2 * nx + nu + nf, nx, nf))


def out_shapes(sz: dict, N: int):
    """Shapes of the compiled kernel's outputs (P_0, L, K, ok, xs, us, fs)."""
    nx, nu, nf = sz["nx"], sz["nu"], sz["nf"]
    f8 = jnp.float64
    shapes = ((nx, nx), (N, nu, nu), (N, nu, nx), (N + 1,), (N + 1, nx), (N, nu), (N, nf))
    return tuple(jax.ShapeDtypeStruct(s, jnp.int32 if len(s) == 1 else f8) for s in shapes)


def compiled_ffi(sz: dict, do_solve: bool):
    """Jitted compiled factorisation (+ solve): (H, G, Sig, F, D, g, d, e) -> (P0, L, K, ok, xs, us, fs)."""
    call = jax.ffi.ffi_call(TARGETS["riccati"], out_shapes(sz, sz["N"]), vmap_method="sequential")
    return jax.jit(lambda *a: call(*a, do_solve=np.int64(do_solve)))


def compiled_ctypes(so: ctypes.CDLL, sz: dict, args, do_solve: bool):
    """Zero-argument call of the compiled kernel via ctypes on numpy copies of ``args``; outputs
    preallocated, returned as numpy arrays."""
    ins = [np.ascontiguousarray(np.asarray(a)) for a in args]
    outs = [np.zeros(s.shape, s.dtype) for s in out_shapes(sz, sz["N"])]
    ptrs = [a.ctypes.data for a in ins + outs]
    N = sz["N"]

    def call():
        so.riccati_c(N, *ptrs, int(do_solve))
        return outs

    return call


def jax_solver(sz: dict):
    """(factor, factor + solve), jitted, in JAX: the factorisation of ``bench_riccati_floor.riccati``
    (local work inside the recursion) keeping what the solve needs (the LU of E_k, X_k, P_{k+1},
    H1[:, x_{k+1}], Ht[:, f]), and the solve of the module docstring. Same outputs as the kernel."""
    nx, nu, nf = sz["nx"], sz["nu"], sz["nf"]
    nz, nxu = 2 * nx + nu + nf, nx + nu
    fs = np.arange(nxu, nxu + nf)
    other = np.setdiff1d(np.arange(nz), fs)
    no = other.size
    T1_base = np.zeros((nz, no))
    T1_base[other, np.arange(no)] = 1.0

    def factor(H, G, S, F, D):
        def step(P, a):
            Hk, Gk, Sk, Fk, Dk = a
            Ht = Hk + (Gk.T * Sk) @ Gk
            T1 = jnp.asarray(T1_base).at[fs].set(Fk)
            H1 = T1.T @ Ht @ T1
            D1 = Dk @ T1
            lu = lu_factor(D1[:, nxu:])
            X = -lu_solve(lu, D1[:, :nxu])
            T2 = jnp.concatenate([jnp.eye(nxu), X], axis=0)
            H2 = T2.T @ H1 @ T2 + X.T @ P @ X
            L = jnp.linalg.cholesky(H2[nx:, nx:])
            K = solve_triangular(L, H2[nx:, :nx], lower=True)
            Pn = H2[:nx, :nx] - K.T @ K
            return 0.5 * (Pn + Pn.T), (L, K, X, lu, P, H1[:, nxu:], Ht[:, fs])

        P0, st = lax.scan(step, jnp.zeros((nx, nx)), (H, G, S, F, D), reverse=True)
        return P0, jnp.linalg.cholesky(P0), st

    def solve(F, D, fac, g, d, e):
        P0, LP0, (L, K, X, lu, Pn, H1x, Htf) = fac

        def back(p, a):
            Lk, Kk, Xk, luk, Pk, H1xk, Htfk, Fk, Dk, gk, dk, ek = a
            y = Htfk @ ek + gk
            g1 = y[other] + Fk.T @ y[fs]
            c = lu_solve(luk, dk - Dk[:, fs] @ ek)
            w = (H1xk @ c + g1).at[nxu:].add(Pk @ c + p)
            h = w[:nxu] + Xk.T @ w[nxu:]
            kv = solve_triangular(Lk, h[nx:], lower=True)
            return h[:nx] - Kk.T @ kv, (kv, c)

        p0, (kv, c) = lax.scan(back, jnp.zeros(nx), (L, K, X, lu, Pn, H1x, Htf, F, D, g, d, e), reverse=True)
        x0 = -cho_solve((LP0, True), p0)

        def fwd(x, a):
            Lk, Kk, Xk, kvk, ck, Fk, ek = a
            u = -solve_triangular(Lk, Kk @ x + kvk, lower=True, trans="T")
            xn = Xk @ jnp.concatenate([x, u]) + ck
            return xn, (xn, u, Fk @ jnp.concatenate([x, u, xn]) + ek)

        _, (xs, us, f) = lax.scan(fwd, x0, (L, K, X, kv, c, F, e))
        return jnp.concatenate([x0[None], xs]), us, f

    def factor_solve(H, G, S, F, D, g, d, e):
        fac = factor(H, G, S, F, D)
        P0, LP0, (L, K, *_) = fac
        ok = jnp.concatenate([jnp.all(jnp.isfinite(L), axis=(1, 2)), jnp.all(jnp.isfinite(LP0))[None]])
        return (P0, L, K, ok.astype(jnp.int32), *solve(F, D, fac, g, d, e))

    return jax.jit(factor), jax.jit(factor_solve)


def sparse_reference(sz: dict, data, b):
    """(xs, us, fs) of the whole KKT system of the module docstring by a sparse LU (SuperLU)."""
    N, nx, nu, nf = (sz[k] for k in ("N", "nx", "nu", "nf"))
    H, G, S, F, D = (np.asarray(v) for v in data)
    g, d, e = (np.asarray(v) for v in b)
    nz, nxu = 2 * nx + nu + nf, nx + nu
    nX, nU = (N + 1) * nx, N * nu
    n = nX + nU + N * nf
    fs = np.arange(nxu, nxu + nf)
    other = np.setdiff1d(np.arange(nz), fs)
    W, A = sp.lil_matrix((n, n)), sp.lil_matrix((N * (nx + nf), n))
    grad = np.zeros(n)
    for k in range(N):
        idx = np.concatenate(
            [
                k * nx + np.arange(nx),
                nX + k * nu + np.arange(nu),
                nX + nU + k * nf + np.arange(nf),
                (k + 1) * nx + np.arange(nx),
            ]
        )
        W[np.ix_(idx, idx)] = W[np.ix_(idx, idx)].toarray() + H[k] + (G[k].T * S[k]) @ G[k]
        grad[idx] += g[k]
        law = np.zeros((nf, nz))
        law[:, fs] = np.eye(nf)
        law[:, other] = -F[k]
        r = k * (nx + nf)
        A[r : r + nx, idx] = D[k]
        A[r + nx : r + nx + nf, idx] = law
    Kkt = sp.bmat([[W.tocsr(), A.T.tocsr()], [A.tocsr(), None]], format="csc")
    rhs_ = np.concatenate([-grad, np.concatenate([np.concatenate([d[k], e[k]]) for k in range(N)])])
    z = spsolve(Kkt, rhs_)
    return z[:nX].reshape(N + 1, nx), z[nX : nX + nU].reshape(N, nu), z[nX + nU : n].reshape(N, nf)


def rel(a, b) -> float:
    """Relative max error of a against b (arrays or tuples of arrays)."""
    a = np.concatenate([np.ravel(v) for v in (a if isinstance(a, tuple | list) else [a])])
    b = np.concatenate([np.ravel(v) for v in (b if isinstance(b, tuple | list) else [b])])
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def check(errors: dict, tol: float, what: str) -> None:
    bad = {k: v for k, v in errors.items() if not v <= tol}
    if bad:
        raise SystemExit(f"{what}: relative errors above {tol:g}: {bad}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--N", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--nb", type=int, default=44, help="block size of the plain block-tridiagonal Cholesky")
    ap.add_argument("--batch", type=int, default=8, help="vmap batch size (<= 1: no batched rows)")
    ap.add_argument("--out", default="results/bench_riccati_compiled.json")
    args = ap.parse_args()
    sz = stage_sizes(args.N)
    data, b = synthetic(sz), rhs(sz)
    tmp = tempfile.TemporaryDirectory()
    so = build_library(sz, args.nb, tmp.name)

    ric = riccati(sz, batched=False)
    jfac, jfs = jax_solver(sz)
    cfac, cfs = compiled_ffi(sz, False), compiled_ffi(sz, True)
    ref = ric(*data)
    jout, cout = jfs(*data, *b), cfs(*data, *b)
    kout = compiled_ctypes(so, sz, (*data, *b), True)()
    dense = sparse_reference(sz, data, b)
    flags = {"jax": np.asarray(jout[3]).tolist(), "ffi": np.asarray(cout[3]).tolist()}
    errors = {
        "jax_solution_vs_sparse_lu": rel(jout[4:], dense),
        "jax_P0_vs_bench_riccati_floor": rel(jout[0], ref[0]),
        "jax_L_vs_bench_riccati_floor": rel(jout[1], ref[1][0]),
        "ffi_P0_vs_jax": rel(cout[0], jout[0]),
        "ffi_L_vs_jax": rel(cout[1], jout[1]),
        "ffi_K_vs_jax": rel(cout[2], jout[2]),
        "ffi_solution_vs_jax": rel(cout[4:], jout[4:]),
        "ffi_solution_vs_sparse_lu": rel(cout[4:], dense),
        "ctypes_vs_ffi": rel(kout, [np.asarray(v) for v in cout]),
    }
    check({k: v for k, v in errors.items() if "solution" in k}, 1e-8, "solutions")
    check({k: v for k, v in errors.items() if "solution" not in k}, 1e-10, "factorisations, compiled against JAX")
    if not (all(flags["jax"]) and flags["jax"] == flags["ffi"]):
        raise SystemExit(f"positive-definiteness flags differ or fail: {flags}")

    bfac, bdata = block_cholesky(args.N + 1, args.nb)
    bffi = jax.jit(
        jax.ffi.ffi_call(
            TARGETS["block_cholesky"], jax.ShapeDtypeStruct(bdata[0].shape, jnp.float64), vmap_method="sequential"
        )
    )
    bL = [np.ascontiguousarray(np.asarray(v)) for v in bdata] + [np.zeros(bdata[0].shape)]
    bptr = [v.ctypes.data for v in bL]
    bct = lambda: so.block_cholesky_c(args.N + 1, *bptr)
    bct()
    errors["block_cholesky_ffi_vs_jax"] = rel(bffi(*bdata)[1:], bfac(*bdata)[1])
    errors["block_cholesky_ctypes_vs_jax"] = rel(bL[2][1:], bfac(*bdata)[1])
    check({k: v for k, v in errors.items() if k.startswith("block")}, 1e-10, "block Cholesky against JAX")

    args_all = (*data, *b)
    fns = {
        "JAX factor (bench_riccati_floor, local work in the recursion)": lambda: ric(*data),
        "JAX factor, keeping what the solve needs": lambda: jfac(*data),
        "JAX factor + solve": lambda: jfs(*args_all),
        "compiled factor, jax.ffi": lambda: cfac(*args_all),
        "compiled factor + solve, jax.ffi": lambda: cfs(*args_all),
        "compiled factor, ctypes": compiled_ctypes(so, sz, args_all, False),
        "compiled factor + solve, ctypes": compiled_ctypes(so, sz, args_all, True),
        f"JAX block-tridiagonal Cholesky, blocks of {args.nb}": lambda: bfac(*bdata),
        f"compiled block-tridiagonal Cholesky, blocks of {args.nb}, jax.ffi": lambda: bffi(*bdata),
        f"compiled block-tridiagonal Cholesky, blocks of {args.nb}, ctypes": bct,
    }
    per = {}
    if args.batch > 1:
        B = args.batch
        bd = [synthetic(sz, seed=s) + rhs(sz, seed=100 + s) for s in range(B)]
        batch = tuple(jnp.stack(v) for v in zip(*bd))
        vj, vc = jax.jit(jax.vmap(jfs)), jax.jit(jax.vmap(cfs))
        vjo, vco = vj(*batch), vc(*batch)
        errors[f"vmap{B}_ffi_P0_vs_jax"] = rel(vco[0], vjo[0])
        errors[f"vmap{B}_ffi_solution_vs_jax"] = rel(vco[4:], vjo[4:])
        check({f"vmap{B}_ffi_P0_vs_jax": errors[f"vmap{B}_ffi_P0_vs_jax"]}, 1e-10, "vmap: compiled against JAX")
        check(
            {f"vmap{B}_ffi_solution_vs_jax": errors[f"vmap{B}_ffi_solution_vs_jax"]}, 1e-8, "vmap: compiled against JAX"
        )
        fns[f"JAX factor + solve, vmap over {B}, per member"] = lambda: vj(*batch)
        fns[f"compiled factor + solve, jax.ffi vmap over {B} (sequential), per member"] = lambda: vc(*batch)
        per = {k: B for k in fns if "vmap" in k}
    for k, v in errors.items():
        print(f"{k}: {v:.2e}")
    load_before = os.getloadavg()
    times = alternate(fns, args.repeats, per)
    load_after = os.getloadavg()
    table = f"| N = {args.N} | median ms | min ms | CPU median ms |\n|---|---|---|---|\n" + "\n".join(
        f"| {k} | {v['median_ms']:.3f} | {v['min_ms']:.3f} | {v['cpu_median_ms']:.3f} |" for k, v in times.items()
    )
    show_table(table, None)
    print(f"load average before / after: {load_before} / {load_after}")
    write(
        {
            "sizes": sz,
            "nb": args.nb,
            "repeats": args.repeats,
            "batch": args.batch,
            "rel_errors": errors,
            "pd_flags_all_ok": bool(all(flags["ffi"])),
            "loadavg_before_after": [load_before, load_after],
            "timings": times,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
