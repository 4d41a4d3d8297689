"""A fixed-step simulator of the body under the smooth contact law, independent of the transcription.

State x = (q, qd), shape (2n,); torque u, shape (n,), held constant over a step (zero-order hold).
One step of length dt is the implicit midpoint rule applied to (1)-(2) with the contact law (3)-(4)
at the active joints, solved for qd+ by Newton's method (the unknowns are qd+ only, since
q+ = q + dt (qd + qd+) / 2):

    r(qd+) = B(qbar)(qd+ - qd) + dt (C(qbar, qdbar) qdbar + G(qbar) - Q(qbar, qdbar, u, f(qbar, qdbar))) = 0
    qbar = q + dt (qd + qd+) / 4,   qdbar = (qd + qd+) / 2

The scheme is A-stable, so the stiff contact (kappa) and friction (mu f_n / xhat) modes do not
force a tiny step; run at dt = h / m it is a grid m times finer than the plan's. With m = 1 a step
is exactly the plan's (6a)-(6b), which is what the tests use to check the simulator against the plan.

Each step also evaluates what the plan keeps as constraints: the five products of (5) at the
midpoint (foot reaction from the inverse translational dynamics, ``model.foot``), and the heights
of the joints O_1..O_n at the step's end (segments are straight between joints, so their lowest
points are joints or the ankle, which is fixed above the ground).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import dynamics as dyn
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.pytree import pytree_dataclass

NEWTON_TOL = 1e-10  # on |r|_inf / (M g dt): the residual is an impulse, scaled by the body weight
NEWTON_MAX_ITERS = 50
LINE_SEARCH = 16  # step halvings tried per Newton iteration
MAX_NEWTON_STEP = 5.0  # rad/s: the largest change of any rate in one Newton iteration
ARMIJO = 1e-4  # sufficient decrease of the line search


@pytree_dataclass
class Plant:
    """The simulated body: chain, foot and contact law (every field a pytree leaf, so perturbed
    plants can be stacked and ``vmap``-ed over)."""

    model: PlanarChain
    foot: FootParams
    contact: ContactParams


class StepInfo(NamedTuple):
    """What one step reports: the (5) products at the midpoint (5,), the joint heights at the end
    (n,), the Newton residual (scaled, see ``NEWTON_TOL``) and the iterations used."""

    foot_margins: jax.Array
    gaps: jax.Array
    residual: jax.Array
    iterations: jax.Array


def _split(x):
    n = x.shape[-1] // 2
    return x[:n], x[n:]


def midpoint_residual(plant: Plant, active: tuple, dt, x, u, qd1):
    """r(qd+) of the module docstring, shape (n,) (N m s)."""
    q0, qd0 = _split(x)
    qdbar = 0.5 * (qd0 + qd1)
    qbar = q0 + 0.5 * dt * qdbar
    f = ct.contact_forces(plant.model, plant.foot, plant.contact, qbar, qdbar, active)
    return dt * dyn.dynamics_residual(plant.model, qbar, qdbar, (qd1 - qd0) / dt, u, f, active)


def _newton(plant: Plant, active: tuple, dt, x, u):
    """qd+ solving r = 0 from the guess qd+ = qd, to NEWTON_TOL or NEWTON_MAX_ITERS iterations.

    Damped Newton: of the steps alpha = 1, 1/2, ..., 2^-(LINE_SEARCH - 1) along the Newton
    direction (capped at MAX_NEWTON_STEP) the first that decreases |r|_2 by the factor
    (1 - ARMIJO alpha) is taken (else the shortest). Full steps alone can jump to a spurious
    root of the stiff friction law (4) with rates of hundreds of rad/s, or cycle without converging.
    """
    scale = 1.0 / (plant.model.total_mass * plant.model.g * dt)
    res = lambda v: midpoint_residual(plant, active, dt, x, u, v)  # noqa: E731
    jac = jax.jacfwd(res)
    alphas = 0.5 ** jnp.arange(LINE_SEARCH)

    def cond(state):
        _, r, it = state
        return (jnp.max(jnp.abs(r)) * scale > NEWTON_TOL) & (it < NEWTON_MAX_ITERS) & jnp.all(jnp.isfinite(r))

    def body(state):
        v, r, it = state
        d = -jnp.linalg.solve(jac(v), r)
        d = d * jnp.minimum(1.0, MAX_NEWTON_STEP / jnp.max(jnp.abs(d)))
        trials = v[None] + alphas[:, None] * d[None]
        r_trials = jax.vmap(res)(trials)
        norms = jnp.linalg.norm(r_trials, axis=1)
        ok = norms <= (1.0 - ARMIJO * alphas) * jnp.linalg.norm(r)
        k = jnp.where(jnp.any(ok), jnp.argmax(ok), LINE_SEARCH - 1)
        return trials[k], r_trials[k], it + 1

    v0 = _split(x)[1]
    v, r, it = jax.lax.while_loop(cond, body, (v0, res(v0), jnp.asarray(0)))
    return v, jnp.max(jnp.abs(r)) * scale, it


def step(plant: Plant, active: tuple, dt, x, u):
    """One implicit-midpoint step: x (2n,), u (n,) -> (x+ (2n,), StepInfo).

    Newton runs without derivatives; one more Newton step from its answer carries them, so that
    ``jax.jacfwd`` of ``step`` is the implicit-function derivative -(dr/dqd+)^-1 dr/d(x, u) at the
    solution rather than the derivative of the iterations.
    """
    v_star, resid, it = _newton(plant, active, dt, jax.lax.stop_gradient(x), jax.lax.stop_gradient(u))
    v_star = jax.lax.stop_gradient(v_star)
    res = lambda v: midpoint_residual(plant, active, dt, x, u, v)  # noqa: E731
    qd1 = v_star - jnp.linalg.solve(jax.jacfwd(res)(v_star), res(v_star))
    q0, qd0 = _split(x)
    q1 = q0 + 0.5 * dt * (qd0 + qd1)
    return jnp.concatenate([q1, qd1]), step_info(plant, active, dt, x, u, q1, qd1, resid, it)


def step_reaction(plant: Plant, active: tuple, dt, x, q1, qd1):
    """The ground reaction on the foot (f_t0, f_n0) (2,) at the midpoint of the step x -> (q1, qd1)."""
    q0, qd0 = _split(x)
    qbar, qdbar = 0.5 * (q0 + q1), 0.5 * (qd0 + qd1)
    f = ct.contact_forces(plant.model, plant.foot, plant.contact, qbar, qdbar, active)
    return ft.foot_reaction(plant.model, qbar, qdbar, (qd1 - qd0) / dt, f)


def step_info(plant: Plant, active: tuple, dt, x, u, q1, qd1, resid, it) -> StepInfo:
    """The (5) products at the step's midpoint and the joint heights at its end."""
    f_c0 = step_reaction(plant, active, dt, x, q1, qd1)
    margins = ft.foot_constraints(plant.foot, plant.contact.mu, f_c0, u[0])
    return StepInfo(margins, kin.contact_gaps(plant.model, plant.foot, q1), resid, it)


class Reference(NamedTuple):
    """The plan on the simulator's grid of M steps of dt: node times t (M+1,), states x (M+1, 2n),
    torques u (M, n) (held over each step)."""

    t: jax.Array
    x: jax.Array
    u: jax.Array

    @property
    def dt(self):
        return self.t[1] - self.t[0]


class Rollout(NamedTuple):
    """A simulated run of M steps: states x (M+1, 2n), applied torques u (M, n), the (5) products
    per step (M, 5), the joint heights at the step ends (M, n), the Newton residual (M,), and per
    step what a safety filter reported (``tracking.filter.FilterInfo``; zeros without one): its
    largest slack (body weights), its QP's KKT residual, its largest torque change (N m), (M,) each."""

    x: jax.Array
    u: jax.Array
    foot_margins: jax.Array
    gaps: jax.Array
    residual: jax.Array
    filter_slack: jax.Array
    filter_residual: jax.Array
    filter_change: jax.Array


def rollout(
    plant: Plant,
    active: tuple,
    ref: Reference,
    x0,
    gains,
    noise,
    u_max,
    u_hold=None,
    blend=None,
    shield=None,
) -> Rollout:
    """Run the policy u_j = clip(u_ref_j + K_j (x_j - x_ref_j) + noise_j, -u_max, u_max) from x0.

    x0: (2n,); gains: (M, n, 2n) (zeros for the open-loop replay of the planned torques);
    noise: (M, n) torque noise (N m); u_max: (n,) the body's strengths. With ``u_hold`` (n,), the
    torques that hold the body at rest in x0, and ``blend`` (M,) falling from 1 to 0, the start is
    blended into the plan: the reference is moved by blend_j (x0 - x_ref_0, u_hold - u_ref_0), so
    that the policy starts exactly where the body is, at rest and with the torques it holds, and
    joins the plan as the blend falls. A step whose Newton solve ends in non-finite numbers keeps
    the state it started from (its residual says so), so one diverged trial neither poisons a batch
    nor hides behind NaNs.

    With ``shield``, a function (x, u, memo) -> (u', (slack, residual, change), prediction) such
    as the steady-foot filter of ``tracking.filter``, the controller's torque (before the noise,
    which the controller does not know) is replaced by u' and the noise added to that; the three
    scalars are recorded. memo = (its previous prediction (5,), the (5) products the body's step
    produced then (5,), as a foot force sensor measures them), NaN before the first step.
    """
    dt = ref.dt
    if blend is None:
        blend, u_hold = jnp.zeros(ref.u.shape[0]), ref.u[0]
    dx0, du0 = x0 - ref.x[0], u_hold - ref.u[0]
    zero = jnp.zeros(())

    def body(carry, inputs):
        x, memo = carry
        x_ref, u_ref, K, w, b = inputs
        u = u_ref + b * du0 + K @ (x - x_ref - b * dx0)
        report, prediction = (zero, zero, zero), memo[0]
        if shield is not None:
            u, report, prediction = shield(x, u, memo)
        u = jnp.clip(u + w, -u_max, u_max)
        x1, info = step(plant, active, dt, x, u)
        ok = jnp.all(jnp.isfinite(x1))
        x1 = jnp.where(ok, x1, x)
        resid = jnp.where(ok, info.residual, jnp.inf)
        return (x1, (prediction, info.foot_margins)), (x1, u, info.foot_margins, info.gaps, resid, *report)

    unknown = jnp.full(5, jnp.nan)
    _, (xs, *out) = jax.lax.scan(body, (x0, (unknown, unknown)), (ref.x[:-1], ref.u, gains, noise, blend))
    return Rollout(jnp.concatenate([x0[None], xs]), *out)
