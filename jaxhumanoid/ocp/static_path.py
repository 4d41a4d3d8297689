"""A start path of postures the body can hold: the ``"static_path"`` initial guess.

The linear guess (Sec. II-G) moves every joint straight from the start to the goal; holding its
postures at rest asks for more torque than the strengths give and puts the centre of pressure
off the sole, so stage 1 starts hundreds of newtons away from feasibility. This guess moves the
postures, interval by interval, to the nearest ones that satisfy the rows of the pseudo-static
model at the interval's midpoint, with the torques and forces its inverse statics gives:

    u_k = G(qbar_k) - J^T f(qbar_k, (q_{k+1} - q_k)/h)         (8) solved for u, laws (3)-(4)
    c_k = [ (5)(f_c0, u_k1) / (M g),                            steady foot, with p.foot_margin
            (u_max -/+ u_k) / u_max,                           strengths
            (f_max -/+ f_k) / (M g),                           force box, when it binds
            y_i(q_{k+1}) ]                                     clearance of the free joints (m)
    c_k >= 0,   q_min <= q_{k+1} <= q_max  (the goal box at k + 1 = N)

Two sweeps, each node chosen by SLSQP as the admissible posture nearest to an even share of the
rest of the way (a target that is admissible already is taken as is):

    forward:  q_{k+1} for k = 1..N-1 towards the goal, from q_1 = q_0
    backward: q_k for k = N-1..2 towards the start, from the goal box's centre

and the path is the forward sweep up to node m and the backward one after it, m the join whose
worst row is least. When that worst row is still violated by more than ``tol`` (a sweep that
meets an obstacle slides along it and cannot go around: lying down, where the body must put a
hand down before it can lean back), the guess is the inverse-dynamics guess itself. The rates
qd are the least-squares solution of (6a) with the fixed zero rates; what (6a) then misses is
linear in the variables and left to the solver. Only the postures are chosen here; u and f are
``transcription.inverse_dynamics_guess`` of the path.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import dynamics as dyn
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.tasks import CONTACT_FORCE_LIMIT

TOL = 1e-3  # worst row (body weights, fractions of the strengths, metres) a path may violate


def interval_rows(layout: tr.Layout, p: tr.OCPParams, f_max: float, q_a, q_b):
    """c_k of the module docstring for the interval from q_a to q_b, (n_c,); >= 0 where admissible."""
    n = layout.n_links
    h = p.T / layout.N
    qbar, rest = 0.5 * (q_a + q_b), jnp.zeros(n)
    f = ct.contact_forces(p.model, p.foot, p.contact, qbar, (q_b - q_a) / h, layout.active)
    u = dyn.pseudo_static_residual(p.model, qbar, rest, f, layout.active)
    weight = p.model.total_mass * p.model.g
    f_c0 = ft.foot_reaction(p.model, qbar, rest, rest, f)
    u_max = jnp.asarray(p.model.u_max)
    parts = [
        ft.foot_constraints(p.foot, p.contact.mu, f_c0, u[0], p.foot_margin, weight) / weight,
        (u_max - u) / u_max,
        (u_max + u) / u_max,
    ]
    if f_max < CONTACT_FORCE_LIMIT:  # a task's limit, posed in every scheme
        parts += [(f_max - f.ravel()) / weight, (f_max + f.ravel()) / weight]
    if layout.clear_joints:
        parts.append(kin.contact_gaps(p.model, p.foot, q_b)[jnp.asarray(layout.clear_joints) - 1])
    return jnp.concatenate(parts)


@functools.lru_cache(maxsize=16)
def _compiled(layout: tr.Layout, f_max: float):
    """Jitted rows over all intervals of a path, and the rows and their Jacobians in q_a and q_b."""
    rows = functools.partial(interval_rows, layout)
    along = jax.vmap(rows, in_axes=(None, None, 0, 0))
    return (
        jax.jit(lambda p, Q_a, Q_b: along(p, f_max, Q_a, Q_b)),
        jax.jit(lambda p, q_a, q_b: rows(p, f_max, q_a, q_b)),
        jax.jit(jax.jacfwd(lambda p, q_a, q_b: rows(p, f_max, q_a, q_b), argnums=1)),
        jax.jit(jax.jacfwd(lambda p, q_a, q_b: rows(p, f_max, q_a, q_b), argnums=2)),
    )


def _nearest(c, dc, target, lo, hi) -> np.ndarray:
    """The posture nearest to ``target`` within [lo, hi] with c >= 0 (SLSQP); ``target`` clipped
    to the box when it is admissible already."""
    x0 = np.clip(target, lo, hi)
    if np.all(np.asarray(c(x0)) >= 0.0):
        return x0
    res = optimize.minimize(
        lambda q: float(np.sum((q - target) ** 2)),
        x0,
        jac=lambda q: 2.0 * (q - target),
        method="SLSQP",
        bounds=list(zip(lo, hi)),
        constraints=[{"type": "ineq", "fun": lambda q: np.asarray(c(q)), "jac": lambda q: np.asarray(dc(q))}],
        options={"maxiter": 200, "ftol": 1e-12},
    )
    return np.asarray(res.x)


def _sweeps(layout: tr.Layout, p: tr.OCPParams, f_max: float, Q, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """The forward and the backward sweep of the module docstring, (N+1, n) each."""
    _, rows, d_a, d_b = _compiled(layout, f_max)
    N = layout.N
    F, B = Q.copy(), Q.copy()
    for k in range(1, N):
        q_a = F[k]
        target = q_a + (F[N] - q_a) / (N - k)
        F[k + 1] = _nearest(lambda q: rows(p, q_a, q), lambda q: d_b(p, q_a, q), target, lo[k + 1], hi[k + 1])
    B[N] = np.clip(0.5 * (lo[N] + hi[N]), lo[N], hi[N])
    for k in range(N - 1, 1, -1):
        q_b = B[k + 1]
        target = q_b + (B[1] - q_b) / k
        B[k] = _nearest(lambda q: rows(p, q, q_b), lambda q: d_a(p, q, q_b), target, lo[k], hi[k])
    return F, B


def _join(layout: tr.Layout, p: tr.OCPParams, f_max: float, F, B) -> tuple[np.ndarray, float]:
    """F up to node m, B after it, for the m in 1..N-1 whose worst row is least; (path, worst)."""
    along = _compiled(layout, f_max)[0]

    def worst(Q_a, Q_b):
        return -np.min(np.asarray(along(p, Q_a, Q_b)), axis=1)

    w_f, w_b, w_join = worst(F[:-1], F[1:]), worst(B[:-1], B[1:]), worst(F[:-1], B[1:])
    N = layout.N
    # worst over the intervals of the joined path: F's intervals < m, the join m, B's intervals > m
    before = np.maximum.accumulate(np.concatenate([[-np.inf], w_f[:-1]]))
    after = np.append(np.maximum.accumulate(w_b[::-1])[::-1][1:], -np.inf)
    total = np.maximum(np.maximum(before, w_join), after)[1:N]
    m = 1 + int(np.argmin(total))
    return np.concatenate([F[: m + 1], B[m + 1 :]]), float(total[m - 1])


def _rates(layout: tr.Layout, T: float, Q) -> np.ndarray:
    """qd (N+1, n): least squares of (6a), q_{k+1} - q_k = h (qd_k + qd_{k+1}) / 2, with qd_0,
    qd_{N-1} and qd_N zero."""
    N, h = layout.N, T / layout.N
    A = np.zeros((N, N + 1))
    A[np.arange(N), np.arange(N)] = A[np.arange(N), np.arange(1, N + 1)] = h / 2
    qd = np.zeros_like(Q)
    qd[1 : N - 1] = np.linalg.lstsq(A[:, 1 : N - 1], np.diff(Q, axis=0), rcond=None)[0]
    return qd


def static_path_guess(layout: tr.Layout, Z, p: tr.OCPParams, lo, hi, f_max: float, tol: float = TOL):
    """The ``"static_path"`` guess from the linear guess ``Z`` (N+1, s) within the bounds ``lo``,
    ``hi`` (N+1, s) and the force box ``f_max`` (N). Returns (Z, worst): ``Z`` with the joined
    path's q, qd and its inverse-dynamics u, f, or the inverse-dynamics guess of the linear ``Z``
    when the worst row of the path (``worst``) is violated by more than ``tol``."""
    sl = layout.stage_slices()
    F, B = _sweeps(layout, p, float(f_max), np.array(Z[:, sl["q"]]), lo[:, sl["q"]], hi[:, sl["q"]])
    Q, worst = _join(layout, p, float(f_max), F, B)
    Z = np.array(Z, dtype=float)
    if worst <= tol:
        Z[:, sl["q"]], Z[:, sl["qd"]] = Q, _rates(layout, float(p.T), Q)
    return np.asarray(tr.inverse_dynamics_guess(layout, Z, p)), worst
