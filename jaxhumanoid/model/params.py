"""Model parameters as immutable pytrees (Table I, Sec. II-D, Sec. II-E).

Every field is a leaf, so any function of the parameters can be differentiated with respect to
them (masses, lengths, contact stiffness, ...). Constructors validate concrete inputs and raise a
``ValueError`` naming the field; traced values (inside ``jit``/``grad``) are passed through
unchecked.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxhumanoid.pytree import pytree_dataclass

N_LINKS = 5
LINK_NAMES = ("lower leg", "upper leg", "trunk + head", "upper arm", "forearm + hand")
JOINT_NAMES = ("ankle", "knee", "hip", "shoulder", "elbow", "hand")


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


@pytree_dataclass
class Humanoid:
    """Inertial parameters of the 5-link chain (Table I) and gravity.

    a: link lengths a_i (m), shape (5,)
    c: distance of the COM of link i from its distal joint O_i towards O_{i-1} (m), shape (5,)
    m: masses m_i (kg), shape (5,)
    inertia: centroidal moments of inertia i_i (kg m^2), shape (5,)
    g: gravitational acceleration (m/s^2)
    """

    a: np.ndarray
    c: np.ndarray
    m: np.ndarray
    inertia: np.ndarray
    g: float

    def __post_init__(self):
        for name in ("a", "c", "m", "inertia"):
            object.__setattr__(self, name, _check("Humanoid", name, getattr(self, name), (N_LINKS,)))
        object.__setattr__(self, "g", _check("Humanoid", "g", self.g, (), positive=False, nonneg=True))
        if _is_concrete(self.a) and _is_concrete(self.c) and not np.all(np.asarray(self.c) <= np.asarray(self.a)):
            raise ValueError(f"Humanoid.c: each c_i must lie on its link (c_i <= a_i), got c={self.c}, a={self.a}")

    @classmethod
    def paper(cls) -> Humanoid:
        """Table I: adult man of 73 kg and 1.74 m (adapted by the paper from its ref. [14])."""
        return cls(
            a=np.array([0.473, 0.422, 0.532, 0.282, 0.355]),
            c=np.array([0.208, 0.173, 0.179, 0.119, 0.174]),
            m=np.array([6.32, 20.7, 36.8, 3.96, 3.26]),
            inertia=np.array([0.0855, 0.399, 1.92, 0.0227, 0.0434]),
            g=9.81,
        )

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
