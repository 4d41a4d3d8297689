"""Direct transcription with the implicit midpoint rule (6), the pseudo-static model (8), NLP (7).

Grid: N intervals of length h = T/N, nodes k = 0..N. Per stage k the full layout holds

    Z[k] = (q_k, qd_k, u_k, f_k)        q, qd, u in R^5; f in R^{2|F|} under scheme A (else empty)

(for k = N, u_N and f_N are padding, fixed at zero), so the paper's stacked vector
{q_0, qd_0, u_0, f_0, ..., q_N, qd_N} is Z flattened. The NLP variables x are the free entries:
q_0, qd_0 = 0 and u_0 (equilibrium torques) are fixed by the initial conditions, and qd_{N-1} =
qd_N = 0 by the terminal static equilibrium, which gives the paper's count

    m = 2n(N+1) + nN + 2|F|N - 3n - 2n        (1485 for E-F, 2485 for A-F at N = 100).

Constraints of interval k, functions of (Z[k], Z[k+1]) only, in this order:

    (6a)  q_{k+1} - q_k - h qdbar_k = 0                                              n
    (6b)  B(qbar_k)(qd_{k+1} - qd_k) + h (C qdbar_k + G(qbar_k) - Q(qbar_k, qdbar_k, u_k)) = 0
          or, pseudo-static, (8): G(qbar_k) - Q(qbar_k, (q_{k+1} - q_k)/h, u_k) = 0   n
    A:    f_k - (f_t, f_n)(qbar_k, qdbar_k) = 0   (laws (3)-(4) at the midpoint)    2|F|
    (5)   steady-foot products >= 0 at the midpoint                                 5
    F+C:  y_Oi(q_{k+1}) >= 0 for the joints without a contact force                 5 - |F|

The constraint Jacobian therefore couples stage k only with stages k and k+1, and the Lagrangian
Hessian is a sum of per-interval (2s x 2s) blocks: ``derivatives.stagewise`` exploits this.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import dynamics as dyn
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, Humanoid
from jaxhumanoid.ocp import tasks as tasks_mod
from jaxhumanoid.pytree import pytree_dataclass

N_Q = 5


@pytree_dataclass
class OCPParams:
    """Everything numeric the NLP depends on (a pytree: vmap and differentiate over it).

    weights: (8,) = (w_u1..w_u5, w_qd, w_dqd, w_du); T: horizon (s); q_start: (5,) start posture.
    """

    model: Humanoid
    foot: FootParams
    contact: ContactParams
    weights: jax.Array | np.ndarray
    T: jax.Array | float
    q_start: jax.Array | np.ndarray


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static shape information of one transcription."""

    N: int
    active: tuple  # joints with contact forces (1..5)
    augmented: bool
    clearance: bool
    pseudo_static: bool

    @property
    def n_f(self) -> int:
        return 2 * len(self.active) if self.augmented else 0

    @property
    def s(self) -> int:
        """Variables per stage in the full layout."""
        return 3 * N_Q + self.n_f

    @property
    def clear_joints(self) -> tuple:
        return tuple(i for i in range(1, 6) if i not in self.active) if self.clearance else ()

    @property
    def n_con(self) -> int:
        """Constraints per interval."""
        return 2 * N_Q + self.n_f + 5 + len(self.clear_joints)

    def stage_slices(self):
        return dict(q=slice(0, 5), qd=slice(5, 10), u=slice(10, 15), f=slice(15, 15 + self.n_f))

    def free_mask(self) -> np.ndarray:
        """(N+1, s) boolean: True for NLP variables."""
        free = np.ones((self.N + 1, self.s), dtype=bool)
        free[0, 0:15] = False  # q_0, qd_0, u_0
        free[self.N - 1, 5:10] = False  # qd_{N-1}
        free[self.N, 5:] = False  # qd_N and the padding u_N, f_N
        return free

    def constraint_kinds(self) -> np.ndarray:
        """Per-interval constraint kinds: 0 equality, 1 inequality (>= 0)."""
        return np.array([0] * (2 * N_Q + self.n_f) + [1] * (5 + len(self.clear_joints)))


def equilibrium_torques(p: OCPParams, q, active):
    """u with G(q) = Q(q, 0, u): static equilibrium of (1) at rest."""
    f = ct.contact_forces(p.model, p.foot, p.contact, q, jnp.zeros(5), active)
    return dyn.gravity_vector(p.model, q) - dyn.generalized_forces(p.model, q, jnp.zeros(5), f, active)


def full_from_free(layout: Layout, x, p: OCPParams):
    """Scatter the NLP vector x into the full (N+1, s) layout, fixed entries from p."""
    base = jnp.zeros((layout.N + 1, layout.s), dtype=jnp.float64)
    q0 = jnp.asarray(p.q_start, dtype=jnp.float64)
    base = base.at[0, 0:5].set(q0).at[0, 10:15].set(equilibrium_torques(p, q0, layout.active))
    idx = np.flatnonzero(layout.free_mask().ravel())
    return base.ravel().at[idx].set(x).reshape(layout.N + 1, layout.s)


def free_from_full(layout: Layout, Z):
    return jnp.asarray(Z).ravel()[np.flatnonzero(layout.free_mask().ravel())]


def midpoint_map(layout: Layout) -> np.ndarray:
    """Constant matrix M with r = M (Z[k], Z[k+1]): the interval's midpoint variables

        r = (qbar, qdbar, dq = q_{k+1} - q_k, dqd = qd_{k+1} - qd_k, u_k, f_k, q_{k+1})

    Every constraint of the interval is a function of r. In r the nonlinear dependence sits in
    (qbar, qdbar) (and q_{k+1} for clearance) only, so derivative sweeps need about half the
    seeds they need in (Z[k], Z[k+1]), where q_k and q_{k+1} act through qbar together.
    """
    s, nf = layout.s, layout.n_f
    M = np.zeros((25 + nf + 5, 2 * s))
    I = np.eye(5)
    q0, qd0, u, f = slice(0, 5), slice(5, 10), slice(10, 15), slice(15, 15 + nf)
    q1, qd1 = slice(s, s + 5), slice(s + 5, s + 10)
    M[0:5, q0], M[0:5, q1] = 0.5 * I, 0.5 * I
    M[5:10, qd0], M[5:10, qd1] = 0.5 * I, 0.5 * I
    M[10:15, q0], M[10:15, q1] = -I, I
    M[15:20, qd0], M[15:20, qd1] = -I, I
    M[20:25, u] = I
    M[25 : 25 + nf, f] = np.eye(nf)
    M[25 + nf :, q1] = I
    return M


def interval_constraints_midpoint(layout: Layout, r, p: OCPParams):
    """Constraints of one interval as a function of its midpoint variables r (``midpoint_map``)."""
    h = p.T / layout.N
    nf = layout.n_f
    qbar, qdbar, dq, dqd, u = r[0:5], r[5:10], r[10:15], r[15:20], r[20:25]
    q1 = r[25 + nf : 30 + nf]
    if layout.pseudo_static:
        qdbar_law = dq / h  # (8): the rate from the positions; equals qdbar where (6a) holds
    else:
        qdbar_law = qdbar
    f_law = ct.contact_forces(p.model, p.foot, p.contact, qbar, qdbar_law, layout.active)
    f_used = r[25 : 25 + nf].reshape(-1, 2) if layout.augmented else f_law
    kin_res = dq - h * qdbar  # (6a)
    if layout.pseudo_static:
        dyn_res = dyn.pseudo_static_residual(p.model, qbar, u, f_used, layout.active)  # (8)
        f_c0 = ft.foot_reaction(p.model, qbar, jnp.zeros(5), jnp.zeros(5), f_used)
    else:
        qdd = dqd / h
        dyn_res = h * dyn.dynamics_residual(p.model, qbar, qdbar, qdd, u, f_used, layout.active)  # (6b)
        f_c0 = ft.foot_reaction(p.model, qbar, qdbar, qdd, f_used)
    parts = [kin_res, dyn_res]
    if layout.augmented:
        parts.append((f_used - f_law).ravel())
    parts.append(ft.foot_constraints(p.foot, p.contact.mu, f_c0, u[0]))  # (5), at the midpoint
    if layout.clear_joints:
        gaps = kin.contact_gaps(p.model, p.foot, q1)
        parts.append(gaps[jnp.asarray(layout.clear_joints) - 1])
    return jnp.concatenate(parts)


def interval_constraints(layout: Layout, za, zb, p: OCPParams):
    """Constraints of one interval from its two stages za = Z[k], zb = Z[k+1]. Shape (n_con,)."""
    r = jnp.asarray(midpoint_map(layout)) @ jnp.concatenate([za, zb])
    return interval_constraints_midpoint(layout, r, p)


def interval_cost(layout: Layout, za, zb, p: OCPParams, last_u):
    """Objective (7) terms of interval k. ``last_u``: the torque-rate term is absent (k = N-1)."""
    sl = layout.stage_slices()
    h = p.T / layout.N
    w = p.weights
    u, qd0, qd1 = za[sl["u"]], za[sl["qd"]], zb[sl["qd"]]
    du = jnp.where(last_u, 0.0, 1.0) * (zb[sl["u"]] - u)
    return h * (jnp.dot(w[:5], u**2) + w[5] * jnp.dot(qd0, qd0)) + (w[6] * jnp.dot(qd1 - qd0, qd1 - qd0) + w[7] * jnp.dot(du, du)) / h


def objective_terms(layout: Layout, Z, p: OCPParams):
    """The four terms of (7) for the whole trajectory (for reports)."""
    sl = layout.stage_slices()
    h = p.T / layout.N
    w = p.weights
    U, QD = Z[:-1, sl["u"]], Z[:, sl["qd"]]
    return {
        "torque": h * jnp.sum(U**2 @ w[:5]),
        "velocity": h * w[5] * jnp.sum(QD[:-1] ** 2),
        "acceleration": w[6] * jnp.sum(jnp.diff(QD, axis=0) ** 2) / h,
        "torque_rate": w[7] * jnp.sum(jnp.diff(U, axis=0) ** 2) / h,
    }


def stage_pairs(Z):
    """(Z[k], Z[k+1]) for k = 0..N-1 as two (N, s) arrays."""
    return Z[:-1], Z[1:]


def all_constraints(layout: Layout, Z, p: OCPParams):
    za, zb = stage_pairs(Z)
    return jax.vmap(interval_constraints, in_axes=(None, 0, 0, None))(layout, za, zb, p).ravel()


def total_cost(layout: Layout, Z, p: OCPParams):
    za, zb = stage_pairs(Z)
    last = jnp.arange(layout.N) == layout.N - 1
    return jnp.sum(jax.vmap(interval_cost, in_axes=(None, 0, 0, None, 0))(layout, za, zb, p, last))


def default_params(task, contact: ContactParams | None = None, T: float = 5.0, weights=None) -> OCPParams:
    task = tasks_mod.get_task(task)
    w = task.weights.as_array() if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (8,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(f"weights: expected 8 finite weights >= 0 (w_u1..w_u5, w_qd, w_dqd, w_du), got {weights!r}")
    return OCPParams(
        model=Humanoid.paper(),
        foot=FootParams.paper(),
        contact=ContactParams.nominal() if contact is None else contact,
        weights=jnp.asarray(w),
        T=jnp.asarray(float(T)),
        q_start=jnp.asarray(task.start),
    )


def bounds_full(layout: Layout, goal, goal_tol=tasks_mod.GOAL_TOLERANCE):
    """Lower/upper bounds in the full layout (N+1, s): joint ranges, goal box, torque and force boxes."""
    lo = np.full((layout.N + 1, layout.s), -np.inf)
    hi = np.full((layout.N + 1, layout.s), np.inf)
    lo[:, 0:5], hi[:, 0:5] = tasks_mod.Q_MIN, tasks_mod.Q_MAX
    lo[-1, 0:5] = np.maximum(tasks_mod.Q_MIN, goal - goal_tol)
    hi[-1, 0:5] = np.minimum(tasks_mod.Q_MAX, goal + goal_tol)
    lo[:, 10:15], hi[:, 10:15] = -tasks_mod.TORQUE_LIMIT, tasks_mod.TORQUE_LIMIT
    if layout.augmented:
        lo[:, 15:] = np.tile([-tasks_mod.CONTACT_FORCE_LIMIT, 0.0], len(layout.active))
        hi[:, 15:] = tasks_mod.CONTACT_FORCE_LIMIT
    return lo, hi


def initial_guess_full(layout: Layout, start, goal, T) -> np.ndarray:
    """Sec. II-G: q linear from start to goal, qd constant, u and f zero (fixed entries overwritten).

    The first interval is frozen (q_0, qd_0 = 0 and u_0 = equilibrium admit only q_1 = q_0), so
    the interpolation starts at node 1: q_1 = q_0 and qd_1 = 0, then linear to the goal at node N.
    """
    N = layout.N
    Z = np.zeros((N + 1, layout.s))
    frac = np.clip((np.arange(N + 1) - 1) / (N - 1), 0.0, 1.0)[:, None]
    Z[:, 0:5] = (1 - frac) * start + frac * goal
    Z[2 : N - 1, 5:10] = (goal - start) / (T * (N - 1) / N)
    return Z
