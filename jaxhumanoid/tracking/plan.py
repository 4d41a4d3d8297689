"""A saved plan as the simulator sees it: the body, foot and contact law it was planned for, its
goal box, and its states and torques on the simulator's finer grid.

Interpolation onto m sub-steps per plan interval follows the plan's own implicit midpoint rule:
inside interval k (length h, tau in [0, h]) the rate is linear and the angle quadratic,

    qd(tau) = qd_k + (qd_{k+1} - qd_k) tau / h,   q(tau) = q_k + qd_k tau + (qd_{k+1} - qd_k) tau^2 / (2h)

which meets q_{k+1} exactly because (6a) holds; the torque u_k is held over the whole interval.
After the plan's horizon the reference may be held for ``hold_s`` seconds at its final state and
torque (the plan ends at rest in static equilibrium), to see whether the body stays there.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.tasks import TASKS, get_task
from jaxhumanoid.strategy.posture import margins
from jaxhumanoid.strategy.solution import Solution, StageStats
from jaxhumanoid.tracking.simulator import Plant, Reference, step

BODY_KEYS = ("a", "c", "m", "inertia", "g", "u_max", "ankle_height", "a0f", "a0b", "kappa", "f0", "xhat", "mu")


@dataclasses.dataclass(frozen=True)
class Goal:
    """The task's terminal box: goal (n,) +- tolerance (rad)."""

    q: np.ndarray
    tolerance: float

    def inside(self, q, slack: float = 0.0):
        """True where every angle of q (..., n) lies within tolerance + slack of the goal."""
        return jnp.all(jnp.abs(q - self.q) <= self.tolerance + slack, axis=-1)


def _built_in_geometry(sol: Solution) -> dict:
    """The full geometry of a file saved before the body keys were stored, for T1..T4 only."""
    if sol.task not in TASKS:
        raise ValueError(
            f"solution: task {sol.task!r} was saved without the body data a simulation needs "
            f"({', '.join(k for k in BODY_KEYS if k not in sol.geometry)}); re-solve it, or use one of "
            f"{', '.join(TASKS)} (the humanoid, the paper's foot, the nominal law)"
        )
    body, foot, law, task = PlanarChain.humanoid(), FootParams.paper(), ContactParams.nominal(), TASKS[sol.task]
    if not np.allclose(np.asarray(sol.geometry["a"]), body.a) or not np.allclose(np.asarray(sol.geometry["m"]), body.m):
        raise ValueError(f"solution: task {sol.task} was saved for a body other than the humanoid, without its data")
    return {
        **{k: getattr(body, k) for k in ("a", "c", "m", "inertia", "g", "u_max")},
        **{k: getattr(foot, k) for k in ("ankle_height", "a0f", "a0b")},
        **{k: getattr(law, k) for k in ("kappa", "f0", "xhat", "mu")},
        "goal": task.goal,
        "goal_tolerance": task.goal_tolerance,
    }


def plant_and_goal(sol: Solution) -> tuple[Plant, Goal]:
    """The body, foot and law the plan was made for, and its goal box, from the saved geometry."""
    geo = sol.geometry if all(k in sol.geometry for k in (*BODY_KEYS, "goal")) else _built_in_geometry(sol)
    f = {k: np.asarray(geo[k], dtype=float) for k in (*BODY_KEYS, "goal", "goal_tolerance")}
    model = PlanarChain(
        a=f["a"],
        c=f["c"],
        m=f["m"],
        inertia=f["inertia"],
        g=float(f["g"]),
        names=sol.geometry["names"],
        u_max=f["u_max"],
    )
    foot = FootParams(a0f=float(f["a0f"]), a0b=float(f["a0b"]), ankle_height=float(f["ankle_height"]))
    law = ContactParams(kappa=float(f["kappa"]), f0=float(f["f0"]), xhat=float(f["xhat"]), mu=float(f["mu"]))
    return Plant(model, foot, law), Goal(f["goal"], float(f["goal_tolerance"]))


def check_substeps(substeps) -> int:
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ValueError(f"substeps: expected an integer >= 1 (simulator steps per plan interval), got {substeps!r}")
    return int(substeps)


def reference(sol: Solution, substeps: int = 10, hold_s: float = 0.0) -> Reference:
    """The plan on a grid of ``substeps`` steps per interval, held for ``hold_s`` s at its end."""
    m = check_substeps(substeps)
    if isinstance(hold_s, bool) or not isinstance(hold_s, (int, float)) or not np.isfinite(hold_s) or hold_s < 0:
        raise ValueError(f"hold_s: expected a finite time >= 0 (s), got {hold_s!r}")
    t, q, qd, u = (np.asarray(a, dtype=float) for a in (sol.t, sol.q, sol.qd, sol.u))
    N, h = u.shape[0], float(t[1] - t[0])
    tau = (np.arange(m) * h / m)[None, :, None]  # (1, m, 1)
    dqd = (qd[1:] - qd[:-1])[:, None, :]  # (N, 1, n)
    q_in = q[:-1, None] + qd[:-1, None] * tau + dqd * tau**2 / (2 * h)
    qd_in = qd[:-1, None] + dqd * tau / h
    x = np.concatenate([np.concatenate([q_in, qd_in], -1).reshape(N * m, -1), np.r_[q[-1], qd[-1]][None]])
    U = np.repeat(u, m, axis=0)
    extra = int(round(hold_s / (h / m)))
    x = np.concatenate([x, np.repeat(x[-1:], extra, axis=0)])
    U = np.concatenate([U, np.repeat(U[-1:], extra, axis=0)])
    times = t[0] + np.arange(x.shape[0]) * h / m
    return Reference(jnp.asarray(times), jnp.asarray(x), jnp.asarray(U))


def static_plan(task="T2", T: float = 1.0, N: int = 10) -> Solution:
    """A plan that holds a built-in task's start posture still for T seconds on N intervals (the
    humanoid, the paper's foot, the nominal law): q constant, qd = 0, u the equilibrium torques.
    A static equilibrium is exact in every discretisation, so it tests a controller (and the
    checks of a trial) without the transcription error of a solved plan."""
    task = get_task(task)
    if isinstance(N, bool) or not isinstance(N, (int, np.integer)) or N < 1:
        raise ValueError(f"N: expected an integer number of intervals >= 1, got {N!r}")
    body, foot, law = PlanarChain.humanoid(), FootParams.paper(), ContactParams.nominal()
    p = tr.default_params(task)
    q = np.asarray(task.start, dtype=float)
    u = np.asarray(tr.equilibrium_torques(p, jnp.asarray(q), task.active))
    n = body.n
    geometry = {
        **{k: getattr(body, k) for k in ("a", "names", "c", "m", "inertia", "g", "u_max")},
        **{k: getattr(foot, k) for k in ("ankle_height", "a0f", "a0b")},
        **{k: getattr(law, k) for k in ("kappa", "f0", "xhat", "mu")},
        "goal": q,
        "goal_tolerance": task.goal_tolerance,
    }
    stats = StageStats("static", "Solve_Succeeded", True, 0, 0.0, 0.0, 0.0, 0.0, 0, 0)
    return Solution(
        task=f"hold {task.key} start",
        scheme="static",
        solver="none",
        t=np.linspace(0.0, float(T), N + 1),
        q=np.tile(q, (N + 1, 1)),
        qd=np.zeros((N + 1, n)),
        u=np.tile(u, (N, 1)),
        f_contact=np.zeros((N, n, 2)),
        gaps=np.tile(np.asarray(kin.contact_gaps(body, foot, jnp.asarray(q))), (N + 1, 1)),
        foot_reaction=np.zeros((N, 2)),
        foot_margins=np.tile(np.asarray(margins(body, q, task.active).foot), (N, 1)),
        objective=0.0,
        objective_terms={},
        stages=[stats],
        active=task.active,
        geometry=geometry,
    )


def interval_defects(sol: Solution, substeps: int) -> np.ndarray:
    """How far the plan is from the simulator, interval by interval: from each node k (the plan's
    state and torque u_k) ``substeps`` simulator steps of h / substeps, against the plan's node
    k + 1. Returns (N, 2): the largest angle error (rad) and rate error (rad/s) per interval. With
    substeps = 1 this is the transcription's own residual (zero up to the solver's tolerance); as
    substeps grows it tends to the plan's local error against the exact dynamics."""
    m = check_substeps(substeps)
    plant, _ = plant_and_goal(sol)
    x = np.c_[sol.q, sol.qd]
    h = float(sol.t[1] - sol.t[0])
    defect = _defects(plant, tuple(sol.active), h / m, m, jnp.asarray(x[:-1]), jnp.asarray(sol.u))
    err = np.abs(np.asarray(defect) - x[1:])
    n = sol.n_links
    return np.stack([err[:, :n].max(axis=1), err[:, n:].max(axis=1)], axis=1)


@functools.partial(jax.jit, static_argnums=(1, 3))
def _defects(plant: Plant, active: tuple, dt, m: int, x, u):
    one = lambda x0, uk: jax.lax.fori_loop(0, m, lambda _, xx: step(plant, active, dt, xx, uk)[0], x0)  # noqa: E731
    return jax.vmap(one)(x, u)
