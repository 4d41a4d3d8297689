"""Study: the KKT matrix eliminated in the order of a recursion over the node states, against the
block LDL^T, on T1's stage-2 KKT matrices.

    OMP_NUM_THREADS=1 python scripts/study_riccati_order.py [--data /tmp/bench_kkt_data.npz]
        [--reg 1e-9] [--out results/study_riccati_order.json] [--md results/study_riccati_order.md]

The matrices are those of ``bench_kkt.py`` (T1, A,F+C stage 2, N = 100, near IPOPT's 3rd and
30th iterates, at its solution, and with synthetic barrier terms), each with the shifts
(delta_w, delta_c) = (0, 0), (0, 1e-9) and (1e-4, 1e-9). The block LDL^T (``kkt.factor``) gives
the reference inertia. The same matrix is then eliminated, as a dense matrix in numpy, in the
order a Riccati recursion takes, interval k = N-1, ..., 0 after the inequality rows:

    each inequality row alone (pivot -d_i < 0: one negative eigenvalue),
    G1(k): the contact forces f_k with the rows of their law (3)-(4), whose Jacobian in f_k is I,
    G2(k): the next state x_{k+1} with the rows (6a)-(6b) of interval k,
    G3(k): the torques u_k, a 5 x 5 reduced Hessian that must be positive definite.

A pair G1 or G2 [[A, L^T], [L, D]] with L square and nonsingular has inertia (nv, nv) whatever A
(D = 0), so only the torque blocks are tested (eigenvalues). Where the end stages fix
qd_{N-1} and qd_N, x_{k+1} pairs with the rows (6a) alone and u_k with the rows (6b). Every pivot
block is factored by LU with partial pivoting, the rest updated by its Schur complement.

Variants: ``none`` eliminates K itself; ``equality`` and ``all`` first put -``--reg`` on the
diagonal of the equality rows, or of all constraint rows, where it is closer to zero (a dual
regularisation); the solve is then refined against K itself (3 steps). Per case: the inertia of
both, whether the IPM's decision (inertia (n, m, 0) or not) agrees, the torque blocks off
positive definiteness, the largest condition number of a pair's L, the normwise backward error
of the solve after 0..3 refinements (in the Ruiz-equilibrated system, as ``bench_kkt.py``
measures it), and the flops of the elimination per interval.
"""

from __future__ import annotations

import argparse

import jax.numpy as jnp
import numpy as np
import scipy.linalg
from _bench import show_table, write
from bench_kkt import backward_error, make_data, ruiz, sparse_kkt

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.strategy.problem import build_problem

VARIANTS = ("none", "equality", "all")
SHIFTS = ((0.0, 0.0), (0.0, 1e-9), (1e-4, 1e-9))


def groups(layout, n: int) -> list[tuple[str, np.ndarray, tuple[int, int]]]:
    """(name, unknowns of K, expected inertia (npos, nneg)) in elimination order."""
    N, nc, nq = layout.N, layout.n_con, layout.n_links
    free = layout.free_mask()
    vidx = np.full(free.shape, -1)
    vidx[free] = np.arange(n)
    sl = layout.stage_slices()
    kinds = layout.constraint_kinds()

    def var(k, name):
        ix = vidx[k, sl[name]]
        return ix[ix >= 0]

    def rows(k, lo, hi):
        return n + k * nc + np.arange(lo, hi)

    law = (2 * nq, 2 * nq + layout.n_f)
    out = [("ineq", np.array([n + k * nc + i]), (0, 1)) for k in range(N) for i in np.flatnonzero(kinds == 1)]
    for k in range(N - 1, -1, -1):
        f, u, xq, xqd = var(k, "f"), var(k, "u"), var(k + 1, "q"), var(k + 1, "qd")
        out.append(("G1", np.concatenate([f, rows(k, *law)]), (f.size, f.size)))
        if xqd.size:
            out.append(("G2", np.concatenate([xq, xqd, rows(k, 0, 2 * nq)]), (2 * nq, 2 * nq)))
            if u.size:
                out.append(("G3", u, (u.size, 0)))
        else:
            out.append(("G2", np.concatenate([xq, rows(k, 0, nq)]), (nq, nq)))
            out.append(("G3", np.concatenate([u, rows(k, nq, 2 * nq)]), (nq, nq)))
    return out


def eliminate(K: np.ndarray, order, rel_tol: float = 1e-13) -> dict:
    """Block elimination of the dense K in ``order``; the inertia, the blocks off their expected
    inertia, the largest condition number of a pair's L, the flops, and the steps of ``solve``."""
    K = K.copy()
    alive = np.ones(K.shape[0], bool)
    tot = np.zeros(3, np.int64)
    off: dict[str, int] = {}
    cond_l, flops, steps = 0.0, 0.0, []
    for name, g, (ep, en) in order:
        alive[g] = False
        rest = np.flatnonzero(alive & np.any(K[g] != 0, axis=0))
        P = K[np.ix_(g, g)]
        if name in ("G1", "G2") or (name == "G3" and en):  # pairs: inertia by structure
            cond_l = max(cond_l, float(np.linalg.cond(K[np.ix_(g[ep:], g[:ep])])))
            counts = np.array([ep, ep, 0])
        else:
            Ps = 0.5 * (P + P.T)
            sc = 1.0 / np.sqrt(np.maximum(np.abs(Ps.diagonal()), 1e-300))
            w = np.linalg.eigvalsh(Ps * sc[:, None] * sc[None, :])
            tol = rel_tol * np.max(np.abs(w))
            counts = np.array([np.sum(w > tol), np.sum(w < -tol), np.sum(np.abs(w) <= tol)])
        if tuple(counts) != (ep, en, 0):
            off[name] = off.get(name, 0) + 1
        tot += counts
        lu = scipy.linalg.lu_factor(P)
        Kgr, Krg = K[np.ix_(g, rest)].copy(), K[np.ix_(rest, g)].copy()
        if rest.size:
            K[np.ix_(rest, rest)] -= Krg @ scipy.linalg.lu_solve(lu, Kgr)
        a, b = g.size, rest.size
        flops += 2 * a**3 / 3 + 2 * a * a * b + 2 * a * b * b
        steps.append((g, rest, lu, Kgr, Krg))
    return {"inertia": tuple(int(v) for v in tot), "off": off, "cond_L": cond_l, "flops": flops, "steps": steps}


def solve(steps, r: np.ndarray) -> np.ndarray:
    """K^{-1} r by the forward and backward substitution of ``eliminate``'s steps."""
    r = r.copy()
    for g, rest, lu, _, Krg in steps:
        if rest.size:
            r[rest] -= Krg @ scipy.linalg.lu_solve(lu, r[g])
    u = np.zeros_like(r)
    for g, rest, lu, Kgr, _ in reversed(steps):
        u[g] = scipy.linalg.lu_solve(lu, r[g] - (Kgr @ u[rest] if rest.size else 0.0))
    return u


def regularised(K: np.ndarray, n: int, rows: np.ndarray, reg: float) -> np.ndarray:
    Kr = K.copy()
    ix = n + rows
    Kr[ix, ix] = np.minimum(Kr[ix, ix], -reg)
    return Kr


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default="/tmp/bench_kkt_data.npz")
    ap.add_argument("--reg", type=float, default=1e-9)
    ap.add_argument("--out", default="results/study_riccati_order.json")
    ap.add_argument("--md", default=None, help="also write the table here")
    args = ap.parse_args()
    D = make_data(args.data)
    n, m = int(D["n"]), int(D["m"])
    layout = build_problem("T1", "A,F+C,1S", N=100).layout
    order = groups(layout, n)
    assert np.array_equal(np.sort(np.concatenate([g for _, g, _ in order])), np.arange(n + m))
    st = kkt.build_structure(
        n, m, D["var_stage"], D["con_stage"], D["hess_rows"], D["hess_cols"], D["jac_rows"], D["jac_cols"]
    )
    eq = np.flatnonzero(np.tile(layout.constraint_kinds() == 0, layout.N))
    rows_of = {"none": np.zeros(0, np.int64), "equality": eq, "all": np.arange(m)}
    rng = np.random.default_rng(1)
    records, table = [], []
    for label in ("it3", "it30", "final", "synth"):
        for dw, dc in SHIFTS:
            args_k = (D[f"{label}_hess"], D[f"{label}_jac"], D[f"{label}_dx"] + dw, D[f"{label}_dc"] - dc)
            A, B = kkt.assemble(st, *(jnp.asarray(a) for a in args_k))
            fac = kkt.factor(st, A, B)
            ref = (int(fac.npos), int(fac.nneg), int(fac.nzero))
            Ks = sparse_kkt(D, *args_k)
            K, sc = Ks.toarray(), ruiz(Ks)
            Ke = (Ks.multiply(sc[:, None]).multiply(sc[None, :])).tocsr()
            r = rng.normal(size=n + m)
            for variant in VARIANTS:
                e = eliminate(regularised(K, n, rows_of[variant], args.reg), order)
                u = solve(e["steps"], r)
                berr = [backward_error(Ke, sc, u, r)]
                for _ in range(3):
                    u = u + solve(e["steps"], r - K @ u)
                    berr.append(backward_error(Ke, sc, u, r))
                decision = (e["inertia"] == (n, m, 0)) == (ref == (n, m, 0))
                rec = {
                    "matrix": label,
                    "delta_w": dw,
                    "delta_c": dc,
                    "variant": variant,
                    "block_ldl_inertia": ref,
                    "riccati_inertia": e["inertia"],
                    "same_inertia": e["inertia"] == ref,
                    "same_decision": decision,
                    "torque_blocks_off": e["off"].get("G3", 0),
                    "max_cond_L": e["cond_L"],
                    "backward_error": berr,
                    "flops_per_interval": e["flops"] / layout.N,
                }
                records.append(rec)
                table.append(
                    [
                        label,
                        f"{dw:g}",
                        f"{dc:g}",
                        variant,
                        str(ref),
                        str(e["inertia"]),
                        "yes" if decision else "NO",
                        str(rec["torque_blocks_off"]),
                        f"{e['cond_L']:.1e}",
                        f"{berr[0]:.0e} / {berr[-1]:.0e}",
                    ]
                )
    head = ["matrix", "delta_w", "delta_c", "regularised rows", "block LDL^T inertia", "Riccati order inertia"]
    head += ["same decision", "torque blocks off", "max cond L", "backward error: plain / refined x3"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r_) + " |" for r_ in table]
    show_table("\n".join(lines), args.md)
    flops = float(np.median([r_["flops_per_interval"] for r_ in records]))
    print(f"elimination: {flops / 1e3:.0f} kflop per interval (median)")
    write({"reg": args.reg, "N": layout.N, "records": records}, args.out)


if __name__ == "__main__":
    main()
