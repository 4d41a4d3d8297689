"""Correctness checks of the NLP (7): cross-validation against the independent CasADi model and
central finite differences of our own derivatives.

Every difference is reported as a relative infinity-norm error

    rel(a, b) = ||a - b||_inf / max(1, ||b||_inf)

with ``a`` our value and ``b`` the reference (CasADi, or the finite difference). Sparse matrices
are compared after scattering both into the same (n x n or m x n) coordinate space; Hessians as
their lower triangles (row >= col).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import scipy.sparse as sp

from jaxhumanoid.validation import casadi_backend as cb

CROSS_TOL = 1e-10
FD_TOL = 1e-4


@dataclasses.dataclass(frozen=True)
class CheckRow:
    """One line of a check report: ``value`` is a relative error (or a count for patterns)."""

    check: str
    quantity: str
    value: float
    tol: float

    @property
    def ok(self) -> bool:
        return bool(np.isfinite(self.value) and self.value <= self.tol)


def _rel(a, b) -> float:
    """||a - b||_inf / max(1, ||b||_inf) for arrays or scipy sparse matrices."""
    if sp.issparse(a) or sp.issparse(b):
        diff = sp.csr_matrix(a - b)
        dmax = float(np.max(np.abs(diff.data))) if diff.nnz else 0.0
        bmax = float(np.max(np.abs(sp.csr_matrix(b).data))) if sp.csr_matrix(b).nnz else 0.0
        return dmax / max(1.0, bmax)
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(np.max(np.abs(a - b), initial=0.0) / max(1.0, float(np.max(np.abs(b), initial=0.0))))


def _coo(values, rows, cols, shape) -> sp.csr_matrix:
    return sp.csr_matrix(sp.coo_matrix((np.asarray(values, dtype=np.float64), (rows, cols)), shape=shape))


def _casadi_sparse(dm) -> sp.csr_matrix:
    rows, cols = dm.sparsity().get_triplet()
    return _coo(np.asarray(dm.nonzeros()), np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64), dm.shape)


def _missing_entries(pattern: sp.csr_matrix, reference: sp.csr_matrix, rel_zero: float) -> int:
    """Count entries of ``reference`` with |value| > rel_zero * max(1, max|reference|) outside ``pattern``."""
    ref = sp.coo_matrix(reference)
    thresh = rel_zero * max(1.0, float(np.max(np.abs(ref.data), initial=0.0)))
    big = np.abs(ref.data) > thresh
    covered = set(zip(*sp.coo_matrix(pattern).nonzero()))
    return int(sum((r, c) not in covered for r, c in zip(ref.row[big], ref.col[big])))


def sample_points(bounds, num_points: int, seed: int = 0) -> np.ndarray:
    """Random points inside the bounds: uniform in [xl, xu] where both are finite, else the start
    point plus a standard normal perturbation (clipped to the one finite bound). Shape (k, n)."""
    if not isinstance(num_points, (int, np.integer)) or num_points < 0:
        raise ValueError(f"points: expected a non-negative integer, got {num_points!r}")
    rng = np.random.default_rng(seed)
    xl, xu, x0 = bounds.xl, bounds.xu, bounds.x0
    boxed = np.isfinite(xl) & np.isfinite(xu)
    out = np.empty((num_points, x0.size))
    for k in range(num_points):
        x = x0 + rng.standard_normal(x0.size)
        x[boxed] = rng.uniform(xl[boxed], xu[boxed])
        out[k] = np.clip(x, xl, xu)
    return out


def cross_validate(
    problem, points: int = 3, x=None, seed: int = 0, tol: float = CROSS_TOL, zero_tol: float = 1e-13
) -> list[CheckRow]:
    """Compare ``problem.nlp`` with its CasADi twin (``validation.casadi_backend``) at ``points`` random
    points inside the bounds (and at ``x`` if given), with random multipliers lam ~ N(0, 1) and
    sigma ~ U(0.5, 2) for the Lagrangian Hessian.

    Rows: f, grad f, g, Jacobian, Hessian (worst rel over the points, see module docstring), and
    "pattern" rows counting CasADi entries with |value| > zero_tol * max(1, max|value|) that lie
    outside our Jacobian/Hessian patterns (must be 0).
    """
    nlp, p = problem.nlp, problem.p
    xs = sample_points(problem.bounds, points, seed)
    if x is not None:
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (nlp.n,):
            raise ValueError(f"x: expected shape ({nlp.n},), got {x.shape}")
        xs = np.vstack([xs, x[None]])
    if xs.shape[0] == 0:
        raise ValueError("points: no point to check (points=0 and x=None)")
    ref = cb.derivative_function(cb.build_casadi_nlp(problem))
    f, g, grad = jax.jit(nlp.f), jax.jit(nlp.g), jax.jit(nlp.grad)
    jac_v, hess_v = jax.jit(nlp.jac_values), jax.jit(nlp.hess_values)
    rng = np.random.default_rng(seed + 1)
    worst = dict.fromkeys(("f", "grad f", "g", "jacobian", "hessian (tril)"), 0.0)
    missing = {"jacobian pattern": 0, "hessian pattern": 0}
    jac_pattern = _coo(np.ones(nlp.nnz_jac), nlp.jac_rows, nlp.jac_cols, (nlp.m, nlp.n))
    hess_pattern = _coo(np.ones(nlp.nnz_hess), nlp.hess_rows, nlp.hess_cols, (nlp.n, nlp.n))
    for xk in xs:
        lam, sigma = rng.standard_normal(nlp.m), float(rng.uniform(0.5, 2.0))
        f_ref, grad_ref, g_ref, jac_ref, hess_ref = ref(xk, lam, sigma)
        jac_ref, hess_ref = _casadi_sparse(jac_ref), _casadi_sparse(hess_ref)
        ours = {
            "f": np.asarray(f(xk, p)),
            "grad f": np.asarray(grad(xk, p)),
            "g": np.asarray(g(xk, p)),
            "jacobian": _coo(jac_v(xk, p), nlp.jac_rows, nlp.jac_cols, (nlp.m, nlp.n)),
            "hessian (tril)": _coo(hess_v(xk, lam, sigma, p), nlp.hess_rows, nlp.hess_cols, (nlp.n, nlp.n)),
        }
        theirs = {
            "f": np.asarray(f_ref).ravel(),
            "grad f": np.asarray(grad_ref).ravel(),
            "g": np.asarray(g_ref).ravel(),
            "jacobian": jac_ref,
            "hessian (tril)": hess_ref,
        }
        for key in worst:
            worst[key] = max(worst[key], _rel(ours[key], theirs[key]))
        missing["jacobian pattern"] += _missing_entries(jac_pattern, jac_ref, zero_tol)
        missing["hessian pattern"] += _missing_entries(hess_pattern, hess_ref, zero_tol)
    rows = [CheckRow("casadi", k, v, tol) for k, v in worst.items()]
    return rows + [CheckRow("casadi", k, float(v), 0.0) for k, v in missing.items()]


def _steps(x) -> np.ndarray:
    """h_i = eps^(1/3) max(1, |x_i|): the central-difference step balancing truncation and rounding."""
    return np.finfo(np.float64).eps ** (1.0 / 3.0) * np.maximum(1.0, np.abs(x))


def finite_difference_check(
    problem, x=None, columns: int = 40, directions: int = 3, seed: int = 0, tol: float = FD_TOL
) -> list[CheckRow]:
    """Central differences of our own derivatives at ``x`` (default: a random point inside the bounds).

    * grad f and the Jacobian column by column on ``columns`` random columns (all if n is smaller):
      (f, g)(x + h_j e_j) - (f, g)(x - h_j e_j) over 2 h_j;
    * Hessian-vector products: for ``directions`` random d = h o v (v ~ N(0, 1)), the central
      difference of grad_x L = sigma grad f + J^T lam along d, divided by t = eps^(1/3), against
      H d / t (so the direction d / t = max(1, |x|) o v is O(1)), H the full symmetric
      Hessian rebuilt from our lower triangle; separately for the objective (sigma = 1, lam = 0)
      and the constraints (sigma = 0, lam ~ N(0, 1)), so that the small objective curvature is
      not hidden under the stiff contact terms.

    Rows hold rel (module docstring) and the max absolute error as a second row per quantity.
    """
    nlp, p = problem.nlp, problem.p
    if not isinstance(columns, (int, np.integer)) or columns < 1:
        raise ValueError(f"columns: expected a positive integer, got {columns!r}")
    if not isinstance(directions, (int, np.integer)) or directions < 1:
        raise ValueError(f"directions: expected a positive integer, got {directions!r}")
    x = sample_points(problem.bounds, 1, seed)[0] if x is None else np.asarray(x, dtype=np.float64)
    if x.shape != (nlp.n,):
        raise ValueError(f"x: expected shape ({nlp.n},), got {x.shape}")
    rng = np.random.default_rng(seed + 2)
    f, g, grad = jax.jit(nlp.f), jax.jit(nlp.g), jax.jit(nlp.grad)
    jac_v, hess_v = jax.jit(nlp.jac_values), jax.jit(nlp.hess_values)
    h = _steps(x)
    J = _coo(jac_v(x, p), nlp.jac_rows, nlp.jac_cols, (nlp.m, nlp.n)).toarray()
    cols = np.sort(rng.choice(nlp.n, size=min(columns, nlp.n), replace=False))
    fd_grad, fd_jac = np.empty(cols.size), np.empty((nlp.m, cols.size))
    for k, j in enumerate(cols):
        e = np.zeros(nlp.n)
        e[j] = h[j]
        fd_grad[k] = (float(f(x + e, p)) - float(f(x - e, p))) / (2 * h[j])
        fd_jac[:, k] = (np.asarray(g(x + e, p)) - np.asarray(g(x - e, p))) / (2 * h[j])
    lam = rng.standard_normal(nlp.m)
    t = np.finfo(np.float64).eps ** (1.0 / 3.0)
    dirs = [h * rng.standard_normal(nlp.n) for _ in range(directions)]

    def hvp_pair(lam_k, sigma):
        def grad_lagrangian(xx):
            Jx = _coo(jac_v(xx, p), nlp.jac_rows, nlp.jac_cols, (nlp.m, nlp.n))
            return sigma * np.asarray(grad(xx, p)) + Jx.T @ lam_k

        tril = _coo(hess_v(x, lam_k, sigma, p), nlp.hess_rows, nlp.hess_cols, (nlp.n, nlp.n))
        H = tril + sp.tril(tril, -1).T
        ours = np.concatenate([H @ (d / t) for d in dirs])
        fd = np.concatenate([(grad_lagrangian(x + d) - grad_lagrangian(x - d)) / (2 * t) for d in dirs])
        return ours, fd

    pairs = {
        "grad f": (np.asarray(grad(x, p))[cols], fd_grad),
        "jacobian": (J[:, cols], fd_jac),
        "hessian-vector f": hvp_pair(np.zeros(nlp.m), 1.0),
        "hessian-vector lam.g": hvp_pair(lam, 0.0),
    }
    rows = []
    for key, (ours, fd) in pairs.items():
        rows.append(CheckRow("finite differences", key, _rel(ours, fd), tol))
        rows.append(
            CheckRow("finite differences", f"{key} (abs)", float(np.max(np.abs(ours - fd), initial=0.0)), np.inf)
        )
    return rows


DEFAULT_CASES = (
    ("T1", "E,F,1S", False),
    ("T1", "A,F,1S", False),
    ("T1", "A,F+C,1S", False),
    ("T1", "A,F+C,1S", True),
    ("T3", "E,F,1S", False),
    ("T3", "A,F,1S", False),
    ("T3", "A,F+C,1S", False),
    ("T3", "A,F+C,1S", True),
)


def case_label(task: str, scheme: str, pseudo_static: bool, N: int) -> str:
    """The row label of one check case."""
    return f"{task} {scheme}{' pseudo-static' if pseudo_static else ''} N={N}"


def check_table(problems, points: int = 2, seed: int = 0) -> list[dict]:
    """Run both checks on each ``(case, problem)`` pair; rows for a printed table
    (``jaxhumanoid check``): case, check, quantity, value, tol, ok. The caller builds the
    problems (``strategy.problem.build_problem``), e.g. for each of ``DEFAULT_CASES``."""
    rows = []
    for case, problem in problems:
        for row in cross_validate(problem, points=points, seed=seed) + finite_difference_check(problem, seed=seed):
            rows.append({"case": case, **dataclasses.asdict(row), "ok": row.ok})
    return rows


def format_table(rows: list[dict]) -> str:
    """Fixed-width text of ``check_table`` rows."""
    lines = [f"{'case':<32} {'check':<19} {'quantity':<24} {'value':>10} {'tol':>8}  ok"]
    for r in rows:
        lines.append(
            f"{r['case']:<32} {r['check']:<19} {r['quantity']:<24} {r['value']:>10.2e} {r['tol']:>8.0e}  "
            f"{'yes' if r['ok'] else 'NO'}"
        )
    return "\n".join(lines)
