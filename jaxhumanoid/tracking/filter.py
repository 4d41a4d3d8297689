"""A per-step safety filter on the torques: the steady-foot conditions (5) enforced, not penalised.

At every simulator step the torque the controller asks for, u_lqr (n,), is replaced by the nearest
torque (in R = I / u_Nm^2) whose step keeps the foot steady with a margin, as a small QP

    min_u  (u - u_lqr)^T R (u - u_lqr) + rho sum(s) + |s|^2
    s.t.   c(x, u_0) + D (u - u_0) + s >= 0      c: the five rows of (5) of this step, tightened by
           s >= 0,  -u_max <= u <= u_max            ``SafetyFilter.margin`` (model.foot.FootMargin)

with D = dc/du at u_0 = u_lqr by ``jax.jacfwd`` through ``simulator.step`` (the implicit-function
derivative, as ``lqr.linearise_foot``; the state x is the one measured, the body and law the
nominal ones: the filter does not know the perturbation). The rows are in body weights M g (the
centre-of-pressure rows divided by a0f and a0b). The slack s (body weights) makes the QP feasible
whatever the state; its penalty is exact (linear, weight rho): s = 0 at the answer whenever some
torque within the strengths keeps the linearised foot steady at a cost per body weight below rho,
and s > 0 means none does. With ``passes`` = 2 the rows are linearised again at the first answer.
When u_lqr already satisfies the rows and the strengths, it is returned unchanged (bitwise).

Two corrections make the nominal rows hold on the body that is actually there:

- an observer (``observer``): c is shifted by the model's error on the previous step, as a foot
  force sensor measures it (the reaction f_c0 and centre of pressure the body produced there,
  against the rows the model predicted at the torque the filter chose). It absorbs the unknown
  masses, lengths and contact law and the torque noise held since, one step late;
- a robust margin against torque errors the filter cannot see before they act (``noise_Nm``):
  row i is tightened by noise_Nm |D_i|_2, so that it holds for any torque error of norm
  <= noise_Nm added to the answer (to first order).

The QP, on z = ((u - u_lqr) / u_Nm, s) (n + 5 variables, 2 n + 10 rows), is solved by ``solve_qp``:
a primal-dual interior-point method (Mehrotra's predictor-corrector) with a fixed number of
iterations and no Python control flow, so that it is jitted and ``vmap``-ed over trials; iterates
that reach the tolerance are frozen. Its KKT residual is returned and recorded per step.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxhumanoid.model import foot as ft
from jaxhumanoid.tracking.simulator import Plant, step, step_reaction

QP_TOL = 1e-10  # KKT residual (scaled units) at which the interior-point iterates are frozen
STEP_TO_BOUNDARY = 0.99  # fraction of the largest step that keeps the slacks and multipliers positive


class QPResult(NamedTuple):
    """The answer z (p,), the multipliers lam (m,) of A z >= b and the KKT residual (max of the
    stationarity, primal and complementarity residuals)."""

    z: jax.Array
    lam: jax.Array
    residual: jax.Array


def _max_step(v, dv):
    """The largest alpha in (0, 1] with v + alpha dv >= 0 (v > 0)."""
    ratios = jnp.where(dv < 0, -v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.minimum(1.0, jnp.min(ratios))


def solve_qp(H, g, A, b, iterations: int = 25) -> QPResult:
    """min 0.5 z^T H z + g^T z  s.t.  A z >= b, by a primal-dual interior-point method.

    H (p, p) symmetric positive definite, g (p,), A (m, p), b (m,). With w = A z - b >= 0 and
    lam >= 0 the KKT conditions are H z + g - A^T lam = 0, A z - b - w = 0, w_i lam_i = 0; each
    iteration is a Mehrotra predictor-corrector Newton step on them, reduced to
    (H + A^T diag(lam / w) A) dz = -r_d - A^T ((r_c + lam r_p) / w), from the infeasible start
    z = 0, w = max(A z - b, 1), lam = 1. ``iterations`` is fixed (a ``fori_loop``); iterates below
    QP_TOL are frozen, and the iterate of the smallest KKT residual is returned (near the answer,
    lam / w spans many decades and a further step can lose what was reached).
    """
    m = b.shape[0]

    def residuals(z, w, lam):
        return H @ z + g - A.T @ lam, A @ z - b - w

    def kkt_norm(z, w, lam):
        r_d, r_p = residuals(z, w, lam)
        return jnp.maximum(jnp.maximum(jnp.max(jnp.abs(r_d)), jnp.max(jnp.abs(r_p))), w @ lam / m)

    def direction(z, w, lam, r_c):
        r_d, r_p = residuals(z, w, lam)
        K = H + A.T @ ((lam / w)[:, None] * A)
        dz = jnp.linalg.solve(K, -r_d - A.T @ ((r_c + lam * r_p) / w))
        dw = A @ dz + r_p
        return dz, dw, -(r_c + lam * dw) / w

    def body(_, state):
        (z, w, lam), best = state
        mu = w @ lam / m
        dz_a, dw_a, dl_a = direction(z, w, lam, w * lam)
        a_aff = jnp.minimum(_max_step(w, dw_a), _max_step(lam, dl_a))
        sigma = (((w + a_aff * dw_a) @ (lam + a_aff * dl_a) / m) / mu) ** 3
        dz, dw, dl = direction(z, w, lam, w * lam + dw_a * dl_a - sigma * mu)
        alpha = STEP_TO_BOUNDARY * jnp.minimum(_max_step(w, dw), _max_step(lam, dl))
        done = kkt_norm(z, w, lam) < QP_TOL
        keep = lambda old, d: jnp.where(done, old, old + alpha * d)  # noqa: E731
        new = (keep(z, dz), keep(w, dw), keep(lam, dl))
        better = kkt_norm(*new) < kkt_norm(*best)
        return new, jax.tree.map(lambda a, c: jnp.where(better, a, c), new, best)

    z0 = jnp.zeros(g.shape[0])
    start = (z0, jnp.maximum(A @ z0 - b, 1.0), jnp.ones(m))
    _, (z, w, lam) = jax.lax.fori_loop(0, iterations, body, (start, start))
    return QPResult(z, lam, kkt_norm(z, w, lam))


@dataclasses.dataclass(frozen=True)
class SafetyFilter:
    """The filter's settings: the margin on (5) it enforces (``load`` in body weights,
    ``friction`` the fraction of the cone kept unused, ``cop`` m inside the sole: a
    ``FootMargin``), ``u_Nm`` (R = I / u_Nm^2), ``slack_weight`` rho (the exact penalty per body
    weight of slack, in units of u_Nm^2 of torque change: 1e3 buys a slack only when the foot rows
    would cost more than about 30 u_Nm per percent of body weight), the interior-point ``iterations``
    and the linearisation ``passes``, the ``observer`` of the model's error and the robust torque
    margin ``noise_Nm`` (N m) (module docstring)."""

    load: float = 0.02
    friction: float = 0.30
    cop: float = 0.03
    u_Nm: float = 20.0
    slack_weight: float = 1e3
    iterations: int = 50
    passes: int = 1
    observer: bool = True
    noise_Nm: float = 10.0

    def __post_init__(self):
        self.margin  # noqa: B018  # FootMargin checks load, friction and cop
        v = self.noise_Nm
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < float("inf"):
            raise ValueError(f"SafetyFilter.noise_Nm: expected a torque >= 0 (N m), got {v!r}")
        for name in ("u_Nm", "slack_weight"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0 or v == float("inf"):
                raise ValueError(f"SafetyFilter.{name}: expected a finite number > 0, got {v!r}")
        for name in ("iterations", "passes"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"SafetyFilter.{name}: expected an integer >= 1, got {v!r}")
        if not isinstance(self.observer, bool):
            raise ValueError(f"SafetyFilter.observer: expected True or False, got {self.observer!r}")

    @property
    def margin(self) -> ft.FootMargin:
        return ft.FootMargin(self.load, self.friction, self.cop)


class FilterInfo(NamedTuple):
    """Per step: the largest slack at the QP's answer (body weights; > 0: the foot rows could not
    be met), its KKT residual, and the largest torque change |u - u_lqr| (N m)."""

    slack: jax.Array
    residual: jax.Array
    change: jax.Array


def reaction_rows(plant: Plant, f_c0, u1, options: SafetyFilter):
    """The rows (5) of the reaction f_c0 (2,) and ankle torque u1, tightened by ``options.margin``,
    in body weights (the centre-of-pressure rows divided by a0f and a0b), shape (5,); >= 0 keeps
    the margin."""
    weight = plant.model.total_mass * plant.model.g
    rows = ft.foot_constraints(plant.foot, plant.contact.mu, f_c0, u1, options.margin, weight)
    return rows / (weight * jnp.array([1.0, 1.0, 1.0, plant.foot.a0f, plant.foot.a0b]))


def foot_rows(plant: Plant, active: tuple, dt, x, u, options: SafetyFilter):
    """``reaction_rows`` of the step from x (2n,) under u (n,) (the reaction at its midpoint)."""
    n = u.shape[0]
    x1, _ = step(plant, active, dt, x, u)
    return reaction_rows(plant, step_reaction(plant, active, dt, x, x1[:n], x1[n:]), u[0], options)


def _linearised(plant: Plant, active: tuple, dt, x, u0, options: SafetyFilter):
    """(c (5,), D (5, n)): the rows at u0 and their derivative in u."""
    rows = lambda u: (foot_rows(plant, active, dt, x, u, options),) * 2  # noqa: E731
    D, c = jax.jacfwd(rows, has_aux=True)(u0)
    return c, D


def qp_matrices(c, D, u_lqr, u0, u_max, options: SafetyFilter):
    """(H, g, A, b) of the module's QP on z = ((u - u_lqr) / u_Nm, s), rows linearised at u0."""
    k, n = D.shape
    s = options.u_Nm
    H = 2.0 * jnp.eye(n + k)
    A = jnp.block(
        [
            [s * D, jnp.eye(k)],
            [jnp.zeros((k, n)), jnp.eye(k)],
            [jnp.eye(n), jnp.zeros((n, k))],
            [-jnp.eye(n), jnp.zeros((n, k))],
        ]
    )
    b = jnp.concatenate([-(c + D @ (u_lqr - u0)), jnp.zeros(k), (-u_max - u_lqr) / s, (u_lqr - u_max) / s])
    return H, jnp.r_[jnp.zeros(n), jnp.full(k, options.slack_weight)], A, b


def measured_rows(plant: Plant, raw, options: SafetyFilter):
    """``reaction_rows`` from the untightened products (5) a step produced (5,) (what a foot force
    sensor measures: f_t0, f_n0 and the centre of pressure, i.e. u_1), with the model's mu."""
    f_n0, f_t0, u1 = raw[0], 0.5 * (raw[2] - raw[1]), raw[3] - plant.foot.a0f * raw[0]
    return reaction_rows(plant, jnp.stack([f_t0, f_n0]), u1, options)


def filter_torque(plant: Plant, active: tuple, dt, x, u_lqr, u_max, options: SafetyFilter, bias=0.0):
    """The filtered torque (n,) for the state x (2n,) and the controller's u_lqr (n,), its
    ``FilterInfo`` (module docstring) and the model's rows at the answer, linearised (5,) (without
    ``bias``). ``plant`` is the controller's (nominal) model; ``bias`` (5,) is added to its rows
    (``shield``: the model's error on the previous step, as measured)."""
    n = u_lqr.shape[0]
    c, D = _linearised(plant, active, dt, x, u_lqr, options)
    bias = bias - options.noise_Nm * jnp.linalg.norm(D, axis=1)  # rows kept against any |torque error| <= noise_Nm
    admissible = jnp.all(c + bias >= 0) & jnp.all(jnp.abs(u_lqr) <= u_max)
    u, u0 = u_lqr, u_lqr
    for i in range(options.passes):
        if i > 0:
            u0 = u
            c, D = _linearised(plant, active, dt, x, u0, options)
        H, g, A, b = qp_matrices(c + bias, D, u_lqr, u0, u_max, options)
        res = solve_qp(H, g, A, b, iterations=options.iterations)
        u = u_lqr + options.u_Nm * res.z[:n]
    u = jnp.where(admissible, u_lqr, u)
    zero = jnp.zeros(())
    slack = jnp.where(admissible, zero, jnp.max(res.z[n:]))
    residual = jnp.where(admissible, zero, res.residual)
    return u, FilterInfo(slack, residual, jnp.max(jnp.abs(u - u_lqr))), c + D @ (u - u0)


def shield(plant: Plant, active: tuple, dt, u_max, options: SafetyFilter):
    """The filter as ``simulator.rollout``'s shield: (x, u_lqr, memo) -> (u, FilterInfo, prediction).
    With ``options.observer`` the rows are corrected by the model's error on the previous step,
    bias = (rows measured there) - (rows the model predicted there at the torque it chose): the
    error of the nominal body and law, and the torque noise held since, as a foot force sensor
    sees them; zero before the first step."""

    def apply(x, u_lqr, memo):
        prediction, raw = memo
        bias = measured_rows(plant, raw, options) - prediction
        bias = jnp.where(jnp.isfinite(bias) & options.observer, bias, 0.0)
        return filter_torque(plant, active, dt, x, u_lqr, u_max, options, bias)

    return apply
