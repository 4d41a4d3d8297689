"""Benchmark: the grouped recursion over (q_k, qd_k, u_{k-1}) in JAX and compiled, on T1's real
stage-2 KKT matrices, against the block LDL^T, in one run.

    OMP_NUM_THREADS=1 python scripts/bench_riccati_real.py [--repeats 30] [--data /tmp/bench_kkt_data.npz]
        [--out results/bench_riccati_real.json] [--md FILE] [--no-compiled]

The order is ``study_riccati_order.py``'s "grouped" one: interval k = N-1, ..., 0 eliminates

    G1(k): the contact forces f_k with the rows of their law (3)-(4),
    G2(k): the next state x_{k+1} with the rows (6a)-(6b),
    G3(k): the torques u_k with the interval's inequality rows,

and leaves a Schur complement S_k on the unknowns C_k it couples to, (x_k, u_{k-1}) (the
torque-rate term of (7) couples u_k to u_{k-1}), which interval k-1 adds to its own block. Each
interval's block of K is gathered once (numpy; zero-padded to the largest sizes, a padding slot
holding 1 on the diagonal), so that the recursion is one ``lax.scan`` of fixed shapes:

    M_k = [[K_LL, K_LC], [K_CL, 0]] + scatter(S_{k+1}),   L = G1 | G2 | G3 of interval k
    block LU of M_k over G1, G2, G3 (LU with partial pivoting inside each group)
    S_k = the trailing block on C_k

The inertia is that of the pivot blocks: G1 and G2 are pairs [[A, E^T], [E, 0]] with E square,
(nv, nv) whatever A; G3's comes from the eigenvalues of its diagonally scaled congruent. The solve is a
forward scan (k descending) and a backward scan (k ascending). What is timed, in alternation:
the recursion's factorisation and one plain solve against ``kkt.factor`` and ``kkt.solve_vec``
(the block LDL^T's plain solve), on each matrix; checked: the inertia against ``kkt.factor``'s
and the backward error (plain and after 3 refinements against K, in numpy) as
``study_riccati_order.py`` measures it.

The same arithmetic compiled (``scripts/ffi/riccati_grouped.cc``, built on the fly with g++ -O3
-march=native at the padded sizes, called through ctypes on the gathered numpy blocks; G3's
inertia by Bunch-Kaufman) is checked and timed alongside: its factorisation includes the copy of
the gathered blocks into its work buffer, timed alone as well. ``--no-compiled`` (or no g++)
skips it.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import collections
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
from _bench import show_table, write
from bench_kkt import backward_error, make_data, ruiz, sparse_kkt
from bench_kkt_methods import alternate
from jax import lax
from jax.scipy.linalg import lu_factor, lu_solve
from study_riccati_order import groups

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.strategy.problem import build_problem


def per_interval(order) -> list[list[np.ndarray]]:
    """[G1, G2, G3] unknowns per interval k = N-1, ..., 0 (G3 empty where it has none)."""
    out: list[list[np.ndarray]] = []
    for name, g in order:
        if name == "G1":
            out.append([g, np.zeros(0, int), np.zeros(0, int)])
        else:
            out[-1][["G1", "G2", "G3"].index(name)] = g
    return out


def carried(K, ivals) -> list[np.ndarray]:
    """C_k: the unknowns outside interval k's groups that its symbolic elimination couples to."""
    adj = collections.defaultdict(set)
    C = K.tocoo()
    for i, j in zip(C.row, C.col):
        if i != j:
            adj[int(i)].add(int(j))
    alive = np.ones(K.shape[0], bool)
    out = []
    for gs in ivals:
        local = set(np.concatenate(gs).tolist())
        touched: set[int] = set()
        for g in gs:
            gset = set(g.tolist())
            alive[g] = False
            rest = {j for j in set().union(*(adj[i] for i in gset)) - gset if alive[j]}
            for a in rest:
                adj[a] |= rest - {a}
                adj[a] -= gset
            touched |= rest
        out.append(np.array(sorted(touched - local), int))
    return out


def layout_blocks(ivals, Cs):
    """Padded per-interval index arrays: the slots of G1 | G2 | G3 | C and, per interval, the
    slots of C_{k+1} inside its local block (where S_{k+1} lands)."""
    sizes = [max(gs[i].size for gs in ivals) for i in range(3)]
    nC = max(c.size for c in Cs)
    nL = sum(sizes)
    idx = np.full((len(ivals), nL + nC), -1)
    for k, (gs, c) in enumerate(zip(ivals, Cs)):
        off = 0
        for g, sz in zip(gs, sizes):
            idx[k, off : off + g.size] = g
            off += sz
        idx[k, nL : nL + c.size] = c
    inpos = np.zeros((len(ivals), nC), int)
    inmask = np.zeros((len(ivals), nC), bool)
    for k in range(1, len(ivals)):  # ivals[k-1] is interval k+1 in time: its C lands in ivals[k]
        slot = {int(v): s for s, v in enumerate(idx[k, :nL]) if v >= 0}
        for s, v in enumerate(idx[k - 1, nL:]):
            if v >= 0:
                assert int(v) in slot, "a carried unknown outside the next interval's block"
                inpos[k, s], inmask[k, s] = slot[int(v)], True
    return idx, sizes, nC, inpos, inmask


def gather(K, idx, nL):
    """Dense M_k without S: K's entries among the slots, the C x C block left to interval k-1."""
    Kd = K.tocsr()
    nT = idx.shape[1]
    M = np.zeros((idx.shape[0], nT, nT))
    for k in range(idx.shape[0]):
        real = idx[k] >= 0
        sub = Kd[idx[k, real]][:, idx[k, real]].toarray()
        Mk = np.zeros((nT, nT))
        Mk[np.ix_(real, real)] = sub
        Mk[nL:, nL:] = 0.0
        pad = np.flatnonzero(~real)
        Mk[pad, pad] = 1.0
        M[k] = Mk
    return M


def eliminate(M, a: int, b: int):
    """One group [a, b) of a block LU: LU of the pivot block, L_rg = M_rg P^{-1} stored below
    it, the trailing block updated by the Schur complement."""
    lu = lu_factor(M[a:b, a:b])
    Lrg = lu_solve(lu, M[b:, a:b].T, trans=1).T
    M = M.at[b:, b:].add(-Lrg @ M[a:b, b:])
    return M.at[b:, a:b].set(Lrg), lu


def g3_counts(P):
    """(npos, nneg, nzero) of a symmetric block from the eigenvalues of its diagonally scaled
    congruent (the scaling makes the signs robust to the barrier terms' range)."""
    d = jnp.abs(jnp.diagonal(P))
    sc = jnp.where(d > 0, 1.0 / jnp.sqrt(d), 1.0)
    w = jnp.linalg.eigvalsh(0.5 * (P + P.T) * sc[:, None] * sc[None, :])
    return jnp.stack([jnp.sum(w > 0), jnp.sum(w < 0), jnp.sum(w == 0)])


def make_recursion(sizes, nC, batched: bool = True, inertia: bool = True):
    """(factor, solve) of the recursion for the padded sizes, as jittable functions. ``batched``
    eliminates G1 for all intervals at once before the scan (its pivot block does not depend on
    S_{k+1}, which lands on x_{k+1} and u_k); ``inertia`` computes G3's counts."""
    b1, b2, nL = sizes[0], sizes[0] + sizes[1], sum(sizes)
    bounds = ((0, b1), (b1, b2), (b2, nL))

    def fstep(S, data):
        M, pos, mask, lu1 = data
        M = M.at[pos[:, None], pos[None, :]].add(jnp.where(mask[:, None] & mask[None, :], S, 0.0))
        if not batched:
            M, lu1 = eliminate(M, 0, b1)
        M, lu2 = eliminate(M, b1, b2)
        counts = g3_counts(M[b2:nL, b2:nL]) if inertia else jnp.zeros(3, jnp.int32)
        M, lu3 = eliminate(M, b2, nL)
        return M[nL:, nL:], (M, [lu1, lu2, lu3], counts)

    def factor(M, inpos, inmask):
        if batched:
            M, lu1 = jax.vmap(lambda Mk: eliminate(Mk, 0, b1))(M)
        else:
            lu1 = (jnp.zeros((M.shape[0], b1, b1)), jnp.zeros((M.shape[0], b1), jnp.int32))
        _, (Mf, lus, counts) = lax.scan(fstep, jnp.zeros((nC, nC)), (M, inpos, inmask, lu1))
        return Mf, lus, jnp.sum(counts, axis=0)

    def fwd(rC, data):
        Mf, lus, r, pos, mask = data
        r = jnp.concatenate([r, jnp.zeros(nC)]).at[pos].add(jnp.where(mask, rC, 0.0))
        for a, b in bounds:
            r = r.at[b:].add(-Mf[b:, a:b] @ r[a:b])
        return r[nL:], r[:nL]

    def bwd(xC, data):
        Mf, lus, y, pos, mask = data
        x = jnp.concatenate([y, xC])
        for (a, b), lu in reversed(list(zip(bounds, lus))):
            x = x.at[a:b].set(lu_solve(lu, x[a:b] - Mf[a:b, b:] @ x[b:]))
        xnext = jnp.where(mask, x[pos], 0.0)  # the next interval's C, in this block's slots
        return xnext, x[:nL]

    def solve(fac, r, inpos, inmask):
        Mf, lus, _ = fac
        _, y = lax.scan(fwd, jnp.zeros(nC), (Mf, lus, r, inpos, inmask))
        # backward: interval 0 (the last of the scan) first; its C_0 is empty
        _, x = lax.scan(bwd, jnp.zeros(nC), (Mf, lus, y, inpos, inmask), reverse=True)
        return x

    return factor, solve


def structural_counts(ivals, idx, sizes) -> np.ndarray:
    """The pairs' inertia (G1, G2) and the padding slots of G3 (eigenvalue 1, to subtract)."""
    tot = np.zeros(3, int)
    for gs in ivals:
        for g in gs[:2]:
            assert g.size % 2 == 0
            tot += [g.size // 2, g.size // 2, 0]
    b2, nL = sizes[0] + sizes[1], sum(sizes)
    tot[0] -= int(np.sum(idx[:, b2:nL] < 0))
    return tot


SOURCE = pathlib.Path(__file__).parent / "ffi" / "riccati_grouped.cc"


def build_compiled(sizes, nC: int, workdir: str):
    """Compile ``SOURCE`` at the padded sizes and load it (ctypes); None without g++."""
    cxx = shutil.which(os.environ.get("CXX", "g++"))
    if cxx is None:
        print("g++ not found: the compiled recursion is skipped", file=sys.stderr)
        return None
    consts = [f"-DB1={sizes[0]}", f"-DB2={sizes[0] + sizes[1]}", f"-DNL={sum(sizes)}", f"-DNC={nC}"]
    lib = pathlib.Path(workdir) / "libriccati_grouped.so"
    cmd = [cxx, "-std=c++17", "-O3", "-march=native", "-shared", "-fPIC", *consts, str(SOURCE), "-o", str(lib)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"compilation failed:\n{' '.join(cmd)}\n{r.stderr}")
    so = ctypes.CDLL(str(lib))
    so.grouped_factor_c.restype = ctypes.c_int
    so.grouped_factor_c.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 7
    so.grouped_solve_c.restype = None
    so.grouped_solve_c.argtypes = [ctypes.c_int64] + [ctypes.c_void_p] * 7
    return so


class Compiled:
    """The compiled recursion on numpy arrays: ``factor(M)`` (copies M into its work buffer)
    and ``solve(rpad)``."""

    def __init__(self, so, inpos, inmask, nL):
        self.so, self.nL = so, nL
        self.inpos = np.ascontiguousarray(inpos, np.int32)
        self.inmask = np.ascontiguousarray(inmask, np.uint8)

    def factor(self, M):
        self.M = np.array(M, np.float64, order="C")
        self.piv = np.zeros((M.shape[0], self.nL), np.int32)
        self.cols = np.zeros((M.shape[0], 3, M.shape[1]), np.int32)
        self.ncols = np.zeros((M.shape[0], 3), np.int32)
        self.cnt = np.zeros(3, np.int64)
        arrays = (self.M, self.piv, self.cols, self.ncols, self.inpos, self.inmask, self.cnt)
        ptr = [a.ctypes.data for a in arrays]
        self.singular = self.so.grouped_factor_c(M.shape[0], *ptr)
        return self

    def solve(self, rpad):
        r = np.array(rpad, np.float64, order="C")
        ptr = [a.ctypes.data for a in (self.M, self.piv, self.cols, self.ncols, self.inpos, self.inmask, r)]
        self.so.grouped_solve_c(r.shape[0], *ptr)
        return r


def op_costs(repeats: int) -> dict:
    """ms per 100 scan steps of each operation one interval of the recursion runs (random data)."""
    rng = np.random.default_rng(0)
    M = jnp.asarray(rng.normal(size=(100, 64, 64)) + 8 * np.eye(64))
    ops = {
        "empty step": lambda m: m[0, 0],
        "lu_factor 20 x 20": lambda m: lu_factor(m[:20, :20])[0][0, 0],
        "lu_factor + lu_solve, 20 x 20 with 44 right-hand sides": lambda m: lu_solve(
            lu_factor(m[:20, :20]), m[:20, 20:]
        )[0, 0],
        "Schur update 44 x 20 x 44 into 64 x 64": lambda m: m.at[20:, 20:].add(-m[20:, :20] @ m[:20, 20:])[30, 30],
        "eigvalsh 17 x 17": lambda m: jnp.linalg.eigvalsh(m[:17, :17] + m[:17, :17].T)[0],
        "cholesky 17 x 17": lambda m: jnp.linalg.cholesky(m[:17, :17] @ m[:17, :17].T)[0, 0],
    }
    fns = {
        k: jax.jit(lambda M, body=body: lax.scan(lambda c, m: (c + body(m), None), 0.0, M)[0])
        for k, body in ops.items()
    }
    return alternate({k: (lambda f=f: f(M)) for k, f in fns.items()}, repeats)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/bench_kkt_data.npz")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--out", default="results/bench_riccati_real.json")
    ap.add_argument("--md", default=None, help="also write the table here")
    ap.add_argument("--no-compiled", action="store_true", help="skip the compiled recursion")
    args = ap.parse_args()
    D = make_data(args.data)
    n, m = int(D["n"]), int(D["m"])
    layout = build_problem("T1", "A,F+C,1S", N=100).layout
    ivals = per_interval(groups(layout, n, "grouped"))
    pat = [D[k] for k in ("var_stage", "con_stage", "hess_rows", "hess_cols", "jac_rows", "jac_cols")]
    st = kkt.build_structure(n, m, *pat)
    ones = [np.ones_like(D[f"it30_{k}"]) for k in ("hess", "jac", "dx", "dc")]
    K0 = sparse_kkt(D, *ones)  # the pattern: every structural entry nonzero
    Cs = carried(K0, ivals)
    idx, sizes, nC, inpos, inmask = layout_blocks(ivals, Cs)
    nL = sum(sizes)
    base = structural_counts(ivals, idx, sizes)
    assert np.all(inpos[inmask] >= sizes[0]), "S_{k+1} lands on G1"
    factor, solve = make_recursion(sizes, nC)
    f_fac, f_sol = jax.jit(factor), jax.jit(solve)
    variants = {
        "G1 in the scan": jax.jit(make_recursion(sizes, nC, batched=False)[0]),
        "no inertia": jax.jit(make_recursion(sizes, nC, inertia=False)[0]),
    }
    so = None if args.no_compiled else build_compiled(sizes, nC, tempfile.mkdtemp())
    k_fac = jax.jit(lambda A, B: kkt.factor(st, A, B))
    k_sol = jax.jit(lambda fac, B, r: kkt.solve_vec(st, fac, kkt.border_coupling(st, fac, B), r))
    jin, jmask = jnp.asarray(inpos), jnp.asarray(inmask)
    real = idx[:, :nL] >= 0

    def pad(v):
        """A vector of K's unknowns in the per-interval local slots (zero in the padding)."""
        return np.where(real, v[np.maximum(idx[:, :nL], 0)], 0.0)

    rng = np.random.default_rng(1)
    records, table = [], []
    for label in ("it3", "it30", "final", "synth"):
        for dw, dc in ((0.0, 1e-9), (1e-4, 1e-9)):
            args_k = (D[f"{label}_hess"], D[f"{label}_jac"], D[f"{label}_dx"] + dw, D[f"{label}_dc"] - dc)
            Ks = sparse_kkt(D, *args_k).tocsr()
            Mnp = gather(Ks, idx, nL)
            M = jnp.asarray(Mnp)
            r = rng.normal(size=n + m)
            rpad_np = pad(r)
            rpad = jnp.asarray(rpad_np)
            fac = f_fac(M, jin, jmask)
            sc = ruiz(Ks)
            Ke = (Ks.multiply(sc[:, None]).multiply(sc[None, :])).tocsr()

            def refined(solve_pad, r=r, Ks=Ks, Ke=Ke, sc=sc):
                """Backward errors of the plain solve and after 1..3 refinements against K."""

                def apply(rr):
                    xp = solve_pad(pad(rr))
                    x = np.zeros(n + m)
                    x[idx[:, :nL][real]] = xp[real]
                    return x

                u = apply(r)
                berr = [backward_error(Ke, sc, u, r)]
                for _ in range(3):
                    u = u + apply(r - Ks @ u)
                    berr.append(backward_error(Ke, sc, u, r))
                return berr

            berr = refined(lambda rp, fac=fac: np.asarray(f_sol(fac, jnp.asarray(rp), jin, jmask)))
            inertia = tuple(int(v) for v in base + np.asarray(fac[2]))
            timed = {}
            if so is not None:
                comp = Compiled(so, inpos, inmask, nL).factor(Mnp)
                c_inertia = tuple(int(v) for v in base + comp.cnt)
                c_berr = refined(comp.solve)
                x_jax, x_c = np.asarray(f_sol(fac, rpad, jin, jmask)), comp.solve(rpad_np)
                c_diff = float(np.max(np.abs(x_c - x_jax)) / np.max(np.abs(x_jax)))
                work = Compiled(so, inpos, inmask, nL)
                timed = {
                    "compiled_factor": lambda work=work, Mnp=Mnp: (work.factor(Mnp), None)[1],
                    "compiled_copy_of_M": lambda Mnp=Mnp: (np.array(Mnp, order="C"), None)[1],
                    "compiled_solve": lambda comp=comp, rp=rpad_np: (comp.solve(rp), None)[1],
                }
            A, B = kkt.assemble(st, *(jnp.asarray(a) for a in args_k))
            kf = k_fac(A, B)
            ref = (int(kf.npos), int(kf.nneg), int(kf.nzero))
            rb = kkt.to_blocks(st, jnp.asarray(r[:n]), jnp.asarray(r[n:]))
            ms = alternate(
                {
                    "recursion_factor": lambda M=M: f_fac(M, jin, jmask),
                    "block_ldl_factor": lambda A=A, B=B: k_fac(A, B),
                    "recursion_solve": lambda fac=fac: f_sol(fac, rpad, jin, jmask),
                    "block_ldl_solve": lambda kf=kf, B=B: k_sol(kf, B, rb),
                    **{f"recursion_factor, {k}": (lambda M=M, f=f: f(M, jin, jmask)) for k, f in variants.items()},
                    **timed,
                },
                args.repeats,
            )
            rec = {"matrix": label, "delta_w": dw, "delta_c": dc, "inertia": inertia, "block_ldl_inertia": ref}
            rec |= {"same_inertia": inertia == ref, "backward_error": berr, "median_ms": ms}
            if so is not None:
                rec["compiled"] = {"inertia": c_inertia, "same_inertia": c_inertia == ref, "backward_error": c_berr}
                rec["compiled"] |= {"singular_blocks": comp.singular, "max_rel_diff_to_jax": c_diff}
                print("compiled:", rec["compiled"], flush=True)
            records.append(rec)
            row = [label, f"{dw:g}", f"{dc:g}", "yes" if inertia == ref else f"NO {inertia} vs {ref}"]
            row += [f"{berr[0]:.0e} / {berr[-1]:.0e}"]
            row += [
                f"{ms[k]:.2f}" for k in ("recursion_factor", "block_ldl_factor", "recursion_solve", "block_ldl_solve")
            ]
            table.append(row)
            print(row, flush=True)
    head = ["matrix", "delta_w", "delta_c", "same inertia", "backward error: plain / refined x3"]
    head += ["recursion factor ms", "block LDL^T factor ms", "recursion solve ms", "block LDL^T solve ms"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r_) + " |" for r_ in table]
    show_table("\n".join(lines), args.md)
    ops = op_costs(args.repeats)
    for k, v in ops.items():
        print(f"{k}: {v:.2f} ms per 100 steps")
    sizes_rec = {"G1": sizes[0], "G2": sizes[1], "G3": sizes[2], "C": nC}
    out = {
        "N": layout.N,
        "padded_sizes": sizes_rec,
        "repeats": args.repeats,
        "records": records,
        "op_ms_per_100_steps": ops,
    }
    write(out, args.out)


if __name__ == "__main__":
    main()
