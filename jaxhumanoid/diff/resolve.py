"""IPOPT re-solves for sensitivity work: warm-started, tightly converged, and continued.

``resolve`` warm-starts IPOPT from a previous KKT point (primal and dual, ``WARM_OPTIONS``);
``resolve_robust`` adds fall-backs; ``reference_solve`` is a tight cold solve with option
fall-backs; ``continuation_solve`` follows one branch of local optima from one parameter value
to another in short sub-steps. A warm start is anything with the fields ``x, lam_g, z_l, z_u``
(an ``NLPResult`` or an ``adjoint.KKTPoint``).
"""

from __future__ import annotations

import jax
import numpy as np

from jaxhumanoid.solvers.ipopt import solve_ipopt

WARM_OPTIONS = {
    "warm_start_init_point": "yes",
    "warm_start_bound_push": 1e-12,
    "warm_start_bound_frac": 1e-12,
    "warm_start_slack_bound_push": 1e-12,
    "warm_start_slack_bound_frac": 1e-12,
    "warm_start_mult_bound_push": 1e-12,
    "mu_init": 1e-9,
}

REFERENCE_FALLBACKS: tuple[dict, ...] = (
    {},
    {"mu_strategy": "adaptive"},
    {"mu_init": 1e-2},
    {"bound_push": 1e-4, "bound_frac": 1e-4},
    {"mu_strategy": "adaptive", "mu_init": 1e-3},
)


def resolve(problem, p=None, bounds=None, warm=None, options: dict | None = None):
    """IPOPT solve of ``problem`` at parameters ``p`` (default problem.p) and ``bounds``; ``warm`` a
    KKT point whose x and multipliers warm-start the solve (``WARM_OPTIONS``). Returns an NLPResult."""
    p = problem.p if p is None else p
    bounds = problem.bounds if bounds is None else bounds
    opts = {**(WARM_OPTIONS if warm is not None else {}), **(options or {})}
    x0 = np.clip(np.asarray(bounds.x0 if warm is None else warm.x, dtype=float), bounds.xl, bounds.xu)
    return solve_ipopt(problem.nlp, p, bounds, x0=x0, options=opts, warm=warm)


def resolve_robust(problem, p=None, bounds=None, warm=None, options: dict | None = None):
    """``resolve`` with fall-backs: primal-dual warm start at mu 1e-9, then at mu 1e-4 (for large
    parameter changes), then a cold start. Returns the first successful result (or the last)."""
    tries = [dict(options or {})]
    if warm is not None:
        tries.append(
            {**(options or {}), "mu_init": 1e-4, "warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6}
        )
    res = None
    for opts in tries:
        res = resolve(problem, p=p, bounds=bounds, warm=warm, options=opts)
        if res.success:
            return res
    if warm is not None:
        res = resolve(problem, p=p, bounds=bounds, warm=None, options=options)
    return res


def reference_solve(problem, tol: float = 1e-10, max_iter: int = 3000, verbose: bool = False):
    """A tightly converged cold solve for sensitivity work, with option fall-backs.

    The cold 1S solve of small problems (T1, N = 15) is reproducible within a process but not
    across processes (the same options gave Solve_Succeeded in 99 or 220 iterations, or
    Infeasible_Problem_Detected); the fall-backs (``REFERENCE_FALLBACKS``) make the reference
    solve robust to that. Returns the first successful NLPResult with ``history['attempt']`` set.
    """
    res = None
    for k, extra in enumerate(REFERENCE_FALLBACKS):
        res = solve_ipopt(problem.nlp, problem.p, problem.bounds, options={"tol": tol, "max_iter": max_iter, **extra})
        if verbose:
            print(f"reference solve attempt {k} {extra}: {res.status}, {res.iterations} its, f = {res.objective:.6g}")
        if res.success:
            res.history = {**(res.history or {}), "attempt": k}
            return res
    raise RuntimeError(f"reference_solve: every attempt failed (last: {res.status if res else None})")


def _interpolate(a, b, t: float):
    """Point t in [0, 1] of the path from leaf a to leaf b: geometric where both ends have the
    same strict sign (weights, masses: equal relative changes per sub-step), else linear."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    same = (a * b) > 0
    geo = np.sign(a) * np.abs(a) ** (1 - t) * np.abs(np.where(same, b, a)) ** t
    return np.where(same, geo, a + t * (b - a))


def _substeps(a, b, max_rel_step: float) -> float:
    """Sub-steps needed from leaf a to leaf b: log-ratio over log(1 + max_rel_step) where both
    ends have the same strict sign, else the change over max_rel_step of the larger end."""
    same = (a * b) > 0
    geo = np.abs(np.log(np.where(same, b, 1.0) / np.where(same, a, 1.0))) / np.log1p(max_rel_step)
    lin = np.abs(b - a) / (max_rel_step * np.maximum(np.abs(a), np.abs(b)) + 1e-12)
    return float(np.max(np.where(same, geo, lin), initial=0.0))


def continuation_solve(
    problem, p_from, res_from, p_to, max_rel_step: float = 0.25, bounds=None, options: dict | None = None
):
    """Follow the branch of local optima through ``res_from`` (at ``p_from``) to ``p_to``.

    The OCP has several local optima; a warm start after a long parameter step can land on
    another branch. The path (``_interpolate``) is cut into k sub-steps so that no leaf of p
    changes by more than a factor ``1 + max_rel_step`` (or, for leaves through zero, by more
    than ``max_rel_step`` of its size) per sub-step, each warm-started from the previous one.
    """
    leaves_a = [np.asarray(a, dtype=float) for a in jax.tree.leaves(p_from)]
    leaves_b = [np.asarray(b, dtype=float) for b in jax.tree.leaves(p_to)]
    if not max_rel_step > 0:
        raise ValueError(f"max_rel_step: expected > 0, got {max_rel_step!r}")
    k = max(1, int(np.ceil(max(_substeps(a, b, max_rel_step) for a, b in zip(leaves_a, leaves_b)) - 1e-9)))
    treedef = jax.tree.structure(p_from)
    res = res_from
    for i in range(1, k + 1):
        p_i = (
            p_to
            if i == k
            else jax.tree.unflatten(treedef, [_interpolate(a, b, i / k) for a, b in zip(leaves_a, leaves_b)])
        )
        res = resolve_robust(problem, p=p_i, bounds=bounds, warm=res, options=options)
        if not res.success:
            break
    return res
