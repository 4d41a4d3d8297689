"""Study: the KKT matrix eliminated in the order of a recursion over the node states, against the
block LDL^T, on T1's stage-2 KKT matrices.

    OMP_NUM_THREADS=1 python scripts/study_riccati_order.py [--data /tmp/bench_kkt_data.npz]
        [--reg 1e-9] [--out results/study_riccati_order.json] [--md results/study_riccati_order.md]

The matrices are those of ``bench_kkt.py`` (T1, A,F+C stage 2, N = 100, near IPOPT's 3rd and
30th iterates, at its solution, and with synthetic barrier terms), each with the shifts
(delta_w, delta_c) = (0, 0), (0, 1e-9) and (1e-4, 1e-9). The block LDL^T (``kkt.factor``) gives
the reference inertia. The same matrix is then eliminated, as a dense matrix in numpy, in the
order a Riccati recursion takes, interval k = N-1, ..., 0:

    G1(k): the contact forces f_k with the rows of their law (3)-(4), whose Jacobian in f_k is I,
    G2(k): the next state x_{k+1} with the rows (6a)-(6b) of interval k,
    G3(k): the torques u_k.

Where the end stages fix qd_{N-1} and qd_N, x_{k+1} pairs with the rows (6a) alone and u_k with
the rows (6b). The inequality rows (pivot -1/Sigma_s - delta_c before any update) go

    first:   each alone, before every interval (the barrier terms condensed into the Hessian),
    late:    each alone, in interval k just before G3(k),
    grouped: together with u_k in G3(k).

Variants pair an order with the matrix it eliminates: K itself, or K Ruiz-equilibrated
(``equilibrated``; a diagonal congruence, so the inertia is K's); ``regularised`` first puts
-``--reg`` on the diagonal of every constraint row where it is closer to zero (a dual
regularisation). Every pivot block is factored by LU with partial pivoting for the solve, and by
Bunch-Kaufman (``scipy.linalg.ldl``) for its inertia (signs of D's eigenvalues, zero only if
exactly zero); the rest is updated by the block's Schur complement. The solve is refined against
K itself (3 steps). Per case: the inertia of both, whether the IPM's decision (inertia (n, m, 0)
or not) agrees, the growth (largest entry of a Schur complement over the largest of the matrix
eliminated), the largest Schur complement each kind of block leaves
(``carried``: the unknowns it couples to, which a recursion carries), the normwise backward error of the solve after 0..3 refinements (in the
Ruiz-equilibrated system, as ``bench_kkt.py`` measures it), and the flops per interval.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse

import jax.numpy as jnp
import numpy as np
import scipy.linalg
from _bench import show_table, write
from bench_kkt import backward_error, make_data, ruiz, sparse_kkt

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.strategy.problem import build_problem

# (label, placement of the inequality rows, equilibrated, dual-regularised)
VARIANTS = (
    ("first", "first", False, False),
    ("first, equilibrated", "first", True, False),
    ("late", "late", False, False),
    ("late, equilibrated", "late", True, False),
    ("grouped", "grouped", False, False),
    ("grouped, equilibrated", "grouped", True, False),
    ("grouped, equilibrated, regularised", "grouped", True, True),
)
SHIFTS = ((0.0, 0.0), (0.0, 1e-9), (1e-4, 1e-9))


def groups(layout, n: int, ineq: str) -> list[tuple[str, np.ndarray]]:
    """(name, unknowns of K) in elimination order; ``ineq`` places the inequality rows."""
    N, nc, nq = layout.N, layout.n_con, layout.n_links
    free = layout.free_mask()
    vidx = np.full(free.shape, -1)
    vidx[free] = np.arange(n)
    sl = layout.stage_slices()
    ineq_rows = np.flatnonzero(layout.constraint_kinds() == 1)

    def var(k, name):
        ix = vidx[k, sl[name]]
        return ix[ix >= 0]

    def rows(k, lo, hi):
        return n + k * nc + np.arange(lo, hi)

    law = (2 * nq, 2 * nq + layout.n_f)
    out = [("ineq", np.array([r])) for k in range(N) for r in n + k * nc + ineq_rows] if ineq == "first" else []
    for k in range(N - 1, -1, -1):
        f, u, xq, xqd = var(k, "f"), var(k, "u"), var(k + 1, "q"), var(k + 1, "qd")
        out.append(("G1", np.concatenate([f, rows(k, *law)])))
        if xqd.size:
            out.append(("G2", np.concatenate([xq, xqd, rows(k, 0, 2 * nq)])))
            g3 = u
        else:
            out.append(("G2", np.concatenate([xq, rows(k, 0, nq)])))
            g3 = np.concatenate([u, rows(k, nq, 2 * nq)])
        mine = n + k * nc + ineq_rows
        if ineq == "late":
            out += [("ineq", np.array([r])) for r in mine]
        elif ineq == "grouped":
            g3 = np.concatenate([g3, mine])
        if g3.size:
            out.append(("G3", g3))
    return out


def block_inertia(P: np.ndarray) -> np.ndarray:
    """(npos, nneg, nzero) of a symmetric block by Bunch-Kaufman: the signs of D's eigenvalues."""
    _, d, _ = scipy.linalg.ldl(0.5 * (P + P.T))
    w = np.linalg.eigvalsh(d)
    return np.array([np.sum(w > 0), np.sum(w < 0), np.sum(w == 0)])


def eliminate(K: np.ndarray, order) -> dict:
    """Block elimination of the dense K in ``order``: the inertia, the growth, the flops, and the
    steps of ``solve``."""
    K = K.copy()
    alive = np.ones(K.shape[0], bool)
    tot = np.zeros(3, np.int64)
    kmax, growth, flops, steps = np.abs(K).max(), 1.0, 0.0, []
    carried: dict[str, int] = {}
    for name, g in order:
        alive[g] = False
        rest = np.flatnonzero(alive & np.any(K[g] != 0, axis=0))
        P = K[np.ix_(g, g)]
        tot += block_inertia(P)
        lu = scipy.linalg.lu_factor(P, check_finite=False)
        Kgr, Krg = K[np.ix_(g, rest)].copy(), K[np.ix_(rest, g)].copy()
        if rest.size:
            K[np.ix_(rest, rest)] -= Krg @ scipy.linalg.lu_solve(lu, Kgr, check_finite=False)
            growth = max(growth, float(np.abs(K[np.ix_(rest, rest)]).max() / kmax))
        a, b = g.size, rest.size
        carried[name] = max(carried.get(name, 0), b)
        flops += 2 * a**3 / 3 + 2 * a * a * b + 2 * a * b * b
        steps.append((g, rest, lu, Kgr, Krg))
    inertia = tuple(int(v) for v in tot)
    return {"inertia": inertia, "growth": growth, "flops": flops, "carried": carried, "steps": steps}


def solve(steps, r: np.ndarray) -> np.ndarray:
    """K^{-1} r by the forward and backward substitution of ``eliminate``'s steps."""
    r = r.copy()
    for g, rest, lu, _, Krg in steps:
        if rest.size:
            r[rest] -= Krg @ scipy.linalg.lu_solve(lu, r[g], check_finite=False)
    u = np.zeros_like(r)
    for g, rest, lu, Kgr, _ in reversed(steps):
        u[g] = scipy.linalg.lu_solve(lu, r[g] - (Kgr @ u[rest] if rest.size else 0.0), check_finite=False)
    return u


def regularised(K: np.ndarray, n: int, reg: float) -> np.ndarray:
    Kr = K.copy()
    ix = np.arange(n, K.shape[0])
    Kr[ix, ix] = np.minimum(Kr[ix, ix], -reg)
    return Kr


def run_variant(K, n, order, equilibrated, reg, Ke, sc, r) -> dict:
    """Eliminate (the equilibrated) K in ``order``; refine the solve against K itself."""
    Kw = regularised(K, n, reg) if reg else K
    s = ruiz(Kw) if equilibrated else np.ones(K.shape[0])
    with np.errstate(all="ignore"):
        try:
            e = eliminate(Kw * s[:, None] * s[None, :], order)
        except ValueError:  # a singular pivot block filled the rest with inf
            return {"failed": True}
        u = s * solve(e["steps"], s * r)
        berr = [backward_error(Ke, sc, u, r)]
        for _ in range(3):
            u = u + s * solve(e["steps"], s * (r - K @ u))
            berr.append(backward_error(Ke, sc, u, r))
    return {"failed": False, **{k: e[k] for k in ("inertia", "growth", "flops", "carried")}, "backward_error": berr}


def fmt(rec) -> list[str]:
    """The table cells of a record: inertia, decision, growth, backward errors."""
    if rec["failed"]:
        return ["failed"] * 4
    b = rec["backward_error"]
    cells = [str(rec["inertia"]), "yes" if rec["same_decision"] else "NO", f"{rec['growth']:.0e}"]
    return cells + [f"{b[0]:.0e} / {b[-1]:.0e}"]


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
    orders = {p: groups(layout, n, p) for p in ("first", "late", "grouped")}
    for order in orders.values():
        assert np.array_equal(np.sort(np.concatenate([g for _, g in order])), np.arange(n + m))
    st = kkt.build_structure(
        n, m, D["var_stage"], D["con_stage"], D["hess_rows"], D["hess_cols"], D["jac_rows"], D["jac_cols"]
    )
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
            for variant, place, equilibrated, reg in VARIANTS:
                e = run_variant(K, n, orders[place], equilibrated, args.reg if reg else 0.0, Ke, sc, r)
                same = not e["failed"] and e["inertia"] == ref
                decision = not e["failed"] and (e["inertia"] == (n, m, 0)) == (ref == (n, m, 0))
                rec = {"matrix": label, "delta_w": dw, "delta_c": dc, "variant": variant}
                rec |= {"block_ldl_inertia": ref, "same_inertia": same, "same_decision": decision}
                rec |= e
                if not e["failed"]:
                    rec["flops_per_interval"] = e["flops"] / layout.N
                records.append(rec)
                table.append([label, f"{dw:g}", f"{dc:g}", variant, str(ref), *fmt(rec)])
    head = ["matrix", "delta_w", "delta_c", "variant", "block LDL^T inertia", "Riccati order inertia"]
    head += ["same decision", "growth", "backward error: plain / refined x3"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r_) + " |" for r_ in table]
    show_table("\n".join(lines), args.md)
    summary = []
    for variant, *_ in VARIANTS:
        rs = [r_ for r_ in records if r_["variant"] == variant]
        ok = [r_ for r_ in rs if not r_["failed"]]
        shifted = [r_ for r_ in ok if r_["delta_c"] > 0]
        summary.append(
            {
                "variant": variant,
                "same_inertia": sum(r_["same_inertia"] for r_ in rs),
                "same_inertia_shifted": sum(r_["same_inertia"] for r_ in rs if r_["delta_c"] > 0),
                "same_decision": sum(r_["same_decision"] for r_ in rs),
                "cases": len(rs),
                "failed": len(rs) - len(ok),
                "max_growth": max(r_["growth"] for r_ in ok),
                "backward_error_shifted_plain": [
                    min(r_["backward_error"][0] for r_ in shifted),
                    max(r_["backward_error"][0] for r_ in shifted),
                ],
                "backward_error_shifted_refined": [
                    min(r_["backward_error"][-1] for r_ in shifted),
                    max(r_["backward_error"][-1] for r_ in shifted),
                ],
                "carried": ok[0]["carried"],
                "kflop_per_interval": float(np.median([r_["flops_per_interval"] for r_ in ok])) / 1e3,
            }
        )
        print(summary[-1])
    write({"reg": args.reg, "N": layout.N, "summary": summary, "records": records}, args.out)


if __name__ == "__main__":
    main()
