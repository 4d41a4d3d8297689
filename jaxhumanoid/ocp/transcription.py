"""Direct transcription with the implicit midpoint rule (6), the pseudo-static model (8), NLP (7).

Grid: N intervals of length h = T/N, nodes k = 0..N. Per stage k the full layout holds

    Z[k] = (q_k, qd_k, u_k, f_k)        q, qd, u in R^n; f in R^{2|F|} under scheme A (else empty)

for a chain of n links (for k = N, u_N and f_N are padding, fixed at zero), so the paper's stacked vector
{q_0, qd_0, u_0, f_0, ..., q_N, qd_N} is Z flattened. The NLP variables x are the free entries:
q_0, qd_0 = 0 and u_0 (equilibrium torques) are fixed by the initial conditions, and qd_{N-1} =
qd_N = 0 by the terminal static equilibrium, which gives the paper's count

    2n(N+1) + nN + 2|F|N - 3n - 2n variables  (the humanoid, n = 5: 1485 for E-F, 2485 for A-F at N = 100).

Constraints of interval k, functions of (Z[k], Z[k+1]) only, in this order:

    (6a)  q_{k+1} - q_k - h qdbar_k = 0                                              n
    (6b)  B(qbar_k)(qd_{k+1} - qd_k) + h (C qdbar_k + G(qbar_k) - Q(qbar_k, qdbar_k, u_k)) = 0
          or, pseudo-static, (8): G(qbar_k) - Q(qbar_k, (q_{k+1} - q_k)/h, u_k) = 0   n
    A:    f_k - (f_t, f_n)(qbar_k, qdbar_k) = 0   (laws (3)-(4) at the midpoint)    2|F|
    (5)   steady-foot products >= 0 at the midpoint, tightened by p.foot_margin      5
    F+C:  y_Oi(q_{k+1}) >= 0 for the joints without a contact force                 n - |F|

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
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import tasks as tasks_mod
from jaxhumanoid.pytree import pytree_dataclass

N_FOOT = 5  # steady-foot products (5a)-(5c) per interval


@pytree_dataclass
class OCPParams:
    """Everything numeric the NLP depends on (a pytree: vmap and differentiate over it).

    For a chain of n links: weights (n + 3,) = (w_u1..w_un, w_qd, w_dqd, w_du); T: horizon (s);
    q_start: (n,) start posture; foot_margin: how far inside the edges of (5) the foot is kept
    (``model.foot.FootMargin``; all zero, the default, is (5) itself).
    """

    model: PlanarChain
    foot: FootParams
    contact: ContactParams
    weights: jax.Array | np.ndarray
    T: jax.Array | float
    q_start: jax.Array | np.ndarray
    foot_margin: ft.FootMargin = ft.FootMargin()


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static shape information of one transcription of a chain of ``n_links`` links."""

    N: int
    active: tuple  # joints with contact forces (1..n_links)
    augmented: bool
    clearance: bool
    pseudo_static: bool
    n_links: int
    # scheme E's contact-force limit: one row per contact joint, its normal force f_n (3) at the
    # midpoint, bounded above by the task's limit (scheme A bounds its force variables instead)
    force_rows: bool = False

    def __post_init__(self):
        if not isinstance(self.n_links, (int, np.integer)) or self.n_links < 2:
            raise ValueError(f"Layout.n_links: expected an integer >= 2, got {self.n_links!r}")
        if not all(1 <= i <= self.n_links for i in self.active):
            raise ValueError(f"Layout.active: joints must lie in 1..{self.n_links}, got {self.active!r}")

    @property
    def n_f(self) -> int:
        return 2 * len(self.active) if self.augmented else 0

    @property
    def s(self) -> int:
        """Variables per stage in the full layout."""
        return 3 * self.n_links + self.n_f

    @property
    def clear_joints(self) -> tuple:
        return tuple(i for i in range(1, self.n_links + 1) if i not in self.active) if self.clearance else ()

    @property
    def n_force_rows(self) -> int:
        """Normal-force rows per interval (``force_rows``)."""
        return len(self.active) if self.force_rows else 0

    @property
    def n_con(self) -> int:
        """Constraints per interval."""
        return 2 * self.n_links + self.n_f + N_FOOT + len(self.clear_joints) + self.n_force_rows

    def stage_slices(self) -> dict[str, slice]:
        """Columns of q, qd, u (n each) and f (n_f) in a stage of the full layout."""
        n = self.n_links
        return dict(q=slice(0, n), qd=slice(n, 2 * n), u=slice(2 * n, 3 * n), f=slice(3 * n, 3 * n + self.n_f))

    def free_mask(self) -> np.ndarray:
        """(N+1, s) boolean: True for NLP variables."""
        sl = self.stage_slices()
        free = np.ones((self.N + 1, self.s), dtype=bool)
        free[0, 0 : sl["u"].stop] = False  # q_0, qd_0, u_0
        free[self.N - 1, sl["qd"]] = False  # qd_{N-1}
        free[self.N, sl["qd"].start :] = False  # qd_N and the padding u_N, f_N
        return free

    def constraint_kinds(self) -> np.ndarray:
        """Per-interval constraint kinds: 0 equality, 1 inequality (>= 0), 2 a normal force bounded
        above by the task's contact-force limit (``force_rows``)."""
        eq, ineq = 2 * self.n_links + self.n_f, N_FOOT + len(self.clear_joints)
        return np.array([0] * eq + [1] * ineq + [2] * self.n_force_rows)


def equilibrium_torques(p: OCPParams, q, active):
    """u with G(q) = Q(q, 0, u): static equilibrium of (1) at rest. q: (n,) -> (n,)."""
    rest = jnp.zeros(p.model.n)
    f = ct.contact_forces(p.model, p.foot, p.contact, q, rest, active)
    return dyn.gravity_vector(p.model, q) - dyn.generalized_forces(p.model, q, rest, f, active)


def full_from_free(layout: Layout, x, p: OCPParams):
    """Scatter the NLP vector x into the full (N+1, s) layout, fixed entries from p."""
    base = jnp.zeros((layout.N + 1, layout.s), dtype=jnp.float64)
    q0 = jnp.asarray(p.q_start, dtype=jnp.float64)
    sl = layout.stage_slices()
    base = base.at[0, sl["q"]].set(q0).at[0, sl["u"]].set(equilibrium_torques(p, q0, layout.active))
    idx = np.flatnonzero(layout.free_mask().ravel())
    return base.ravel().at[idx].set(x).reshape(layout.N + 1, layout.s)


def free_from_full(layout: Layout, Z):
    return jnp.asarray(Z).ravel()[np.flatnonzero(layout.free_mask().ravel())]


def midpoint_slices(layout: Layout) -> dict[str, slice]:
    """Entries of the midpoint variables r (``midpoint_map``): n each, f n_f; size 6n + n_f."""
    n, nf = layout.n_links, layout.n_f
    names = ("qbar", "qdbar", "dq", "dqd", "u")
    out = {name: slice(i * n, (i + 1) * n) for i, name in enumerate(names)}
    out["f"] = slice(5 * n, 5 * n + nf)
    out["q1"] = slice(5 * n + nf, 6 * n + nf)
    return out


def midpoint_map(layout: Layout) -> np.ndarray:
    """Constant matrix M (6n + n_f, 2s) with r = M (Z[k], Z[k+1]): the interval's midpoint variables

        r = (qbar, qdbar, dq = q_{k+1} - q_k, dqd = qd_{k+1} - qd_k, u_k, f_k, q_{k+1})

    Every constraint of the interval is a function of r. In r the nonlinear dependence sits in
    (qbar, qdbar) (and q_{k+1} for clearance) only, so derivative sweeps need about half the
    seeds they need in (Z[k], Z[k+1]), where q_k and q_{k+1} act through qbar together.
    """
    s, n = layout.s, layout.n_links
    sl, r = layout.stage_slices(), midpoint_slices(layout)
    M = np.zeros((r["q1"].stop, 2 * s))
    I = np.eye(n)
    q0, qd0, u, f = sl["q"], sl["qd"], sl["u"], sl["f"]
    q1, qd1 = slice(s + q0.start, s + q0.stop), slice(s + qd0.start, s + qd0.stop)
    M[r["qbar"], q0], M[r["qbar"], q1] = 0.5 * I, 0.5 * I
    M[r["qdbar"], qd0], M[r["qdbar"], qd1] = 0.5 * I, 0.5 * I
    M[r["dq"], q0], M[r["dq"], q1] = -I, I
    M[r["dqd"], qd0], M[r["dqd"], qd1] = -I, I
    M[r["u"], u] = I
    M[r["f"], f] = np.eye(layout.n_f)
    M[r["q1"], q1] = I
    return M


# The parts of r grouped by how much of the model a forward tangent seeded in them passes through:
# the positions reach every kinematic term, the rates the velocity terms, and (dq, dqd, u, f)
# enter (6)-(8) and (3)-(5) only through products with terms of the positions and rates.
MIDPOINT_GROUPS = (("qbar", "q1"), ("qdbar",), ("dq", "dqd", "u", "f"))


def midpoint_groups(layout: Layout) -> tuple[np.ndarray, ...]:
    """Indices into r of each of ``MIDPOINT_GROUPS``: a partition of r's 6n + n_f entries."""
    sl = midpoint_slices(layout)
    return tuple(np.concatenate([np.arange(sl[k].start, sl[k].stop) for k in names]) for names in MIDPOINT_GROUPS)


def interval_constraints_midpoint(layout: Layout, r, p: OCPParams):
    """Constraints of one interval as a function of its midpoint variables r (``midpoint_map``)."""
    return _interval_constraints(layout, {k: r[s] for k, s in midpoint_slices(layout).items()}, p)


def interval_constraints_grouped(layout: Layout, zs, p: OCPParams):
    """``interval_constraints_midpoint`` of r given as its groups zs[g] = r[midpoint_groups(layout)[g]].

    A forward sweep that differentiates one group only, the others held, carries tangents through
    the operations that group reaches (``derivatives.local``'s grouped Jacobian)."""
    sl = midpoint_slices(layout)
    parts = {}
    for names, z in zip(MIDPOINT_GROUPS, zs, strict=True):
        i = 0
        for k in names:
            size = sl[k].stop - sl[k].start
            parts[k], i = z[i : i + size], i + size
    return _interval_constraints(layout, parts, p)


def _interval_constraints(layout: Layout, parts: dict, p: OCPParams):
    h = p.T / layout.N
    qbar, qdbar, dq, dqd, u = (parts[k] for k in ("qbar", "qdbar", "dq", "dqd", "u"))
    q1 = parts["q1"]
    if layout.pseudo_static:
        qdbar_law = dq / h  # (8): the rate from the positions; equals qdbar where (6a) holds
    else:
        qdbar_law = qdbar
    f_law = ct.contact_forces(p.model, p.foot, p.contact, qbar, qdbar_law, layout.active)
    f_used = parts["f"].reshape(-1, 2) if layout.augmented else f_law
    kin_res = dq - h * qdbar  # (6a)
    if layout.pseudo_static:
        dyn_res = dyn.pseudo_static_residual(p.model, qbar, u, f_used, layout.active)  # (8)
        rest = jnp.zeros(layout.n_links)
        f_c0 = ft.foot_reaction(p.model, qbar, rest, rest, f_used)
    else:
        qdd = dqd / h
        dyn_res = h * dyn.dynamics_residual(p.model, qbar, qdbar, qdd, u, f_used, layout.active)  # (6b)
        f_c0 = ft.foot_reaction(p.model, qbar, qdbar, qdd, f_used)
    rows = [kin_res, dyn_res]
    if layout.augmented:
        rows.append((f_used - f_law).ravel())
    weight = p.model.total_mass * p.model.g
    rows.append(ft.foot_constraints(p.foot, p.contact.mu, f_c0, u[0], p.foot_margin, weight))  # (5), at the midpoint
    if layout.clear_joints:
        gaps = kin.contact_gaps(p.model, p.foot, q1)
        rows.append(gaps[jnp.asarray(layout.clear_joints) - 1])
    if layout.force_rows:
        rows.append(f_law[:, 1])  # f_n <= the contact-force limit (bounds of the NLP)
    return jnp.concatenate(rows)


def interval_constraints(layout: Layout, za, zb, p: OCPParams):
    """Constraints of one interval from its two stages za = Z[k], zb = Z[k+1]. Shape (n_con,)."""
    r = jnp.asarray(midpoint_map(layout)) @ jnp.concatenate([za, zb])
    return interval_constraints_midpoint(layout, r, p)


def interval_cost(layout: Layout, za, zb, p: OCPParams, last_u):
    """Objective (7) terms of interval k. ``last_u``: the torque-rate term is absent (k = N-1)."""
    sl = layout.stage_slices()
    h = p.T / layout.N
    w = p.weights
    n = layout.n_links
    u, qd0, qd1 = za[sl["u"]], za[sl["qd"]], zb[sl["qd"]]
    du = jnp.where(last_u, 0.0, 1.0) * (zb[sl["u"]] - u)
    effort = h * (jnp.dot(w[:n], u**2) + w[n] * jnp.dot(qd0, qd0))
    return effort + (w[n + 1] * jnp.dot(qd1 - qd0, qd1 - qd0) + w[n + 2] * jnp.dot(du, du)) / h


OBJECTIVE_TERMS = ("torque", "velocity", "acceleration", "torque_rate")  # (7)'s terms, in its order


def objective_terms(layout: Layout, Z, p: OCPParams):
    """The four terms of (7) for the whole trajectory (for reports), keyed by ``OBJECTIVE_TERMS``."""
    sl = layout.stage_slices()
    h = p.T / layout.N
    w, n = p.weights, layout.n_links
    U, QD = Z[:-1, sl["u"]], Z[:, sl["qd"]]
    return {
        "torque": h * jnp.sum(U**2 @ w[:n]),
        "velocity": h * w[n] * jnp.sum(QD[:-1] ** 2),
        "acceleration": w[n + 1] * jnp.sum(jnp.diff(QD, axis=0) ** 2) / h,
        "torque_rate": w[n + 2] * jnp.sum(jnp.diff(U, axis=0) ** 2) / h,
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


def default_params(
    task,
    contact: ContactParams | None = None,
    T: float = 5.0,
    weights=None,
    model: PlanarChain | None = None,
    foot: FootParams | None = None,
    foot_margin: ft.FootMargin | None = None,
) -> OCPParams:
    """Parameters of ``task`` for ``model`` (default the humanoid) on ``foot`` (default the paper's),
    with the ``contact`` law (default nominal), the task's weights unless ``weights`` (n + 3,) and
    the ``foot_margin`` on (5) (default none)."""
    task = tasks_mod.get_task(task)
    model = PlanarChain.humanoid() if model is None else model
    n = model.n
    if task.n != n:
        raise ValueError(f"model: task {task.key} is posed for {task.n} joints, the chain has {n} links")
    w = task.weights.as_array(n) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (n + 3,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(
            f"weights: expected {n + 3} finite weights >= 0 (w_u1..w_u{n}, w_qd, w_dqd, w_du), got {weights!r}"
        )
    foot = FootParams.paper() if foot is None else foot
    return OCPParams(
        model=model,
        foot=foot,
        contact=ContactParams.nominal() if contact is None else contact,
        weights=jnp.asarray(w),
        T=jnp.asarray(float(T)),
        q_start=jnp.asarray(task.start),
        foot_margin=ft.check_foot_margin(foot_margin, foot),
    )


def bounds_full(
    layout: Layout, goal, q_min, q_max, u_max, goal_tol=tasks_mod.GOAL_TOLERANCE, f_max=tasks_mod.CONTACT_FORCE_LIMIT
):
    """Lower/upper bounds in the full layout (N+1, s): joint ranges q_min/q_max (n,), goal box,
    torque box [-u_max, u_max] (n,) and force box: f_t in [-f_max, f_max], f_n <= f_max (N).

    f_n has no lower bound: its row f_n = f_n(y) of (3) keeps it positive, and a bound f_n >= 0
    would put a barrier term -mu log f_n on a contact in the air, where f_n(y) ~ 2^(-kappa y / f0)
    is 1e-20 and smaller; its multiplier mu / f_n then dominates the KKT system and the
    interior-point path crawls (stage 1 of the reference-posing tasks: 107-397 iterations with
    the bound, 34-51 without on T2-T4)."""
    sl = layout.stage_slices()
    lo = np.full((layout.N + 1, layout.s), -np.inf)
    hi = np.full((layout.N + 1, layout.s), np.inf)
    lo[:, sl["q"]], hi[:, sl["q"]] = q_min, q_max
    lo[-1, sl["q"]] = np.maximum(q_min, goal - goal_tol)
    hi[-1, sl["q"]] = np.minimum(q_max, goal + goal_tol)
    u_max = np.asarray(u_max, dtype=float)
    lo[:, sl["u"]], hi[:, sl["u"]] = -u_max, u_max
    if layout.augmented:
        lo[:, sl["f"]] = np.tile([-f_max, -np.inf], len(layout.active))
        hi[:, sl["f"]] = f_max
    return lo, hi


def initial_guess_full(layout: Layout, start, goal, T) -> np.ndarray:
    """Sec. II-G: q linear from start to goal, qd constant, u and f zero (fixed entries overwritten).

    The first interval is frozen (q_0, qd_0 = 0 and u_0 = equilibrium admit only q_1 = q_0), so
    the interpolation starts at node 1: q_1 = q_0 and qd_1 = 0, then linear to the goal at node N.
    """
    N = layout.N
    sl = layout.stage_slices()
    Z = np.zeros((N + 1, layout.s))
    frac = np.clip((np.arange(N + 1) - 1) / (N - 1), 0.0, 1.0)[:, None]
    Z[:, sl["q"]] = (1 - frac) * start + frac * goal
    Z[2 : N - 1, sl["qd"]] = (goal - start) / (T * (N - 1) / N)
    return Z


def inverse_dynamics_guess(layout: Layout, Z, p: OCPParams) -> np.ndarray:
    """``Z`` with the torques u_k (k >= 1) and, under A, the forces f_k of every interval set to the
    inverse dynamics of its motion: the dynamics rows ((6b), or (8) when pseudo-static) and the force
    rows hold exactly at the guess, so only the foot, clearance and bound rows can be violated.

    Q = u + J^T f in (2), so the residual of (6b) or (8) at u = 0 is the torque that zeroes it.
    The first interval keeps its fixed equilibrium torque u_0.
    """
    sl, rs = layout.stage_slices(), midpoint_slices(layout)
    M = jnp.asarray(midpoint_map(layout))
    h = p.T / layout.N

    def interval(za, zb):
        r = M @ jnp.concatenate([za, zb])
        qbar, qdbar, dq, dqd = r[rs["qbar"]], r[rs["qdbar"]], r[rs["dq"]], r[rs["dqd"]]
        zero = jnp.zeros(layout.n_links)
        rate = dq / h if layout.pseudo_static else qdbar  # the rate the force rows use
        f = ct.contact_forces(p.model, p.foot, p.contact, qbar, rate, layout.active)
        if layout.pseudo_static:
            u = dyn.pseudo_static_residual(p.model, qbar, zero, f, layout.active)
        else:
            u = dyn.dynamics_residual(p.model, qbar, qdbar, dqd / h, zero, f, layout.active)
        return u, f.ravel()

    Z = np.array(Z, dtype=float)
    u, f = (np.asarray(a) for a in jax.vmap(interval)(jnp.asarray(Z[:-1]), jnp.asarray(Z[1:])))
    Z[1 : layout.N, sl["u"]] = u[1:]
    if layout.augmented:
        Z[: layout.N, sl["f"]] = f
    return Z
