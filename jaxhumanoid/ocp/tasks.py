"""Tasks: start and goal postures of a planar chain, and the benchmark tasks T1-T4 (Sec. III-B).

Every number the paper leaves open for T1-T4 lives here or on the body: reference postures, goal
tolerance and the cost weights of (7) per task; the joint ranges and strengths are the body's
(``PlanarChain.humanoid``: adult ranges of motion and strengths), and a task may narrow or widen
the ranges with its own. The paper adjusts the weights "from task to task, with the goal of
obtaining human-like behaviors and well-balanced contributions by each cost term": here the
torque term is an effort in fractions of each joint's strength (``effort_weights``), and T2, the
fastest fall, weighs accelerations and torque rates twice as much (docs/modelling.md).
``examples/paper/`` keeps the paper's own posing (a ±1000 N m torque box, wider ranges, one set of
weights) for Table II.

Postures of the humanoid (relative angles q, rad; conventions in ``jaxhumanoid.model``):

* standing: upright, leaning 3 deg forward so the centre of pressure sits 5 cm ahead of the ankle,
  arms hanging with the elbows slightly bent.
* prone ("sphinx on the knees"): face down, knee, elbow and hand on the ground, forearms flat
  forward, elbows under the shoulders, hips 5 cm and shoulders 27 cm above the ground.
* supine: on the back with the knees up and the foot flat, the hip on the ground, the trunk raised
  19 deg and the hands on the ground beside the head (160 deg of shoulder flexion, 120 deg of
  elbow flexion).

The lying postures were designed (by a small constrained least-squares fit under the nominal
contact law) so that each is a static equilibrium that satisfies the steady-foot constraints (5)
with margin (>= 3 cm of centre-of-pressure margin). No lying posture can do so under the nominal
and the relaxed contact laws at once with the same joint angles (the relaxed law changes the
load shared between the contacts and the foot by hundreds of newtons); the two-stage strategy
therefore re-seats the start posture by millimetres for the relaxed-law stages
(``strategy.posture.reseat_for_contact``) so that the relaxed law carries the same contact forces.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxhumanoid.model.params import DEG, HUMANOID_STRENGTH, PlanarChain

STANDING = np.array([93.0 * DEG, 0.0, 0.0, -np.pi, -12.0 * DEG])
PRONE = np.array([3.277316, -0.256628, -0.299796, -4.512321, -1.369876])
SUPINE = np.array([0.703314, -1.776783, 1.39798, -5.93413, -2.094397])

GOAL_TOLERANCE = 0.05  # rad: the goal posture is "slightly relaxed by bound constraints" (Sec. II-G)
CONTACT_FORCE_LIMIT = 1.0e4  # N: box on augmented contact-force variables
EFFORT_SCALE = 100.0  # weight of (u_j / u_max_j)^2 in the torque term of (7) (``effort_weights``)


def _nonneg(name: str, val) -> None:
    arr = np.asarray(val, dtype=float)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"Weights.{name}: must be finite and >= 0, got {val}")


@dataclasses.dataclass(frozen=True)
class Weights:
    """The weights of the objective (7): w_u (one per joint torque), w_qd, w_dqd, w_du.

    J = h sum_k [ sum_j w_u[j] u_kj^2 + w_qd |qd_k|^2 ]
        + h sum_k [ w_dqd |(qd_{k+1} - qd_k)/h|^2 + w_du |(u_{k+1} - u_k)/h|^2 ]

    i.e. time integrals of torques squared, velocities squared, accelerations squared and torque
    rates squared, so that the value hardly depends on N (2S compares objectives across grids).
    ``w_u`` is a scalar (the same for every joint) or a sequence with one weight per joint.
    """

    w_u: float | tuple = 1e-3
    w_qd: float = 1.0
    w_dqd: float = 2e-2
    w_du: float = 1e-5

    def __post_init__(self):
        if np.ndim(self.w_u) > 1 or np.size(self.w_u) == 0:
            raise ValueError(f"Weights.w_u: expected a scalar or a sequence of per-joint weights, got {self.w_u!r}")
        if np.ndim(self.w_u) == 1:
            object.__setattr__(self, "w_u", tuple(float(w) for w in self.w_u))
        for name in ("w_u", "w_qd", "w_dqd", "w_du"):
            _nonneg(name, getattr(self, name))

    def as_array(self, n: int) -> np.ndarray:
        """(n + 3,) = (w_u1..w_un, w_qd, w_dqd, w_du) for a chain of n links."""
        if np.ndim(self.w_u) == 1 and np.size(self.w_u) != n:
            raise ValueError(f"Weights.w_u: expected {n} weights (one per joint), got {np.size(self.w_u)}")
        w_u = np.broadcast_to(np.asarray(self.w_u, dtype=float), (n,))
        return np.array([*w_u, self.w_qd, self.w_dqd, self.w_du], dtype=float)


def effort_weights(u_max, scale: float = EFFORT_SCALE) -> tuple[float, ...]:
    """Per-joint torque weights w_u_j = scale / u_max_j^2 (u_max: (n,) strengths, N m): the torque
    term of (7) becomes an effort in fractions of each joint's strength."""
    u_max = np.asarray(u_max, dtype=float)
    if u_max.ndim != 1 or not np.all(np.isfinite(u_max)) or np.any(u_max <= 0):
        raise ValueError(f"u_max: expected positive joint strengths (N m), one per joint, got {u_max!r}")
    return tuple(float(w) for w in scale / u_max**2)


def _posture(owner: str, name: str, value, n: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1 or arr.size < 2 or (n is not None and arr.size != n):
        want = "(n,) with n >= 2" if n is None else f"({n},)"
        raise ValueError(f"{owner}.{name}: expected one angle per joint, shape {want}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{owner}.{name}: angles must be finite, got {arr}")
    return arr


@dataclasses.dataclass(frozen=True)
class Task:
    """Start and goal postures of a chain of n links, shape (n,) each; ``active``: the contact
    set F of the F+C scheme (joints in 1..n, Figs. 5-8); ``q_min``/``q_max``: joint ranges (n,)
    replacing the body's (``PlanarChain.q_min``/``q_max``) when given; ``goal_tolerance``: the
    half-width of the terminal box around the goal (rad, Sec. II-G); ``key``: a short name
    (default ``name``), e.g. ``T1`` for the paper's tasks; ``contact_force_limit``: the largest
    normal force any body contact may carry, in body weights M g (a bound on the contact-force
    variables of scheme A; under scheme E a row per contact joint and interval bounds the law's
    normal force (3) at the midpoint; None: only the wide box ``CONTACT_FORCE_LIMIT``)."""

    name: str
    start: np.ndarray
    goal: np.ndarray
    active: tuple
    weights: Weights = Weights()
    q_min: np.ndarray | None = None
    q_max: np.ndarray | None = None
    goal_tolerance: float = GOAL_TOLERANCE
    key: str = ""
    contact_force_limit: float | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Task.name: expected a non-empty string, got {self.name!r}")
        object.__setattr__(self, "key", self.key or self.name)
        tol = self.goal_tolerance
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not np.isfinite(tol) or tol < 0:
            raise ValueError(f"Task.goal_tolerance: expected a finite half-width >= 0 (rad), got {tol!r}")
        cap = self.contact_force_limit
        if cap is not None and (isinstance(cap, bool) or not isinstance(cap, (int, float)) or not 0 < cap < np.inf):
            raise ValueError(f"Task.contact_force_limit: expected a positive number of body weights, got {cap!r}")
        if not isinstance(self.weights, Weights):
            raise ValueError(f"Task.weights: expected a Weights, got {type(self.weights).__name__}")
        start = _posture("Task", "start", self.start)
        n = start.size
        object.__setattr__(self, "start", start)
        object.__setattr__(self, "goal", _posture("Task", "goal", self.goal, n))
        active = tuple(int(i) for i in self.active)
        if len(set(active)) != len(active) or not all(1 <= i <= n for i in active):
            raise ValueError(f"Task.active: expected distinct joints in 1..{n}, got {self.active!r}")
        object.__setattr__(self, "active", active)
        for name in ("q_min", "q_max"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _posture("Task", name, getattr(self, name), n))
        if self.q_min is not None and self.q_max is not None and not np.all(self.q_min < self.q_max):
            raise ValueError(f"Task.q_min: each q_min_i must be below q_max_i, got {self.q_min} and {self.q_max}")

    @property
    def n(self) -> int:
        """Number of joints of the chain the task is posed for."""
        return self.start.size

    def force_box(self, model: PlanarChain) -> float:
        """The bound (N) on |f| of every contact-force variable: ``contact_force_limit`` body
        weights of ``model``, else ``CONTACT_FORCE_LIMIT``."""
        if self.contact_force_limit is None:
            return CONTACT_FORCE_LIMIT
        return float(self.contact_force_limit) * float(model.total_mass) * float(model.g)

    def joint_ranges(self, model: PlanarChain) -> tuple[np.ndarray, np.ndarray]:
        """(q_min, q_max), (n,) each: the task's own ranges where given, else the body's."""
        if model.n != self.n:
            raise ValueError(f"model: task {self.key} is posed for {self.n} joints, the chain has {model.n}")
        q_min = np.asarray(model.q_min, dtype=float) if self.q_min is None else self.q_min
        q_max = np.asarray(model.q_max, dtype=float) if self.q_max is None else self.q_max
        return q_min, q_max


# (7) per task: effort weights on the torques; T2 damps the fall with twice the acceleration
# and torque-rate weights. T3 caps its body contacts at 2 M g: without the cap, rising from supine
# pushes off at 3.4 M g; the other tasks' optima stay below 1 M g without one.
_EFFORT = effort_weights(HUMANOID_STRENGTH)
_CALM = Weights(w_u=_EFFORT, w_qd=1.0, w_dqd=0.02, w_du=1e-5)
_FALL = Weights(w_u=_EFFORT, w_qd=1.0, w_dqd=0.04, w_du=2e-5)

TASKS = {
    "T1": Task("prone-to-stand", PRONE, STANDING, (1, 4, 5), weights=_CALM, key="T1"),
    "T2": Task("stand-to-prone", STANDING, PRONE, (1, 4, 5), weights=_FALL, key="T2"),
    "T3": Task("supine-to-stand", SUPINE, STANDING, (2, 5), weights=_CALM, key="T3", contact_force_limit=2.0),
    "T4": Task("stand-to-supine", STANDING, SUPINE, (2, 5), weights=_CALM, key="T4"),
}
_BY_NAME = {t.name: t for t in TASKS.values()}


NO_FORCE_LIMIT = "none"  # a contact_force_limit that lifts a task's own limit (command line, study spec)


def with_force_limit(task, limit: float | str) -> Task:
    """``task`` (a Task or key) with ``contact_force_limit`` = ``limit``: body weights, or
    ``NO_FORCE_LIMIT`` for none."""
    cap = None if limit == NO_FORCE_LIMIT else limit
    if isinstance(cap, str):
        raise ValueError(f"contact_force_limit: expected body weights or {NO_FORCE_LIMIT!r}, got {limit!r}")
    return dataclasses.replace(get_task(task), contact_force_limit=cap)


def get_task(key: str) -> Task:
    """A task by key (``T1``..``T4``, case-insensitive) or readable name (``prone-to-stand``...)."""
    if isinstance(key, Task):
        return key
    k = str(key).strip()
    if k.upper() in TASKS:
        return TASKS[k.upper()]
    if k.lower() in _BY_NAME:
        return _BY_NAME[k.lower()]
    allowed = ", ".join(f"{t.key} ({t.name})" for t in TASKS.values())
    raise ValueError(f"task: unknown task {key!r}; allowed: {allowed}")
