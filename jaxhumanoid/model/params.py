"""Model parameters as immutable pytrees (Table I, Sec. II-D, Sec. II-E).

Every numeric field is a leaf, so any function of the parameters can be differentiated with
respect to them (masses, lengths, contact stiffness, ...); names are static metadata. Constructors
validate concrete inputs and raise a ``ValueError`` naming the field; traced values (inside
``jit``/``grad``) are passed through unchecked.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxhumanoid.pytree import pytree_dataclass, static_field

# Joints O_1..O_5 of the paper's humanoid (links: lower leg, upper leg, trunk + head, upper arm,
# forearm + hand).
HUMANOID_JOINTS = ("knee", "hip", "shoulder", "elbow", "hand")

DEG = np.pi / 180.0
# Adult ranges of motion of the humanoid's relative angles (deg, docs/modelling.md): q_1 (the lower
# leg, wide because the foot is fixed), knee, hip, shoulder (-180 = hanging arm), elbow.
HUMANOID_RANGES = (np.array([0.0, -150.0, -30.0, -360.0, -150.0]), np.array([210.0, 5.0, 140.0, -120.0, 5.0]))
# Strengths (N m, both sides together) at the joints of u_1..u_5: ankle, knee, hip, shoulder, elbow.
HUMANOID_STRENGTH = np.array([300.0, 500.0, 400.0, 160.0, 150.0])
TORQUE_LIMIT = 1000.0  # N m: the torque box of a chain that gives no strengths (far above any cost optimum)


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer) and isinstance(x, (int, float, np.ndarray, np.generic, jax.Array))


def _check(owner: str, name: str, value, shape: tuple, positive: bool = True, nonneg: bool = False):
    """Validate a concrete field; returns a float64 numpy array (or the value unchanged if traced)."""
    if isinstance(value, jax.core.Tracer):
        return value
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{owner}.{name}: expected numbers of shape {shape}, got {value!r}") from err
    if arr.shape != shape:
        raise ValueError(f"{owner}.{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{owner}.{name}: values must be finite, got {arr}")
    if positive and not np.all(arr > 0):
        raise ValueError(f"{owner}.{name}: values must be > 0, got {arr}")
    if nonneg and not np.all(arr >= 0):
        raise ValueError(f"{owner}.{name}: values must be >= 0, got {arr}")
    return arr


def default_joint_names(n: int) -> tuple[str, ...]:
    """("O_1", ..., "O_n"): the joint names of a chain that gives none."""
    return tuple(f"O_{i}" for i in range(1, n + 1))


def default_joint_ranges(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Joint ranges (q_min, q_max) of a generic chain, (n,) each: q_1 (the absolute angle of the
    first link) in [0, 210 deg], so that the link stays above the ground plane through the ankle;
    every relative angle in [-180 deg, 180 deg]."""
    q_min = np.concatenate([[0.0], np.full(n - 1, -180.0)]) * DEG
    q_max = np.concatenate([[210.0], np.full(n - 1, 180.0)]) * DEG
    return q_min, q_max


def _check_names(names, n: int) -> tuple[str, ...]:
    if names is None:
        return default_joint_names(n)
    names = tuple(names)
    if len(names) != n or not all(isinstance(x, str) and x for x in names):
        raise ValueError(f"PlanarChain.names: expected {n} non-empty strings (one per joint O_1..O_{n}), got {names!r}")
    if len(set(names)) != n:
        raise ValueError(f"PlanarChain.names: joint names must be distinct, got {names!r}")
    return names


@pytree_dataclass
class PlanarChain:
    """A planar serial chain of n >= 2 links on a steady foot (Table I for the paper's humanoid).

    a: link lengths a_i (m), shape (n,); n = len(a)
    c: distance of the COM of link i from its distal joint O_i towards O_{i-1} (m), shape (n,)
    m: masses m_i (kg), shape (n,)
    inertia: centroidal moments of inertia i_i (kg m^2), shape (n,)
    g: gravitational acceleration (m/s^2)
    names: names of the joints O_1..O_n (static, not a leaf); default ("O_1", ..., "O_n")
    q_min, q_max: joint ranges (rad), shape (n,), used by tasks that give none; default
        ``default_joint_ranges(n)``
    u_max: joint strengths (N m), shape (n,): torque u_i is boxed to [-u_max_i, u_max_i];
        default ``TORQUE_LIMIT`` for every joint
    """

    a: np.ndarray
    c: np.ndarray
    m: np.ndarray
    inertia: np.ndarray
    g: float = 9.81
    names: tuple = static_field(default=None)
    q_min: np.ndarray | None = None
    q_max: np.ndarray | None = None
    u_max: np.ndarray | None = None

    def __post_init__(self):
        shape = np.shape(self.a)
        if len(shape) != 1 or shape[0] < 2:
            raise ValueError(f"PlanarChain.a: expected the lengths of n >= 2 links, shape (n,), got shape {shape}")
        n = shape[0]
        object.__setattr__(self, "names", _check_names(self.names, n))
        for name in ("a", "c", "m", "inertia"):
            object.__setattr__(self, name, _check("PlanarChain", name, getattr(self, name), (n,)))
        object.__setattr__(self, "g", _check("PlanarChain", "g", self.g, (), positive=False, nonneg=True))
        if _is_concrete(self.a) and _is_concrete(self.c) and not np.all(np.asarray(self.c) <= np.asarray(self.a)):
            raise ValueError(f"PlanarChain.c: each c_i must lie on its link (c_i <= a_i), got c={self.c}, a={self.a}")
        lo, hi = default_joint_ranges(n)
        for name, default in (("q_min", lo), ("q_max", hi)):
            value = default if getattr(self, name) is None else getattr(self, name)
            object.__setattr__(self, name, _check("PlanarChain", name, value, (n,), positive=False))
        if _is_concrete(self.q_min) and _is_concrete(self.q_max) and not np.all(self.q_min < self.q_max):
            raise ValueError(
                f"PlanarChain.q_min: each q_min_i must be below q_max_i, got q_min={self.q_min}, q_max={self.q_max}"
            )
        u_max = np.full(n, TORQUE_LIMIT) if self.u_max is None else self.u_max
        object.__setattr__(self, "u_max", _check("PlanarChain", "u_max", u_max, (n,)))

    @classmethod
    def humanoid(cls) -> PlanarChain:
        """Table I: adult man of 73 kg and 1.74 m (adapted by the paper from its ref. [14]), with
        adult ranges of motion (``HUMANOID_RANGES``) and strengths (``HUMANOID_STRENGTH``), both
        documented with their sources in docs/modelling.md. The paper gives neither; q_1 is the
        absolute angle of the lower leg, whose range is wide because the foot is fixed.
        """
        return cls(
            a=np.array([0.473, 0.422, 0.532, 0.282, 0.355]),
            c=np.array([0.208, 0.173, 0.179, 0.119, 0.174]),
            m=np.array([6.32, 20.7, 36.8, 3.96, 3.26]),
            inertia=np.array([0.0855, 0.399, 1.92, 0.0227, 0.0434]),
            g=9.81,
            names=HUMANOID_JOINTS,
            q_min=HUMANOID_RANGES[0] * DEG,
            q_max=HUMANOID_RANGES[1] * DEG,
            u_max=HUMANOID_STRENGTH.copy(),
        )

    @property
    def n(self) -> int:
        """Number of links (and of joints O_1..O_n)."""
        return len(self.names)

    @property
    def total_mass(self):
        return self.m.sum()


@pytree_dataclass
class ContactParams:
    """Ground contact laws (3)-(4).

    kappa: asymptotic contact stiffness (N/m); f0: normal force at zero gap (N);
    xhat: reference sliding velocity (m/s); mu: friction coefficient.
    """

    kappa: float
    f0: float
    xhat: float
    mu: float

    def __post_init__(self):
        for name in ("kappa", "f0", "xhat", "mu"):
            object.__setattr__(self, name, _check("ContactParams", name, getattr(self, name), ()))

    @classmethod
    def nominal(cls) -> ContactParams:
        """Sec. II-D: kappa = 1e5 N/m, f0 = 200 N, xhat = 0.02 m/s, mu = 1."""
        return cls(kappa=1e5, f0=200.0, xhat=0.02, mu=1.0)

    @classmethod
    def relaxed(cls) -> ContactParams:
        """Sec. III-A, first stage of 2S: kappa = 5e4 N/m, f0 = 300 N, xhat = 0.1 m/s, mu = 1."""
        return cls(kappa=5e4, f0=300.0, xhat=0.1, mu=1.0)


@pytree_dataclass
class FootParams:
    """Steady foot (Sec. II-E, Fig. 4).

    a0f: toe distance ahead of the ankle (m); a0b: heel distance behind it (m);
    ankle_height: height of the ankle centre O_0 above the ground (m). The paper leaves the
    ankle height open; we take 0.039 x body height (Winter's anthropometric ratio) = 0.068 m.
    """

    a0f: float
    a0b: float
    ankle_height: float

    def __post_init__(self):
        for name in ("a0f", "a0b", "ankle_height"):
            object.__setattr__(self, name, _check("FootParams", name, getattr(self, name), ()))

    @classmethod
    def paper(cls) -> FootParams:
        return cls(a0f=0.200, a0b=0.058, ankle_height=0.068)
