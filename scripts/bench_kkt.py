"""Benchmark: the IPM's block-tridiagonal KKT factorisation (the ``solvers/ipm/kkt`` package) on real
humanoid KKT matrices.

    OMP_NUM_THREADS=1 python scripts/bench_kkt.py [--repeats 20] [--out results/bench_kkt.json]
                                                  [--data /tmp/bench_kkt_data.npz] [--no-check]
                                                  [--baseline-kkt old_kkt.py]

The matrices are those of T1's stage-2 NLP at N = 100 (A,F+C,2S), as the IPM sees them near the
points IPOPT passes through: the interpolated 2S warm start is solved by IPOPT with the 2S stage-2
options, stopped after 3 and 30 iterations and run to the end; at each point the Hessian of the
Lagrangian (IPOPT's multipliers) and the Jacobian are evaluated, and the barrier diagonals are
formed as the IPM forms them (Sigma_x = z_l / (x - x_l) + z_u / (x_u - x), inequality rows
-1 / Sigma_s with Sigma_s = |lambda| / slack; equality rows 0). One further matrix ("synth")
takes the final point with synthetic log-uniform Sigma_x and D_c in 1e-8 .. 1e8. The NLP data
are cached in ``--data`` (IPOPT takes a minute), the reference eigenvalues next to it.

For each matrix: IPOPT's inertia correction on ``factor``'s inertia picks delta_c = 1e-9 if K is
singular and the smallest delta_w in {0, 1e-4 * 8^j} giving inertia (n, m, 0); the cases are
(0, 0), (0, delta_c) and (delta_w, delta_c). For each case:
  - time (median of ``--repeats``, jitted, wall and CPU) of ``factor``, one plain block solve
    (``solve_vec``) and ``solve`` with the IPM's refinement settings (min 1, max 10 steps,
    ratio 1e-10), and the refinement steps taken,
  - the number of pivot blocks off the quasi-definite fast path (eigendecomposed),
  - accuracy: normwise backward error of the refined solve in the Ruiz-equilibrated system (an
    independent numpy equilibration), and of ``scipy.sparse.linalg.spsolve`` on the same
    equilibrated system, and their relative difference,
  - inertia from ``factor`` against dense ``numpy.linalg.eigvalsh`` of the equilibrated K (a
    congruence): "OK" when equal, eigenvalues with |eig| <= n eps max|eig| (third number) counted
    as either sign or zero.
``--baseline-kkt FILE`` runs the same for another version of the module given as one file (the
``kkt.py`` of a revision where it is a single module) and then times both in alternation (one call
of each per round), so that a varying load on the machine affects both alike.
Set OMP_NUM_THREADS=1 when comparing with other runs; report ``uptime`` next to the numbers.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import hashlib
import importlib.util
import os
import pathlib
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.solvers.ipm.kkt.assembly import equilibrate_compact
from jaxhumanoid.solvers.ipm.kkt.pivot import pivot
from jaxhumanoid.studies.bench import time_fn, write_record
from jaxhumanoid.studies.kkt_data import backward_error, make_data, ruiz, sparse_kkt


# ------------------------------------------------------------------------------------ data
def dense_inertia(Ks, cache_dir: pathlib.Path):
    """Eigenvalues of the equilibrated K (dense eigvalsh, cached by hash): (number > tol, number
    < -tol, number within [-tol, tol], min |eig|), tol = n eps max|eig|: the signs of the
    eigenvalues within the band are not determined by double precision."""
    Kd = Ks.toarray()
    key = hashlib.sha1(Kd.tobytes()).hexdigest()[:16]
    f = cache_dir / f"eig_{key}.npy"
    if f.exists():
        ev = np.load(f)
    else:
        ev = np.linalg.eigvalsh(Kd)
        np.save(f, ev)
    tol = ev.size * np.finfo(float).eps * np.max(np.abs(ev))
    npos, nneg = int(np.sum(ev > tol)), int(np.sum(ev < -tol))
    return npos, nneg, int(ev.size - npos - nneg), float(np.min(np.abs(ev)))


def inertia_consistent(ours, ref) -> bool:
    """``factor``'s (npos, nneg, nzero) against eigvalsh's (npos, nneg, n_band): equal, or each
    eigenvalue in the undetermined band |eig| <= n eps max|eig| counted as one of the three."""
    (p, n, z), (p0, n0, b) = ours, ref
    return p0 <= p <= p0 + b and n0 <= n <= n0 + b and z <= b and p + n + z == p0 + n0 + b


def baseline_slow_blocks(K, st, A, B):
    """Pivot blocks that fail the plain quasi-definite test (Cholesky of P and of minus the
    Schur complement), simulated in numpy on the exact D_k sequence: for versions of the module
    without ``pivot_paths``."""
    d = K.equilibrate(A, B)
    As, Bs = (np.asarray(v) for v in K.scale_blocks(A, B, d))
    rb, cb, nbx = st.b_rows, st.b_cols, st.nbx
    C = np.zeros((rb.size, rb.size))
    slow = 0
    for k in range(st.S):
        Dk = As[k].copy()
        Dk[np.ix_(rb, rb)] -= C
        Dk = 0.5 * (Dk + Dk.T)
        try:
            Lp = np.linalg.cholesky(Dk[:nbx, :nbx])
            W = np.linalg.solve(Lp, Dk[:nbx, nbx:])
            np.linalg.cholesky(W.T @ W - Dk[nbx:, nbx:])
        except np.linalg.LinAlgError:
            slow += 1
        Dinv = np.linalg.pinv(Dk, hermitian=True)
        bs = Bs[k][np.ix_(rb, cb)]
        C = bs @ Dinv[np.ix_(cb, cb)] @ bs.T
    return slow


def count_slow(K, st, A, B):
    if hasattr(K, "pivot_paths"):
        paths = np.asarray(jax.jit(lambda A, B: K.pivot_paths(st, A, B))(A, B))
        return {"slow_blocks": int(np.sum(paths == 2))}
    return {"slow_blocks": baseline_slow_blocks(K, st, A, B)}


def find_shift(st, A, B):
    """IPOPT's inertia correction on the ``factor`` inertia: delta_c = 1e-9 if K is singular, then
    the smallest delta_w in {0, 1e-4 * 8^j} giving inertia (n, m, 0); (None, dc) if none <= 1e4."""
    fac = kkt.factor(st, A, B)
    dc = 1e-9 if int(fac.nzero) > 0 else 0.0
    for j in range(-1, 14):
        dw = 0.0 if j < 0 else 1e-4 * 8.0**j
        A2 = kkt.add_diagonal(st, A, jnp.full(st.n, dw), jnp.full(st.m, -dc))
        if bool(kkt.inertia_ok(st, kkt.factor(st, A2, B))):
            return dw, dc
    return None, dc


def run_case(K, st, D, label, dw, dcr, repeats, check, cache_dir):
    """One KKT matrix with ``kkt`` module K (and its structure st)."""
    hv, jv = D[f"{label}_hess"], D[f"{label}_jac"]
    dx, dc = D[f"{label}_dx"] + dw, D[f"{label}_dc"] - dcr
    A, B = K.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    rng = np.random.default_rng(1)
    rx, rc = jnp.asarray(rng.standard_normal(st.n)), jnp.asarray(rng.standard_normal(st.m))
    f_factor = jax.jit(lambda A, B: K.factor(st, A, B))
    fac = f_factor(A, B)
    r_blk = K.to_blocks(st, rx, rc)
    f_plain = jax.jit(lambda fac, B, r: _plain_solve(K, st, fac, B, r))
    f_solve = jax.jit(lambda fac, A, B, rx, rc: K.solve(st, fac, A, B, rx, rc, 1, 10, 1e-10))
    # refinement steps taken: re-run the loop's own rule
    f_steps = jax.jit(lambda fac, A, B, rx, rc: _refinement_steps(K, st, fac, A, B, rx, rc))
    out = {"label": label, "delta_w": dw, "delta_c": dcr}
    out["factor"] = time_fn(f_factor, A, B, repeats=repeats)
    out["plain_solve"] = time_fn(f_plain, fac, B, r_blk, repeats=repeats)
    out["solve_refined"] = time_fn(f_solve, fac, A, B, rx, rc, repeats=repeats)
    out["refinement_steps"] = int(f_steps(fac, A, B, rx, rc))
    if K is kkt:
        out["batched_pivots"] = batched_pivots(st, A, B, repeats)
    out.update(count_slow(K, st, A, B))
    ux, uc = f_solve(fac, A, B, rx, rc)
    u = np.concatenate([np.asarray(ux), np.asarray(uc)])
    r = np.concatenate([np.asarray(rx), np.asarray(rc)])
    Kmat = sparse_kkt(D, hv, jv, dx, dc)
    s = ruiz(Kmat)
    Ks = (sp.diags(s) @ Kmat @ sp.diags(s)).tocsc()
    out["backward_error"] = backward_error(Ks, s, u, r)
    out["inertia"] = [int(fac.npos), int(fac.nneg), int(fac.nzero)]
    out["inertia_ok"] = bool(K.inertia_ok(st, fac))
    if check:
        ref = s * spla.spsolve(Ks, s * r)
        out["spsolve_backward_error"] = backward_error(Ks, s, ref, r)
        out["rel_diff_spsolve"] = float(np.linalg.norm((u - ref) / s) / np.linalg.norm(ref / s))
        npos, nneg, nzero, minabs = dense_inertia(Ks, cache_dir)
        out["inertia_eigvalsh"] = [npos, nneg, nzero]  # nzero: |eig| <= n eps max|eig|
        out["min_abs_eig_equilibrated"] = minabs
        out["inertia_match"] = inertia_consistent(out["inertia"], out["inertia_eigvalsh"])
    return out


def batched_pivots(st, A, B, repeats):
    """Times of the pivot factorisations of all S equilibrated diagonal blocks (fill left out) at
    once under ``vmap``, and of every second one: the work of the first levels of an odd-even
    (cyclic-reduction) elimination, against the sequential block loop of ``factor``."""
    _, As, _ = equilibrate_compact(st, A, B)
    tol = 10.0 * st.nb * float(np.finfo(np.float64).eps)
    f = jax.jit(jax.vmap(lambda D: pivot(0.5 * (D + D.T), st.nbx, True, tol)))
    return {"all": time_fn(f, As, repeats=repeats), "every_second": time_fn(f, As[1::2], repeats=repeats)}


def _plain_solve(K, st, fac, B, r):
    """One pass of the block solve (no refinement): the package's ``solve_vec``, or the private
    ``_solve_vec`` of a single-file baseline (with or without the border coupling argument)."""
    if hasattr(K, "solve_vec"):
        return K.solve_vec(st, fac, K.border_coupling(st, fac, B), r)
    if hasattr(K, "_border_coupling"):
        return K._solve_vec(st, fac, K._border_coupling(st, fac, B), r)
    return K._solve_vec(st, fac, r)


def _refinement_steps(K, st, fac, A, B, rx, rc, min_steps=1, max_steps=10, ratio_max=1e-10):
    """The number of refinement steps ``solve`` takes (same rule, counted)."""
    r = K.to_blocks(st, rx, rc)
    dr = jnp.max(jnp.abs(fac.d * r))
    u = jnp.zeros_like(r)
    res = r
    steps = jnp.zeros((), jnp.int32)
    done = jnp.zeros((), bool)
    for t in range(max_steps + 1):
        ratio = jnp.max(jnp.abs(fac.d * res)) / jnp.maximum(jnp.max(jnp.abs(u / fac.d)) + dr, 1e-300)
        go = (~done) & ((t <= min_steps) | (ratio > ratio_max))
        done = ~go
        u_new = u + _plain_solve(K, st, fac, B, res)
        u = jnp.where(go, u_new, u)
        res = jnp.where(go, r - K.matvec(A, B, u), res)
        steps = steps + go.astype(jnp.int32)
    return steps - 1  # the first pass is the plain solve


def interleaved(cases, repeats):
    """Median wall/CPU ms of several jitted calls timed in alternation (one call of each per
    round), so that a varying load on a shared machine affects all alike."""
    for fn, args in cases.values():
        jax.block_until_ready(fn(*args))
    wall = {k: [] for k in cases}
    cpu = {k: [] for k in cases}
    for _ in range(repeats):
        for k, (fn, args) in cases.items():
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn(*args))
            wall[k].append((time.perf_counter() - t0) * 1e3)
            cpu[k].append((time.process_time() - c0) * 1e3)
    return {
        k: {
            "median_ms": float(np.median(wall[k])),
            "cpu_median_ms": float(np.median(cpu[k])),
            "min_ms": float(np.min(wall[k])),
        }
        for k in cases
    }


def load_module(path: str):
    """A single-file kkt module from ``path``, importable as ``kkt_baseline``."""
    spec = importlib.util.spec_from_file_location("kkt_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look the module up
    spec.loader.exec_module(mod)
    return mod


def structure_for(K, D):
    """The static KKT structure of the matrices in ``D`` built by the kkt module ``K``."""
    return K.build_structure(
        int(D["n"]),
        int(D["m"]),
        D["var_stage"],
        D["con_stage"],
        D["hess_rows"],
        D["hess_cols"],
        D["jac_rows"],
        D["jac_cols"],
    )


def compare(D, K_old, repeats, labels):
    """Interleaved timing of the baseline module against this kkt package on the same matrices."""
    sts = {name: structure_for(K, D) for name, K in (("old", K_old), ("new", kkt))}
    rows = []
    rng = np.random.default_rng(1)
    rx, rc = jnp.asarray(rng.standard_normal(int(D["n"]))), jnp.asarray(rng.standard_normal(int(D["m"])))
    for label, dw, dc in labels:
        cases = {}
        for name, K in (("old", K_old), ("new", kkt)):
            st = sts[name]
            A, B = K.assemble(
                st,
                jnp.asarray(D[f"{label}_hess"]),
                jnp.asarray(D[f"{label}_jac"]),
                jnp.asarray(D[f"{label}_dx"] + dw),
                jnp.asarray(D[f"{label}_dc"] - dc),
            )
            ff = jax.jit(lambda A, B, K=K, st=st: K.factor(st, A, B))
            fac = ff(A, B)
            fs = jax.jit(lambda fac, A, B, rx, rc, K=K, st=st: K.solve(st, fac, A, B, rx, rc, 1, 10, 1e-10))
            fp = jax.jit(lambda fac, B, r, K=K, st=st: _plain_solve(K, st, fac, B, r))
            cases[f"{name}_factor"] = (ff, (A, B))
            cases[f"{name}_plain"] = (fp, (fac, B, K.to_blocks(st, rx, rc)))
            cases[f"{name}_refined"] = (fs, (fac, A, B, rx, rc))
        t = interleaved(cases, repeats)
        row = {"label": label, "delta_w": dw, "delta_c": dc, "times": t}
        rows.append(row)
        print(
            f"{label:6s} dw={dw:7.1e} dc={dc:5.0e}"
            f"  factor {t['old_factor']['median_ms']:6.2f} -> {t['new_factor']['median_ms']:6.2f} ms"
            f" (cpu {t['old_factor']['cpu_median_ms']:6.2f} -> {t['new_factor']['cpu_median_ms']:6.2f})"
            f"  plain {t['old_plain']['median_ms']:5.2f} -> {t['new_plain']['median_ms']:5.2f}"
            f"  refined {t['old_refined']['median_ms']:5.2f} -> {t['new_refined']['median_ms']:5.2f} ms",
            flush=True,
        )
    return rows


def uptime() -> str:
    try:
        return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    except OSError:
        return ""


def _print_case(r, S):
    print(
        f"  {r['module']:3s} {r['label']:6s} dw={r['delta_w']:7.1e} dc={r['delta_c']:5.0e}"
        f" factor {r['factor']['median_ms']:6.2f} ms"
        f" (cpu {r['factor']['cpu_median_ms']:6.2f})  plain {r['plain_solve']['median_ms']:5.2f}  refined"
        f" {r['solve_refined']['median_ms']:5.2f} ms ({r['refinement_steps']:2d} st)  slow {r['slow_blocks']:3d}/{S}"
        + (
            f"  batched pivots {r['batched_pivots']['all']['median_ms']:5.2f}"
            f" (every second {r['batched_pivots']['every_second']['median_ms']:5.2f})"
            if "batched_pivots" in r
            else ""
        )
        + f"  berr {r['backward_error']:.0e}"
        + (
            f" (spsolve {r['spsolve_backward_error']:.0e}, diff {r['rel_diff_spsolve']:.0e})"
            f"  inertia {tuple(r['inertia'])}"
            f" eig {tuple(r['inertia_eigvalsh'])} {'OK' if r['inertia_match'] else 'MISMATCH'}"
            if "inertia_eigvalsh" in r
            else f"  inertia {tuple(r['inertia'])}"
        ),
        flush=True,
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--out", default="results/bench_kkt.json")
    ap.add_argument("--data", default="/tmp/bench_kkt_data.npz")
    ap.add_argument("--labels", nargs="*", default=["it3", "it30", "final", "synth"])
    ap.add_argument("--no-check", action="store_true", help="skip the spsolve and eigvalsh references")
    ap.add_argument(
        "--baseline-kkt",
        default=None,
        help="a single-file kkt.py (`git show REV:jaxhumanoid/solvers/ipm/kkt.py > old.py`): "
        "the same checks for it, and timings interleaved with this one's",
    )
    args = ap.parse_args()
    D = make_data(args.data)
    cache_dir = pathlib.Path(args.data).with_suffix(".eig")
    cache_dir.mkdir(exist_ok=True)
    modules = [("new", kkt)] + ([("old", load_module(args.baseline_kkt))] if args.baseline_kkt else [])
    sts = {name: structure_for(K, D) for name, K in modules}
    st = sts["new"]
    load_before = uptime()
    print(f"n={st.n} m={st.m} S={st.S} nb={st.nb} nbx={st.nbx}; {load_before}")
    rows, shifts = [], []
    for label in args.labels:
        hv, jv, dx, dc = (jnp.asarray(D[f"{label}_{k}"]) for k in ("hess", "jac", "dx", "dc"))
        A, B = kkt.assemble(st, hv, jv, dx, dc)
        dw, dcr = find_shift(st, A, B)
        cases = [(0.0, 0.0)] + ([(0.0, dcr)] if dcr else []) + ([(dw, dcr)] if dw else [])
        for shift, dcs in cases:
            shifts.append((label, shift, dcs))
            for name, K in modules:
                r = run_case(K, sts[name], D, label, shift, dcs, args.repeats, not args.no_check, cache_dir)
                r["module"] = name
                rows.append(r)
                _print_case(r, st.S)
    results = {
        "n": st.n,
        "m": st.m,
        "S": st.S,
        "nb": st.nb,
        "nbx": st.nbx,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "uptime_before": load_before,
        "cases": rows,
    }
    if args.baseline_kkt:
        print(f"interleaved timings, baseline -> this kkt package (medians of {args.repeats}); {uptime()}")
        results["interleaved"] = compare(D, modules[1][1], args.repeats, shifts)
    results["uptime_after"] = load_after = uptime()
    print(load_after)
    write_record(results, args.out)


if __name__ == "__main__":
    main()
