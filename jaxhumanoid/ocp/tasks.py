"""The benchmark tasks T1-T4 (Sec. III-B) and every number the paper leaves open.

All open choices live here: reference postures, joint ranges, goal tolerance, torque box and the
eight cost weights of (7).

Postures (relative angles q, rad; conventions in ``jaxhumanoid.model``):

* standing: upright, leaning 3 deg forward so the centre of pressure sits 5 cm ahead of the ankle,
  arms hanging with the elbows slightly bent.
* prone ("sphinx on the knees"): face down, knee, elbow and hand on the ground, forearms flat
  forward, elbows under the shoulders, hips 5 cm and shoulders 27 cm above the ground.
* supine: on the back with the knees up and the foot flat, hip on the ground, trunk raised 14 deg,
  arms stretched overhead with the hands on the ground behind the head.

The lying postures were designed (by a small constrained least-squares fit under the nominal
contact law) so that each is a static equilibrium that satisfies the steady-foot constraints (5)
with margin: foot load f_n0 = 150-180 N and centre of pressure u_1/f_n0 inside [-a0f, a0b] with
>= 4 cm to spare. No lying posture can do so under the nominal and the relaxed contact laws at
once (the relaxed law changes the load shared between the contacts and the foot by hundreds of
newtons); the two-stage strategy therefore re-seats the start posture by millimetres for stage 1
(``strategy.solve.reseat_for_contact``) so that the relaxed law carries the same contact forces.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxhumanoid.model.params import N_LINKS

DEG = np.pi / 180.0

STANDING = np.array([93.0 * DEG, 0.0, 0.0, -np.pi, -12.0 * DEG])
PRONE = np.array([3.277316, -0.256628, -0.299796, -4.512321, -1.369876])
SUPINE = np.array([0.697404, -1.787126, 1.333707, -0.441913 - 2 * np.pi, -0.003109])

# Joint ranges (rad). q_1 is the absolute angle of the lower leg; the shoulder range spans the
# hanging arm (-180 deg), the forward-raised arm of the prone posture and the overhead arm of the
# supine posture (-385 deg, i.e. 205 deg of flexion).
Q_MIN = np.array([0.0, -165.0, -45.0, -420.0, -160.0]) * DEG
Q_MAX = np.array([210.0, 5.0, 160.0, -100.0, 5.0]) * DEG

GOAL_TOLERANCE = 0.05  # rad: the goal posture is "slightly relaxed by bound constraints" (Sec. II-G)
TORQUE_LIMIT = 1000.0  # N m: a safety box; the cost keeps torques far below it
CONTACT_FORCE_LIMIT = 1.0e4  # N: box on augmented contact-force variables


@dataclasses.dataclass(frozen=True)
class Weights:
    """The eight weights of the objective (7).

    J = h sum_k [ sum_j w_u[j] u_kj^2 + w_qd |qd_k|^2 ]
        + h sum_k [ w_dqd |(qd_{k+1} - qd_k)/h|^2 + w_du |(u_{k+1} - u_k)/h|^2 ]

    i.e. time integrals of torques squared, velocities squared, accelerations squared and torque
    rates squared, so that the value hardly depends on N (2S compares objectives across grids).
    """

    w_u: tuple = (1e-3, 1e-3, 1e-3, 1e-3, 1e-3)
    w_qd: float = 1.0
    w_dqd: float = 2e-2
    w_du: float = 1e-5

    def __post_init__(self):
        if len(self.w_u) != N_LINKS:
            raise ValueError(f"Weights.w_u: expected {N_LINKS} weights, got {len(self.w_u)}")
        for name, val in (("w_u", self.w_u), ("w_qd", self.w_qd), ("w_dqd", self.w_dqd), ("w_du", self.w_du)):
            arr = np.asarray(val, dtype=float)
            if not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise ValueError(f"Weights.{name}: must be finite and >= 0, got {val}")

    def as_array(self) -> np.ndarray:
        """(8,) = (w_u1..w_u5, w_qd, w_dqd, w_du)."""
        return np.array([*self.w_u, self.w_qd, self.w_dqd, self.w_du], dtype=float)


@dataclasses.dataclass(frozen=True)
class Task:
    key: str
    name: str
    start: np.ndarray
    goal: np.ndarray
    active: tuple  # contact set F of the F+C scheme (Figs. 5-8)
    weights: Weights = Weights()


TASKS = {
    "T1": Task("T1", "prone-to-stand", PRONE, STANDING, (1, 4, 5)),
    "T2": Task("T2", "stand-to-prone", STANDING, PRONE, (1, 4, 5)),
    "T3": Task("T3", "supine-to-stand", SUPINE, STANDING, (2, 5)),
    "T4": Task("T4", "stand-to-supine", STANDING, SUPINE, (2, 5)),
}
_BY_NAME = {t.name: t for t in TASKS.values()}


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
