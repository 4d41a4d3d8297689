"""Start postures: the static equilibrium nearest to a guess that keeps the foot steady with margin.

At rest (qd = qdd = 0) every posture q is an equilibrium of (1) with the torques
u(q) = G(q) - J_F(q)^T f(q), the contact forces f(q) given by the law (3)-(4) at the gaps of q.
What a posture must satisfy to start a task is the steady foot (5) at those torques, with margin,
and the clearance of the joints that carry no contact force. ``find_equilibrium`` solves

    min_q  |q - q_guess|^2
    s.t.   f_n0 >= load_min                                       (5a), a minimum load on the foot
           (1 - friction_margin) mu f_n0 -/+ f_t0 >= 0            (5b), away from slipping
           (a0f - cop_margin) f_n0 + u_1 >= 0,
           (a0b - cop_margin) f_n0 - u_1 >= 0                     (5c), the centre of pressure inside
           y_i(q) >= clearance for the joints i not in ``active``
           q_min <= q <= q_max

by SLSQP with exact JAX derivatives (n <= ~10 variables), and reports what the posture carries
under the nominal law and, re-seated as the two-stage strategy does, under the relaxed law of
stage 1 (``reseat_for_contact``).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from scipy import optimize

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.nlp import COMPILER_OPTIONS
from jaxhumanoid.ocp.tasks import Task


@dataclasses.dataclass(frozen=True)
class Margins:
    """What the foot and the contacts carry at rest in a posture, under one contact law.

    u: (n,) equilibrium torques (N m); forces: (k, 2) (f_t, f_n) at the active joints (N);
    foot_reaction: (2,) (f_t0, f_n0) (N); foot: (5,) the products of (5); gaps: (n,) heights of
    O_1..O_n (m); load: f_n0 / (M g); friction: |f_t0| / (mu f_n0); cop: the centre of pressure
    u_1 / f_n0 (m, toes at -a0f, heel at a0b); ok: every margin of ``find_equilibrium`` holds.
    """

    u: np.ndarray
    forces: np.ndarray
    foot_reaction: np.ndarray
    foot: np.ndarray
    gaps: np.ndarray
    load: float
    friction: float
    cop: float
    ok: bool


@dataclasses.dataclass(frozen=True)
class Equilibrium:
    """A start posture: q (n,), how far it moved from the guess (rad, max norm), its margins under
    the nominal law, and the posture re-seated for the relaxed law with its margins there."""

    q: np.ndarray
    moved: float
    nominal: Margins
    q_relaxed: np.ndarray
    relaxed: Margins


@dataclasses.dataclass(frozen=True)
class MarginSpec:
    """The margins a start posture must keep (see the module docstring)."""

    load_min: float = 0.1  # f_n0 >= load_min M g
    friction_margin: float = 0.1  # |f_t0| <= (1 - friction_margin) mu f_n0
    cop_margin: float = 0.02  # m inside each edge of the sole
    clearance: float = 0.01  # m above the ground for the joints without contact force

    def foot_margin(self) -> ft.FootMargin:
        """The margins on (5) alone."""
        return ft.FootMargin(load=self.load_min, friction=self.friction_margin, cop=self.cop_margin)


def _params(model, foot, contact, q, active) -> tr.OCPParams:
    n = model.n
    task = Task("posture", np.asarray(q, float), np.asarray(q, float), tuple(active))
    return tr.default_params(task, contact=contact, model=model, foot=foot, weights=np.ones(n + 3))


def _rest(p: tr.OCPParams, q, active):
    """(u, forces, foot reaction, gaps) at rest in posture q."""
    rest = jnp.zeros_like(q)
    u = tr.equilibrium_torques(p, q, active)
    f = ct.contact_forces(p.model, p.foot, p.contact, q, rest, active)
    f_c0 = ft.foot_reaction(p.model, q, rest, rest, f)
    return u, f, f_c0, kin.contact_gaps(p.model, p.foot, q)


def _constraints(p: tr.OCPParams, active, spec: MarginSpec):
    """c(q) >= 0 of the module docstring, in newtons (the clearance rows scaled by M g / 1 m)."""
    free = np.array([i for i in range(p.model.n) if i + 1 not in active], dtype=int)
    weight = float(np.sum(np.asarray(p.model.m)) * float(p.model.g))
    margin = spec.foot_margin()

    def c(q):
        u, _, f_c0, gaps = _rest(p, q, active)
        rows = ft.foot_constraints(p.foot, p.contact.mu, f_c0, u[0], margin, weight)
        return jnp.concatenate([rows, weight * (gaps[free] - spec.clearance)])

    return c


def margins(
    model: PlanarChain,
    q,
    active,
    contact: ContactParams | None = None,
    foot: FootParams | None = None,
    spec: MarginSpec = MarginSpec(),
) -> Margins:
    """What posture q (n,) carries at rest under ``contact`` (default nominal) on ``foot``."""
    foot = FootParams.paper() if foot is None else foot
    contact = ContactParams.nominal() if contact is None else contact
    q = jnp.asarray(q, dtype=float)
    p = _params(model, foot, contact, q, active)
    u, f, f_c0, gaps = (np.asarray(a) for a in _rest(p, q, tuple(active)))
    c = np.asarray(_constraints(p, tuple(active), spec)(q))
    f_n0 = float(f_c0[1])
    return Margins(
        u=u,
        forces=f,
        foot_reaction=f_c0,
        foot=np.asarray(ft.foot_constraints(p.foot, p.contact.mu, jnp.asarray(f_c0), u[0])),
        gaps=gaps,
        load=f_n0 / float(np.sum(np.asarray(model.m)) * float(model.g)),
        friction=abs(float(f_c0[0])) / max(float(contact.mu) * f_n0, 1e-300),
        cop=float(u[0]) / f_n0 if f_n0 > 0 else float("nan"),
        ok=bool(np.all(c >= -1e-6)),
    )


@functools.partial(jax.jit, compiler_options=COMPILER_OPTIONS)
def _gaps(model: PlanarChain, foot: FootParams, q):
    """``kinematics.contact_gaps`` (n,) and its Jacobian (n, n) below, each one program: the
    Gauss-Newton loops below evaluate them a few dozen times. Compiled, they give the same bits as
    their operations evaluated one by one (tests/test_posture.py), so the seated postures, and the
    solves that start from them, do not move."""
    return kin.contact_gaps(model, foot, q)


_gaps_jacobian = jax.jit(jax.jacfwd(kin.contact_gaps, argnums=2), compiler_options=COMPILER_OPTIONS)


def _inverse_normal_force(contact: ContactParams, f):
    """y with f_n(y) = f for the law (3): y = -(f0/kappa) log2(2^(f/f0) - 1)."""
    return -(contact.f0 / contact.kappa) * np.log2(np.expm1(f * np.log(2.0) / contact.f0))


def reseat_for_contact(p: tr.OCPParams, q, active, new_contact: ContactParams, iters: int = 8):
    """Shift posture q by the least joint motion so that ``new_contact`` carries the same normal
    forces at the contacts as ``p.contact`` does at q (hence nearly the same equilibrium torques and
    foot reaction: the start posture keeps its steady-foot margins under the new law); see
    ``seat_with_forces`` for the contacts that carry less than ``LIGHT_CONTACT``.

    The motion also moves the centre of mass, and with it the ankle torque u_1 by a few N m. On a
    lightly loaded foot that can move the centre of pressure off the sole (at 0.1 M g, 3 N m is
    4 cm), and the frozen first interval would then violate (5) whatever the solver does. When the
    least motion breaks a row of (5) that held at q, the posture is seated again with u_1 as one
    more least-squares row (``seat_with_forces(ankle_torque=...)``; on the perturbed T1 starts of
    the robustness study it lands within a few N m and a few per cent of the forces, inside (5)).

    Returns (q_new, max |gap change| in m; 0 for a body without contacts).
    """
    q = np.asarray(q, dtype=float)
    idx = np.asarray(active, dtype=int) - 1
    gaps = np.asarray(_gaps(p.model, p.foot, q))[idx]
    f_nom = np.asarray(ct.normal_force(p.contact, gaps))
    q_new = seat_with_forces(p.model, p.foot, new_contact, q, active, f_nom, iters)
    rows, u1 = rest_foot_rows(p.model, p.foot, p.contact, q, active)
    rows_new, _ = rest_foot_rows(p.model, p.foot, new_contact, q_new, active)
    if np.min(rows_new) < min(0.0, float(np.min(rows))):
        q_new = seat_with_forces(p.model, p.foot, new_contact, q, active, f_nom, 4 * iters, ankle_torque=u1)
    gaps_new = np.asarray(_gaps(p.model, p.foot, q_new))[idx]
    return q_new, float(np.max(np.abs(gaps_new - gaps), initial=0.0))


def rest_foot_rows(model, foot, contact, q, active) -> tuple[np.ndarray, float]:
    """The rows (5) at rest in posture q under ``contact`` (no margins), and the ankle torque u_1."""
    p = _params(model, foot, contact, q, active)
    u, _, f_c0, _ = _rest(p, jnp.asarray(q), tuple(active))
    return np.asarray(ft.foot_constraints(p.foot, p.contact.mu, f_c0, u[0])), float(u[0])


LIGHT_CONTACT = 1.0  # N: a contact asked to carry less is lifted no higher than where it carries this


def seat_with_forces(
    model: PlanarChain,
    foot: FootParams,
    contact: ContactParams,
    q,
    active,
    forces,
    iters: int = 8,
    ankle_torque: float | None = None,
):
    """Posture q (n,) moved by the least joint motion (Gauss-Newton, minimum-norm steps) so that the
    law ``contact`` carries the normal ``forces`` (k,) (N) at the ``active`` joints; with
    ``ankle_torque`` (N m) the ankle's equilibrium torque is one more row, and the posture the
    damped Gauss-Newton steps end at is the least-squares compromise of the rows.

    A contact asked for less than ``LIGHT_CONTACT`` is left where it is when the law loads it
    lightly there too; when the law presses it harder (a softer law reaches further: the relaxed
    law of stage 1 carries ~200 N at a gap where the nominal one carries 0.5 N), it is lifted to
    where the law carries ``LIGHT_CONTACT``, so that no contact takes load the posture did not have.
    """
    q = np.asarray(q, dtype=float)
    forces = np.asarray(forces, dtype=float)
    rows_all = np.asarray(active, dtype=int) - 1
    at_q = np.asarray(ct.normal_force(contact, np.asarray(_gaps(model, foot, q))[rows_all]))
    seated = (forces > LIGHT_CONTACT) | (at_q > LIGHT_CONTACT)
    if not np.any(seated):
        return q
    target = _inverse_normal_force(contact, np.maximum(forces[seated], LIGHT_CONTACT))
    rows = rows_all[seated]
    if ankle_torque is not None:
        return _seat_keeping_ankle(model, foot, contact, q, active, rows, target, float(ankle_torque), iters)
    q_new = q.copy()
    for _ in range(iters):
        y = np.asarray(_gaps(model, foot, q_new))[rows]
        J = np.asarray(_gaps_jacobian(model, foot, jnp.asarray(q_new)))[rows]
        q_new = q_new + np.linalg.lstsq(J, target - y, rcond=None)[0]
    return q_new


def _seat_keeping_ankle(model, foot, contact, q, active, rows, target, ankle_torque: float, iters: int):
    """``seat_with_forces`` with the ankle's equilibrium torque as one more row: damped Gauss-Newton
    (the step halved until the residual, gaps in m and the torque in kN m, decreases), because
    the torque depends on the gaps through the steep law."""
    p = _params(model, foot, contact, q, active)

    def residual(qq):
        u1 = tr.equilibrium_torques(p, qq, tuple(active))[:1]
        return jnp.concatenate([kin.contact_gaps(model, foot, qq)[rows] - target, 1e-3 * (u1 - ankle_torque)])

    jac = jax.jacfwd(residual)
    q_new = np.asarray(q, dtype=float).copy()
    for _ in range(iters):
        r = np.asarray(residual(jnp.asarray(q_new)))
        step = np.linalg.lstsq(np.asarray(jac(jnp.asarray(q_new))), r, rcond=None)[0]
        t = 1.0
        while t > 1e-3 and np.linalg.norm(residual(jnp.asarray(q_new - t * step))) > np.linalg.norm(r):
            t *= 0.5
        q_new = q_new - t * step
    return q_new


def find_equilibrium(
    model: PlanarChain,
    q_guess,
    active,
    contact: ContactParams | None = None,
    foot: FootParams | None = None,
    q_min=None,
    q_max=None,
    spec: MarginSpec = MarginSpec(),
    relaxed: ContactParams | None = None,
) -> Equilibrium:
    """The static equilibrium nearest to ``q_guess`` (n,) that keeps the foot steady with margin.

    ``active``: the joints (1..n) that may carry contact forces; ``contact`` the law (default
    nominal); ``q_min``/``q_max`` the joint ranges (default the body's); ``relaxed`` the law of
    stage 1 (default ``ContactParams.relaxed()``). Raises ValueError naming what fails when no
    such posture is found near the guess.
    """
    foot = FootParams.paper() if foot is None else foot
    contact = ContactParams.nominal() if contact is None else contact
    active = tuple(int(i) for i in active)
    q_guess = np.asarray(q_guess, dtype=float)
    if q_guess.shape != (model.n,) or not np.all(np.isfinite(q_guess)):
        raise ValueError(f"q_guess: expected {model.n} finite joint angles (rad), got {q_guess!r}")
    if not all(1 <= i <= model.n for i in active):
        raise ValueError(f"active: expected joints in 1..{model.n}, got {active!r}")
    lo = np.asarray(model.q_min if q_min is None else q_min, dtype=float)
    hi = np.asarray(model.q_max if q_max is None else q_max, dtype=float)
    p = _params(model, foot, contact, q_guess, active)
    c = jax.jit(_constraints(p, active, spec))
    dc = jax.jit(jax.jacfwd(_constraints(p, active, spec)))
    scale = 1.0 / max(float(np.sum(np.asarray(model.m)) * float(model.g)), 1.0)
    res = optimize.minimize(
        lambda q: float(np.sum((q - q_guess) ** 2)),
        np.clip(q_guess, lo, hi),
        jac=lambda q: 2.0 * (q - q_guess),
        method="SLSQP",
        bounds=list(zip(lo, hi)),
        constraints=[
            {"type": "ineq", "fun": lambda q: scale * np.asarray(c(q)), "jac": lambda q: scale * np.asarray(dc(q))}
        ],
        options={"maxiter": 500, "ftol": 1e-14},
    )
    q = np.asarray(res.x, dtype=float)
    nominal = margins(model, q, active, contact, foot, spec)
    if not nominal.ok:
        raise ValueError(
            f"find_equilibrium: no static equilibrium keeping the foot steady (5) with margin "
            f"was found near q_guess (SLSQP: {res.message}); at the end the foot load is "
            f"{nominal.load:.2f} M g, friction use {nominal.friction:.2f}, centre of pressure "
            f"{nominal.cop:+.3f} m in [{-float(foot.a0f):.3f}, {float(foot.a0b):.3f}]"
        )
    relaxed = ContactParams.relaxed() if relaxed is None else relaxed
    q_rel, _ = reseat_for_contact(p, q, active, relaxed)
    return Equilibrium(
        q=q,
        moved=float(np.max(np.abs(q - q_guess))),
        nominal=nominal,
        q_relaxed=q_rel,
        relaxed=margins(model, q_rel, active, relaxed, foot, spec),
    )


def check_start_margin(task: Task, model: PlanarChain, margin: ft.FootMargin, contact=None, foot=None) -> None:
    """Raise a ValueError when the task's start posture, at rest under ``contact`` on ``foot``, does not
    keep the foot within ``margin``: a plan's first interval is frozen at its start (qd_0 = 0, u_0 the
    equilibrium torques), so a plan with margin needs a start that has it."""
    spec = MarginSpec(load_min=margin.load, friction_margin=margin.friction, cop_margin=margin.cop, clearance=0.0)
    m = margins(model, task.start, task.active, contact=contact, foot=foot, spec=spec)
    if not m.ok:
        foot = FootParams.paper() if foot is None else foot
        raise ValueError(
            f"foot_margin: the start posture of task {task.key} keeps a foot load of {m.load:.3f} M g, uses "
            f"{m.friction:.3f} of the friction cone and has its centre of pressure at {m.cop:+.4f} m in "
            f"[{-float(foot.a0f):.3f}, {float(foot.a0b):.3f}]; allowed: load <= {m.load:.3f}, "
            f"friction <= {1 - m.friction:.3f}, cop <= {min(m.cop + float(foot.a0f), float(foot.a0b) - m.cop):.4f} m"
        )
