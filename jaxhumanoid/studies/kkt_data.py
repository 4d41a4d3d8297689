"""The KKT matrices of T1's stage-2 NLP (A,F+C,2S, N = 100) as the IPM sees them near the points
IPOPT passes through, for the benchmarks of the IPM's KKT solves (``scripts/bench_kkt.py``,
``scripts/bench_kkt_methods.py``), and an independent check of a solve's accuracy.

``make_data`` solves the interpolated 2S start with IPOPT's stage-2 options, stopped after 3 and
30 iterations and run to the end; at each point it evaluates the Lagrangian Hessian (IPOPT's
multipliers) and the Jacobian and forms the barrier diagonals as the IPM forms them
(Sigma_x = z_l / (x - x_l) + z_u / (x_u - x); inequality rows -1 / Sigma_s with
Sigma_s = |lambda| / slack; equality rows 0). A fourth matrix ("synth") takes the final point with
log-uniform Sigma_x and D_c in 1e-8 .. 1e8. The data are cached in a ``.npz`` file.
"""

from __future__ import annotations

import pathlib

import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp

from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.handover import STAGE2_DEFAULTS, interpolate_full
from jaxhumanoid.studies.bench import BENCH_STAGE1_OPTIONS, stage1_problem


def make_data(path: str) -> dict[str, np.ndarray]:
    """Hessian/Jacobian values and barrier diagonals at IPOPT iterates of T1's stage 2 (cached)."""
    p = pathlib.Path(path)
    if p.exists():
        z = np.load(p, allow_pickle=False)
        return {k: z[k] for k in z.files}
    first, prob = stage1_problem("T1")
    nlp, b = prob.nlp, prob.bounds
    r1 = solve_ipopt(first.nlp, first.p, first.bounds, options=BENCH_STAGE1_OPTIONS)
    Zf = interpolate_full(first.full(r1.x), float(prob.p.T), prob.layout)
    x0 = np.clip(np.asarray(tr.free_from_full(prob.layout, Zf)), b.xl, b.xu)
    out: dict[str, np.ndarray] = {}
    for label, iters in (("it3", 3), ("it30", 30), ("final", 3000)):
        r = solve_ipopt(nlp, prob.p, b, x0=x0, options={**STAGE2_DEFAULTS, "max_iter": iters})
        x, lam = np.asarray(r.x), np.asarray(r.lam_g)
        hv = np.asarray(nlp.hess_values(jnp.asarray(x), jnp.asarray(lam), 1.0, prob.p))
        jv = np.asarray(nlp.jac_values(jnp.asarray(x), prob.p))
        g = np.asarray(nlp.g(jnp.asarray(x), prob.p))
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = np.where(np.isfinite(b.xl), r.z_l / np.maximum(x - b.xl, 1e-20), 0.0) + np.where(
                np.isfinite(b.xu), r.z_u / np.maximum(b.xu - x, 1e-20), 0.0
            )
            ineq = b.gl < b.gu
            s = np.clip(g, b.gl, b.gu)
            slack = np.minimum(
                np.where(np.isfinite(b.gl), s - b.gl, np.inf), np.where(np.isfinite(b.gu), b.gu - s, np.inf)
            )
            sig_s = np.abs(lam) / np.maximum(slack, 1e-20)
            dc = np.where(ineq, -1.0 / np.maximum(sig_s, 1e-20), 0.0)
        out[f"{label}_hess"], out[f"{label}_jac"] = hv, jv
        out[f"{label}_dx"], out[f"{label}_dc"] = sx, dc
        out[f"{label}_iters"] = np.asarray(r.iterations)
        print(
            f"  {label}: IPOPT {r.iterations} iterations, {r.status}; Sigma_x in "
            f"[{sx[sx > 0].min():.1e}, {sx.max():.1e}], -D_c in [{dc[dc < 0].min():.1e}, {dc[dc < 0].max():.1e}]"
        )
    rng = np.random.default_rng(0)
    bounded = np.isfinite(b.xl) | np.isfinite(b.xu)
    out["synth_hess"], out["synth_jac"] = out["final_hess"], out["final_jac"]
    out["synth_dx"] = np.where(bounded, 10.0 ** rng.uniform(-8, 8, nlp.n), 0.0)
    out["synth_dc"] = np.where(b.gl < b.gu, -(10.0 ** rng.uniform(-8, 8, nlp.m)), 0.0)
    out["synth_iters"] = out["final_iters"]
    for k, v in dict(
        n=nlp.n,
        m=nlp.m,
        var_stage=nlp.var_stage,
        con_stage=nlp.con_stage,
        hess_rows=nlp.hess_rows,
        hess_cols=nlp.hess_cols,
        jac_rows=nlp.jac_rows,
        jac_cols=nlp.jac_cols,
    ).items():
        out[k] = np.asarray(v)
    p.parent.mkdir(parents=True, exist_ok=True)
    np.savez(p, **out)  # type: ignore[arg-type]
    return out


def sparse_kkt(D, hv, jv, dx, dc):
    """The sparse KKT matrix [[W + diag(dx), J^T], [J, diag(dc)]] of one point of ``make_data``'s data."""
    n, m = int(D["n"]), int(D["m"])
    hr, hc, jr, jc = D["hess_rows"], D["hess_cols"], D["jac_rows"], D["jac_cols"]
    W = sp.coo_matrix((hv, (hr, hc)), shape=(n, n)).tocsr()
    W = W + sp.triu(W.T, k=1) + sp.diags(dx)
    J = sp.coo_matrix((jv, (jr, jc)), shape=(m, n)).tocsr()
    return sp.bmat([[W, J.T], [J, sp.diags(dc)]]).tocsc()


def ruiz(K, passes: int = 30):
    """Symmetric Ruiz scaling s of a sparse symmetric K (numpy; independent of kkt.equilibrate):
    S K S has rows of unit infinity norm. A diagonal congruence: inertia unchanged."""
    K = sp.csr_matrix(K)
    s = np.ones(K.shape[0])
    for _ in range(passes):
        Ks = sp.diags(s) @ K @ sp.diags(s)
        rmax = np.asarray(abs(Ks).max(axis=1).todense()).ravel()
        s = s / np.sqrt(np.where(rmax > 0, rmax, 1.0))
    return s


def backward_error(Ks, s, u, r):
    """Normwise backward error of u for K u = r, measured in the equilibrated system S K S."""
    v = u / s
    res = Ks @ v - s * r
    knorm = abs(Ks).sum(axis=1).max()
    return float(np.max(np.abs(res)) / (knorm * np.max(np.abs(v)) + np.max(np.abs(s * r))))
