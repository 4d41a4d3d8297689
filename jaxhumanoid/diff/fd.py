"""Finite-difference checks of the sensitivities, and the rows of ``jaxhumanoid check --sensitivities``.

``check_against_fd`` compares, per parameter group, dx* and dV* with central differences of
warm-started IPOPT re-solves (2-norm relative error below ``FD_TOL`` = 1e-4), records how far a
wrong sign, a missed active set and flipped multipliers miss the same differences (the check
must reject them), and measures the cost of a sensitivity against the cold solve.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np

from jaxhumanoid.diff.active_set import missed_active_set
from jaxhumanoid.diff.kkt import KKTSensitivity, bounds_for_goal
from jaxhumanoid.diff.resolve import reference_solve, resolve
from jaxhumanoid.diff.trees import rel_err, tree_vdot
from jaxhumanoid.strategy.problem import Problem, build_problem

GROUPS = ("weights", "contact", "model", "horizon", "start")
MODEL_GROUP_FIELDS = ("a", "c", "m", "inertia")
FD_TOL = 1e-4  # relative agreement required of every directional derivative


def param_direction(p, group: str, seed: int = 0):
    """A tangent of p that moves one parameter group by relative amounts in [-1, 1] (random,
    reproducible): weights (n + 3), contact (kappa, f0, xhat, mu), model (a, c, m, inertia),
    horizon (T), start (q_start, absolute radians). Everything else zero."""
    rng = np.random.default_rng(seed)
    dp = jax.tree.map(np.zeros_like, jax.tree.map(lambda a: np.asarray(a, dtype=float), p))

    def rel(a):
        a = np.asarray(a, dtype=float)
        return a * rng.uniform(-1.0, 1.0, size=a.shape)

    if group == "weights":
        return dataclasses.replace(dp, weights=rel(p.weights))
    if group == "contact":
        c = p.contact
        new = jax.tree.unflatten(jax.tree.structure(c), [rel(v) for v in jax.tree.leaves(c)])
        return dataclasses.replace(dp, contact=new)
    if group == "model":
        mdl = p.model
        moved = {name: rel(getattr(mdl, name)) for name in MODEL_GROUP_FIELDS}
        # a tangent is rebuilt by unflattening (the leaves are the fields in order): zero masses
        # would not pass the model's constructor
        leaves = [
            moved.get(f.name, np.zeros_like(np.asarray(getattr(mdl, f.name), dtype=float)))
            for f in dataclasses.fields(mdl)
            if not f.metadata.get("static")
        ]
        return dataclasses.replace(dp, model=jax.tree.unflatten(jax.tree.structure(mdl), leaves))
    if group == "horizon":
        return dataclasses.replace(dp, T=rel(p.T))
    if group == "start":
        return dataclasses.replace(dp, q_start=rng.uniform(-1.0, 1.0, size=np.shape(p.q_start)))
    raise ValueError(f"group: {group!r} not in {GROUPS}")


def perturb(p, dp, t: float):
    """p + t dp leaf by leaf (numpy leaves; validation bypassed as for any pytree map)."""
    return jax.tree.map(lambda a, d: np.asarray(a, dtype=float) + t * np.asarray(d, dtype=float), p, dp)


def fd_directional(problem, result, dp=None, dgoal=None, eps: float = 1e-5, options: dict | None = None):
    """Central differences of warm-started IPOPT re-solves along (dp, dgoal).

    Returns (dx_fd (n,), dV_fd, (res_plus, res_minus)). ``options`` default to tol 1e-10.
    """
    opts = {"tol": 1e-10, "acceptable_iter": 0, "max_iter": 500, **(options or {})}
    out = []
    for t in (eps, -eps):
        p = problem.p if dp is None else perturb(problem.p, dp, t)
        goal = None if dgoal is None else np.asarray(problem.task.goal) + t * np.asarray(dgoal)
        b = problem.bounds if dgoal is None else bounds_for_goal(problem, goal)
        res = resolve(problem, p=p, bounds=b, warm=result, options=opts)
        if not res.success:
            raise RuntimeError(f"fd_directional: re-solve at t={t:g} returned {res.status}")
        out.append(res)
    dx = (out[0].x - out[1].x) / (2 * eps)
    dV = (out[0].objective - out[1].objective) / (2 * eps)
    return dx, dV, tuple(out)


def mutation_errors(problem, result, kkt, dp, dx_fd) -> dict:
    """Relative errors of deliberately wrong sensitivities against the same finite differences:
    the check's tolerance must reject them (a wrong sign, a missed active set, multipliers read
    with the opposite sign convention)."""
    out = {"wrong_sign": rel_err(-kkt.jvp(dp), dx_fd)}
    for name, kw in (
        ("missed_active_set", {"active": missed_active_set(kkt.active)}),
        ("flipped_multipliers", {"lam_g": -np.asarray(result.lam_g)}),
    ):
        try:
            out[name] = rel_err(KKTSensitivity(problem, result, warn=False, **kw).jvp(dp), dx_fd)
        except np.linalg.LinAlgError:
            out[name] = np.inf  # singular reduced KKT matrix: no sensitivity at all
    return out


def _group_direction(p, group: str, seed: int):
    """(dp, dgoal) of one group: a ``param_direction`` or, for "goal", a random (n,) goal tangent."""
    if group == "goal":
        return None, np.random.default_rng(seed).uniform(-1, 1, p.model.n)
    return param_direction(p, group, seed=seed), None


def _group_row(prob, res, kkt, group: str, seed: int, eps: float) -> tuple[dict, object, np.ndarray]:
    """(row, dp, dx_fd) of one group: its dx*, dV* against finite differences, and the tangent."""
    dp, dgoal = _group_direction(prob.p, group, seed)
    kkt.jvp(dp, dgoal)  # compile
    t0 = time.perf_counter()
    dx = kkt.jvp(dp, dgoal)
    t_jvp = time.perf_counter() - t0
    dx_fd, dV_fd, rr = fd_directional(prob, res, dp, dgoal, eps=eps)
    g_env = kkt.objective_gradient(goal=True)
    dV_env = (tree_vdot(g_env[0], dp) if dp is not None else 0.0) + (
        float(g_env[1] @ dgoal) if dgoal is not None else 0.0
    )
    dV_chain = kkt.objective_jvp(dp, dgoal, dx=dx)
    row = {
        "group": group,
        "norm_dx": float(np.linalg.norm(dx)),
        "rel_err_dx_2norm": rel_err(dx, dx_fd),
        "rel_err_dx_maxnorm": float(np.max(np.abs(dx - dx_fd)) / np.max(np.abs(dx_fd))),
        "dropped_residual": kkt.dropped_residual,
        "dV_envelope": dV_env,
        "dV_chain": dV_chain,
        "dV_fd": dV_fd,
        "rel_err_dV_env_fd": abs(dV_env - dV_fd) / abs(dV_fd),
        "rel_err_dV_env_chain": abs(dV_env - dV_chain) / abs(dV_env),
        "jvp_time_s": t_jvp,
        "warm_resolve_iters": [r.iterations for r in rr],
        "warm_resolve_time_s": float(np.mean([r.solve_time_s for r in rr])),
    }
    return row, dp, dx_fd


def _cost(res, kkt, rows, ct, t_factor: float) -> dict:
    """Times of a factorisation, a JVP, a VJP and the envelope gradient against the solves."""
    kkt.vjp(ct)
    t0 = time.perf_counter()
    kkt.vjp(ct)
    t_vjp = time.perf_counter() - t0
    t0 = time.perf_counter()
    kkt.objective_gradient()
    t_env = time.perf_counter() - t0
    t_iter = res.solve_time_s / max(res.iterations, 1)
    t_jvp = float(np.median([r["jvp_time_s"] for r in rows]))
    c = {
        "cold_solve_time_s": res.solve_time_s,
        "cold_solve_iters": res.iterations,
        "time_per_solver_iteration_s": t_iter,
        "factorisation_time_s": t_factor,
        "jvp_time_s (after factorisation)": t_jvp,
        "vjp_time_s (after factorisation)": t_vjp,
        "envelope_gradient_time_s": t_env,
        "warm_resolve_time_s": float(np.mean([r["warm_resolve_time_s"] for r in rows])),
        "ratio_(factor+jvp)/cold_solve": (t_factor + t_jvp) / res.solve_time_s,
        "ratio_(factor+vjp)/cold_solve": (t_factor + t_vjp) / res.solve_time_s,
        "(factor+jvp)_in_solver_iterations": (t_factor + t_jvp) / t_iter,
        "(factor+vjp)_in_solver_iterations": (t_factor + t_vjp) / t_iter,
        "extra_jvp_in_solver_iterations": t_jvp / t_iter,
    }
    c["ratio_(factor+jvp)/warm_resolve"] = (t_factor + t_jvp) / c["warm_resolve_time_s"]
    return c


def _print_check(out: dict, prob, kkt) -> None:
    print(f"{out['task']} {out['scheme']} N={out['N']}: n={prob.nlp.n} m={prob.nlp.m}; active set {kkt.report()}")
    print(
        f"{'group':>8} {'|dx|':>10} {'err dx 2n':>10} {'err dx inf':>10} {'dV env':>14} {'dV chain':>14} "
        f"{'dV fd':>14} {'err env/fd':>10}"
    )
    for r in out["rows"]:
        print(
            f"{r['group']:>8} {r['norm_dx']:10.3e} {r['rel_err_dx_2norm']:10.2e} {r['rel_err_dx_maxnorm']:10.2e} "
            f"{r['dV_envelope']:14.8e} {r['dV_chain']:14.8e} {r['dV_fd']:14.8e} {r['rel_err_dV_env_fd']:10.2e}"
        )
    print(f"  mutations (weights, must exceed {FD_TOL:g}): {out['mutations_weights_rel_err_dx']}")
    for k, v in out["cost"].items():
        print(f"  {k}: {v:.4g}")


def check_against_fd(
    task="T1",
    scheme="A,F+C,1S",
    N=15,
    T=5.0,
    eps=1e-5,
    seed=1,
    groups=GROUPS + ("goal",),
    verbose=True,
    problem=None,
    result=None,
) -> dict:
    """Directional derivatives of x* and V* against central differences of warm re-solves, and
    the cost of a sensitivity relative to a solve. Returns a JSON-able dict.

    ``problem``/``result``: reuse a built problem and its converged solution (default: build
    ``task``/``scheme``/``N``/``T`` and ``reference_solve`` it). The cost of one JVP/VJP
    (factorisation included) is reported against the cold solve and in units of its average
    IPOPT iteration.
    """
    prob = build_problem(task, scheme, N=N, T=T) if problem is None else problem
    res = reference_solve(prob, verbose=verbose) if result is None else result
    KKTSensitivity(prob, res)  # compile
    t0 = time.perf_counter()
    kkt = KKTSensitivity(prob, res)
    t_factor = time.perf_counter() - t0
    rows, mutations = [], None
    for group in groups:
        row, dp, dx_fd = _group_row(prob, res, kkt, group, seed, eps)
        rows.append(row)
        if group == "weights":
            mutations = mutation_errors(prob, res, kkt, dp, dx_fd)
    ct = np.random.default_rng(seed).normal(size=prob.nlp.n)
    out = {
        "task": prob.task.key,
        "scheme": str(prob.scheme),
        "N": prob.layout.N,
        "n": prob.nlp.n,
        "m": prob.nlp.m,
        "eps": eps,
        "tol": FD_TOL,
        "objective": res.objective,
        "active_set": kkt.report(),
        "rows": rows,
        "mutations_weights_rel_err_dx": mutations,
        "cost": _cost(res, kkt, rows, ct, t_factor),
    }
    if verbose:
        _print_check(out, prob, kkt)
    return out


def table_rows(out: dict, tol: float = FD_TOL) -> list[dict]:
    """``check_against_fd`` result as rows of ``jaxhumanoid.checks.format_table``: per parameter
    group the 2-norm relative error of dx* and of dV* (envelope theorem) against the finite
    differences."""
    case = f"{out['task']} {out['scheme']} N={out['N']}"
    rows = []
    for r in out["rows"]:
        for quantity, value in (
            (f"dx* {r['group']}", r["rel_err_dx_2norm"]),
            (f"dV* {r['group']}", r["rel_err_dV_env_fd"]),
        ):
            rows.append(
                {
                    "case": case,
                    "check": "sensitivity vs FD",
                    "quantity": quantity,
                    "value": float(value),
                    "tol": tol,
                    "ok": bool(np.isfinite(value) and value <= tol),
                }
            )
    return rows


def sensitivity_table(
    tasks=("T1", "T2", "T3", "T4"), scheme="A,F+C,1S", N=15, T=5.0, eps=1e-5, seed=1, verbose=False
) -> tuple[list[dict], list[dict]]:
    """``check_against_fd`` on each task, a key or a built ``Problem`` (a task file's): (table
    rows, full results) for ``jaxhumanoid check --sensitivities``. A task whose solves fail, or
    whose reduced KKT matrix is singular, gives one failing row (the message under ``"error"``)."""
    rows, outs = [], []
    for task in tasks:
        if isinstance(task, Problem):
            problem, key, sch, n = task, task.task.key, str(task.scheme), task.layout.N
        else:
            problem, key, sch, n = None, task, scheme, N
        try:
            out = check_against_fd(key, sch, n, T=T, eps=eps, seed=seed, verbose=verbose, problem=problem)
        except (RuntimeError, np.linalg.LinAlgError) as err:  # a failed solve or a singular reduced KKT matrix
            rows.append(
                {
                    "case": f"{key} {sch} N={n}",
                    "check": "sensitivity vs FD",
                    "quantity": f"failed ({type(err).__name__})",
                    "value": float("inf"),
                    "tol": FD_TOL,
                    "ok": False,
                    "error": str(err),
                }
            )
            continue
        outs.append(out)
        rows += table_rows(out)
    return rows, outs
