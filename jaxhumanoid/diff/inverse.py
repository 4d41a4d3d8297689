"""Inverse optimal control: recover the cost-weight ratios from an optimal trajectory.

``WeightFit`` fits log-weights so that x*(w) matches a given trajectory, by Gauss-Newton (the
residual Jacobian from KKT JVPs) or L-BFGS (``jax.grad`` through ``make_solve``), every solve
continued along the data's branch of local optima (``continuation_solve``). ``fit_task_weights``
is one whole experiment: the data from the task's own weights, a fit from one random start.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

from jaxhumanoid.diff.adjoint import make_solve, warm_start
from jaxhumanoid.diff.kkt import KKTSensitivity
from jaxhumanoid.diff.resolve import continuation_solve, reference_solve, resolve
from jaxhumanoid.diff.trees import rel_err, zeros_like_params
from jaxhumanoid.ocp.nlp import Bounds
from jaxhumanoid.strategy.problem import Problem, build_problem


def weight_names(n: int) -> tuple[str, ...]:
    """The names of the n + 3 weights of (7) for a chain of n links."""
    return (*(f"w_u{j + 1}" for j in range(n)), "w_qd", "w_dqd", "w_du")


def free_weights(n: int) -> tuple[int, ...]:
    """Every weight but w_qd (index n), which fixes the scale: x*(c w) = x*(w) for every c > 0."""
    return tuple(j for j in range(n + 3) if j != n)


WEIGHT_NAMES = weight_names(5)
FREE_WEIGHTS = free_weights(5)


def perturbed_weights(w, seed: int = 0, lo: float = 2.0, hi: float = 5.0, free=None) -> np.ndarray:
    """``w`` with each free weight multiplied or divided (at random, reproducibly) by a factor
    drawn uniformly from [lo, hi]: the start of an inverse problem."""
    if not 0 < lo <= hi:
        raise ValueError(f"lo, hi: expected 0 < lo <= hi, got {lo!r}, {hi!r}")
    rng = np.random.default_rng(seed)
    free = np.asarray(free_weights(np.size(w) - 3) if free is None else free, dtype=np.int64)
    out = np.asarray(w, dtype=float).copy()
    out[free] *= rng.uniform(lo, hi, size=free.size) ** rng.choice([-1.0, 1.0], size=free.size)
    return out


def trajectory_scale(problem, x) -> np.ndarray:
    """(n,) per-variable scale of the trajectory mismatch: RMS over the nodes of each column of
    the full layout (q, qd, u, f) of ``x``, floored at 1e-3 of the largest column."""
    Z = problem.full(x)
    col = np.sqrt(np.mean(Z**2, axis=0))
    col = np.maximum(col, 1e-3 * col.max() + 1e-12)
    return np.broadcast_to(col, Z.shape)[problem.layout.free_mask()]


class WeightFit:
    """Fit the cost weights so that the optimal trajectory matches ``x_data``.

    Unknowns theta = log w[free] (``free`` defaults to every weight but w_qd, which
    stays at ``w_init[n]``: only ratios of weights are identifiable). The loss is the scaled
    mismatch ``1/2 ||(x*(w(theta)) - x_data) / s||^2`` (s: ``trajectory_scale`` of x_data).

    Every solve follows one branch of local optima: the first is warm-started from ``x_data``
    (primal only, the multipliers are unknown in an inverse problem) at ``w_init``, and each
    later one by ``continuation_solve`` from the previous solve (sub-steps of at most a factor
    1 + ``max_rel_step`` per weight). Without it, a warm start after a long step can land on
    another local optimum, where the mismatch is large and flat.

    Methods: ``gauss_newton`` (residual Jacobian from one KKT factorisation and one JVP per
    unknown) and ``lbfgs`` (scipy L-BFGS-B on the loss and its ``jax.vjp`` through
    ``make_solve``: one solve and one adjoint per evaluation).

    Both are local. From ``perturbed_weights(w, seed=0)`` they recover the weights on the
    paper's posing of T1-T4 (``examples/paper/``, N = 15). From ``seed=1`` (factors 0.28, 0.21,
    2.4, 4.9, 0.34, 0.31, 4.5) Gauss-Newton fails on all four: it lowers the loss (T1 49 -> 32,
    T2 71 -> 46, T3 8.1 -> 4.8, T4 29 -> 6.5), on T2-T4 by driving one weight towards 0 (w_u5 on
    T2 and T3, w_dqd on T4), and on T3 its
    trial steps jump from loss 6.5 to 16 where the followed branch ends. The first solve is
    not the cause: on T2 and T3 it equals the data's branch continued from the true weights.
    """

    def __init__(
        self,
        problem,
        x_data,
        w_init,
        free=None,
        max_rel_step: float = 0.25,
        options: dict | None = None,
        verbose: bool = False,
    ):
        self.problem = problem
        self.x_data = np.asarray(x_data, dtype=float)
        if self.x_data.shape != (problem.nlp.n,):
            raise ValueError(f"x_data: expected shape ({problem.nlp.n},), got {self.x_data.shape}")
        self.w_init = np.asarray(w_init, dtype=float)
        nw = problem.p.model.n + 3
        if self.w_init.shape != (nw,) or not np.all(self.w_init > 0):
            raise ValueError(f"w_init: expected {nw} positive weights, got {w_init!r}")
        self.free = np.asarray(free_weights(nw - 3) if free is None else free, dtype=np.int64)
        self.scale = trajectory_scale(problem, self.x_data)
        self.options = {"tol": 1e-10, "max_iter": 3000, **(options or {})}
        self.max_rel_step = max_rel_step
        self.verbose = verbose
        self.stats: dict[str, Any] = {"solves": 0, "solve_wall_s": 0.0, "sensitivities": 0, "sensitivity_wall_s": 0.0}
        self.history: list[dict] = []
        self._last = None  # (theta, p, result) of the latest solve
        self._best = None  # (loss, theta, p, result) of the solve with the smallest loss: the anchor
        p0 = self.params(self.theta_init)
        b = problem.bounds
        start = Bounds(x0=np.clip(self.x_data, b.xl, b.xu), xl=b.xl, xu=b.xu, gl=b.gl, gu=b.gu)
        t0 = time.perf_counter()
        res = resolve(problem, p=p0, bounds=start, options=self.options)
        if not res.success:
            raise RuntimeError(f"WeightFit: the first solve (at w_init, from x_data) returned {res.status}")
        self._record(self.theta_init, p0, res, time.perf_counter() - t0)

    @property
    def theta_init(self) -> np.ndarray:
        return np.log(self.w_init[self.free])

    def weights(self, theta) -> np.ndarray:
        w = self.w_init.copy()
        w[self.free] = np.exp(np.asarray(theta, dtype=float))
        return w

    def params(self, theta):
        return dataclasses.replace(self.problem.p, weights=self.weights(theta))

    def residual_of(self, x) -> np.ndarray:
        return (np.asarray(x) - self.x_data) / self.scale

    def _record(self, theta, p, res, wall):
        self.stats["solves"] += 1
        self.stats["solve_wall_s"] += wall
        theta = np.array(theta, dtype=float)
        self._last = (theta, p, res)
        r = self.residual_of(res.x)
        loss = float(0.5 * r @ r)
        if self._best is None or loss < self._best[0]:
            self._best = (loss, theta, p, res)
        self.history.append({"theta": theta.tolist(), "loss": loss, "ipopt_iterations": int(res.iterations)})
        if self.verbose:
            print(f"  solve {self.stats['solves']:3d}: loss {loss:.6e}  ipopt its {res.iterations}")

    def solve(self, theta):
        """(p, result) at ``theta`` (an NLPResult, or a KKTPoint from ``lbfgs``), continued from the
        solve with the smallest loss so far.

        Not from the latest: a rejected trial step can land on another branch of local optima,
        and continuing from there would carry the following solves onto it.
        """
        theta = np.asarray(theta, dtype=float)
        for th, p_done, res_done in (self._last, self._best[1:]):
            if np.array_equal(theta, th):
                return p_done, res_done
        _, _, p_from, res_from = self._best
        p = self.params(theta)
        t0 = time.perf_counter()
        res = continuation_solve(
            self.problem, p_from, res_from, p, max_rel_step=self.max_rel_step, options=self.options
        )
        if not res.success:
            raise RuntimeError(f"WeightFit: solve at w = {self.weights(theta)} returned {res.status}")
        self._record(theta, p, res, time.perf_counter() - t0)
        return p, res

    def residual(self, theta) -> np.ndarray:
        return self.residual_of(self.solve(theta)[1].x)

    def jacobian(self, theta) -> np.ndarray:
        """(n, k) d residual / d theta: one KKT factorisation, one JVP per unknown."""
        p, res = self.solve(theta)
        t0 = time.perf_counter()
        kkt = KKTSensitivity(self.problem, res, p=p)
        w = self.weights(theta)
        cols = []
        for i in self.free:
            dw = np.zeros(w.size)
            dw[i] = w[i]  # d w_i / d theta_j
            cols.append(kkt.jvp(dataclasses.replace(zeros_like_params(p), weights=dw)) / self.scale)
        self.stats["sensitivities"] += 1
        self.stats["sensitivity_wall_s"] += time.perf_counter() - t0
        return np.stack(cols, axis=1)

    def gauss_newton(
        self, theta0=None, max_evals: int = 30, max_step: float = 1.0, tol: float = 1e-12, xtol: float = 1e-9
    ):
        """Levenberg-Marquardt-damped Gauss-Newton, steps clipped to ||dtheta||_inf <= max_step
        (a factor e per weight: long steps make the continuation expensive). Stops when the
        step falls below ``xtol`` (further steps only chase IPOPT's tolerance), when an accepted
        step reduces the loss by less than ``tol`` relative, or after ``max_evals`` solves.
        Returns theta."""
        theta = self.theta_init if theta0 is None else np.asarray(theta0, dtype=float)
        r = self.residual(theta)
        loss, evals, damping = 0.5 * r @ r, 1, 1e-6
        converged = False
        while evals < max_evals and not converged:
            Jm = self.jacobian(theta)
            g, A = Jm.T @ r, Jm.T @ Jm
            if np.max(np.abs(g)) <= tol * max(1.0, loss):
                break
            accepted = False
            while evals < max_evals:
                step = -np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-12), g)
                step *= min(1.0, max_step / max(np.max(np.abs(step)), 1e-300))
                if np.max(np.abs(step)) < xtol:
                    break
                r_new = self.residual(theta + step)
                evals += 1
                loss_new = 0.5 * r_new @ r_new
                if loss_new < loss:
                    converged = loss - loss_new <= tol * loss
                    theta, r, loss, accepted = theta + step, r_new, loss_new, True
                    damping = max(damping / 10, 1e-12)
                    break
                damping *= 10
            if not accepted:
                break
        return theta

    def lbfgs(self, theta0=None, max_evals: int = 80, max_step: float = 0.5):
        """scipy L-BFGS-B on the loss and its gradient by ``jax.vjp`` through ``make_solve``
        (reverse mode: one adjoint solve per gradient). Returns theta.

        The unknowns are preconditioned once, v = R (theta - theta0) with R^T R = J0^T J0 + I /
        max_step^2, J0 the residual Jacobian at theta0 (one KKT factorisation): a unit step in
        v then moves theta by at most ``max_step`` (2-norm), and by about a Gauss-Newton step
        in the well-determined directions. Unscaled, the loss is ill-conditioned in theta and
        L-BFGS-B stalled (T3: loss 9.7 -> 7.4 in 30 evaluations, against 1e-22 in 9 for
        Gauss-Newton), and its first unit step in theta, up to a factor e per weight, landed on
        another branch of local optima. As in ``solve``, every solve continues from the best
        one so far (its KKT point is the warm start passed to the solve).
        """
        theta0 = self.theta_init if theta0 is None else np.asarray(theta0, dtype=float)
        J0 = self.jacobian(theta0)
        R = np.linalg.cholesky(J0.T @ J0 + np.eye(J0.shape[1]) / max_step**2).T
        R_inv = np.linalg.inv(R)
        solve = make_solve(self.problem, options=self.options, max_rel_step=self.max_rel_step, strict=True)
        w_fixed, free = jnp.asarray(self.w_init), jnp.asarray(self.free)
        x_data, scale = jnp.asarray(self.x_data), jnp.asarray(self.scale)
        theta_of = lambda v: theta0 + R_inv @ v  # noqa: E731

        def loss(v, warm):
            w = w_fixed.at[free].set(jnp.exp(theta0 + jnp.asarray(R_inv) @ v))
            x, point = solve(dataclasses.replace(self.problem.p, weights=w), warm)
            r = (x - x_data) / scale
            return 0.5 * jnp.dot(r, r), point

        def fg(v):
            _, _, p_best, res_best = self._best
            warm = warm_start(res_best, p_best)
            t0 = time.perf_counter()
            val, pullback, point = jax.vjp(lambda vv: loss(vv, warm), jnp.asarray(v), has_aux=True)
            t1 = time.perf_counter()
            (g,) = pullback(jnp.ones_like(val))
            t_adj = time.perf_counter() - t1
            self.stats["sensitivities"] += 1
            self.stats["sensitivity_wall_s"] += t_adj
            theta = theta_of(np.asarray(v))
            self._record(theta, self.params(theta), point, t1 - t0)
            return float(val), np.asarray(g, dtype=float)

        sol = optimize.minimize(
            fg,
            np.zeros_like(theta0),
            jac=True,
            method="L-BFGS-B",
            options={"maxfun": max_evals, "ftol": 1e-15, "gtol": 1e-12},
        )
        self.stats["lbfgs_message"] = str(sol.message)
        return theta_of(np.asarray(sol.x, dtype=float))

    def summary(self, theta, w_true=None) -> dict:
        """Recovered weights and the trajectory mismatch at ``theta`` (JSON-able)."""
        _, res = self.solve(theta)
        Zd, Zh = self.problem.full(self.x_data), self.problem.full(res.x)
        r = self.residual_of(res.x)
        names, sl = weight_names(self.w_init.size - 3), self.problem.layout.stage_slices()
        out = {
            "weight_names": list(names),
            "free": [names[i] for i in self.free],
            "w_initial": self.w_init.tolist(),
            "w_recovered": self.weights(theta).tolist(),
            "loss_initial": self.history[0]["loss"],
            "loss_final": float(0.5 * r @ r),
            "max_abs_q_error_rad": float(np.max(np.abs(Zh[:, sl["q"]] - Zd[:, sl["q"]]))),
            "max_abs_u_error_Nm": float(np.max(np.abs(Zh[:-1, sl["u"]] - Zd[:-1, sl["u"]]))),
            "rel_err_x": rel_err(res.x, self.x_data),
            **self.stats,
        }
        if w_true is not None:
            w_true = np.asarray(w_true, dtype=float)
            out["w_true"] = w_true.tolist()
            out["initial_factors"] = (self.w_init[self.free] / w_true[self.free]).tolist()
            out["recovered_factors"] = (self.weights(theta)[self.free] / w_true[self.free]).tolist()
            out["max_rel_weight_error"] = float(np.max(np.abs(self.weights(theta)[self.free] / w_true[self.free] - 1)))
        return out


def fit_task_weights(
    task: str | Problem = "T1",
    N: int = 15,
    T: float = 5.0,
    scheme: str = "A,F+C,1S",
    method: str = "gn",
    seed: int = 0,
    max_evals: int | None = None,
    verbose: bool = False,
) -> dict:
    """One inverse experiment: x_data = x*(w_true) by ``reference_solve`` with the task's weights,
    then a fit from ``perturbed_weights(w_true, seed)`` by ``method`` (``gn``: ``gauss_newton``,
    at most ``max_evals`` (default 30) solves; ``lbfgs``: ``lbfgs``, default 80). Returns the
    JSON-able ``WeightFit.summary`` with the settings, the wall time and the loss history.
    ``task``: a key, or a built ``Problem`` (a task file's), whose scheme, grid and horizon then
    replace ``scheme``, ``N`` and ``T``."""
    if method not in ("gn", "lbfgs"):
        raise ValueError(f"method: {method!r} not in ('gn', 'lbfgs')")
    t_start = time.perf_counter()
    prob = task if isinstance(task, Problem) else build_problem(task, scheme, N=N, T=T)
    scheme, N = str(prob.scheme), prob.layout.N
    data = reference_solve(prob, tol=1e-10, verbose=verbose)
    w_true = np.asarray(prob.p.weights, dtype=float)
    fit = WeightFit(prob, data.x, perturbed_weights(w_true, seed), verbose=verbose)
    if method == "gn":
        theta = fit.gauss_newton(max_evals=max_evals or 30)
    else:
        theta = fit.lbfgs(max_evals=max_evals or 80)
    out = {
        "task": prob.task.key,
        "scheme": scheme,
        "N": N,
        "method": method,
        "seed": seed,
        "data_objective": data.objective,
        **fit.summary(theta, w_true),
    }
    out["wall_time_s"] = time.perf_counter() - t_start
    out["history"] = fit.history
    return out
