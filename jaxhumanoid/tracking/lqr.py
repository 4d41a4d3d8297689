"""Time-varying LQR around a plan, on the simulator's grid.

Linearising the simulator's step x+ = F(x, u) (``simulator.step``) along the reference,

    dx_{j+1} = A_j dx_j + B_j du_j,   A_j = dF/dx (2n, 2n),  B_j = dF/du (2n, n)   (from ``jax.jacfwd``)

and minimising sum_j (dx_j^T Q dx_j + du_j^T R du_j) dt + dx_M^T Q_M dx_M gives the backward
discrete Riccati recursion (a ``lax.scan`` from j = M - 1 down to 0)

    K_j = -(R dt + B_j^T P_{j+1} B_j)^-1 B_j^T P_{j+1} A_j
    P_j = Q dt + A_j^T P_{j+1} (A_j + B_j K_j),   P_M = Q_M

and the policy u_j = u_ref_j + K_j (x_j - x_ref_j), saturated at the body's strengths. The cost
also weights the deviation of the steady-foot products (5) of each step, y_j = C_j dx_j + D_j du_j
(``linearise_foot``, in newtons), by W = I / foot_N^2: the controller prefers corrections that
move the ground reaction on the foot little. With Q_j = Q + C_j^T W C_j, R_j = R + D_j^T W D_j,
N_j = C_j^T W D_j the recursion becomes

    K_j = -(R_j dt + B_j^T P_{j+1} B_j)^-1 (B_j^T P_{j+1} A_j + N_j^T dt)
    P_j = Q_j dt + A_j^T P_{j+1} A_j + (A_j^T P_{j+1} B_j + N_j dt) K_j The smooth
contact law makes F differentiable everywhere, so no contact-mode schedule enters: the gains see
the contacts through A_j and B_j alone.

Default weights (``LQRWeights``), in Bryson's form 1 / (acceptable deviation)^2: 0.02 rad per
joint angle, 0.2 rad/s per rate, 20 N m per torque, 50 N per steady-foot product, and a terminal
weight of 10 s times the running state weight. They are the same for every task and every joint.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.tracking.simulator import Plant, Reference, step


def check_number_fields(obj, strict: bool) -> None:
    """Every field of the dataclass ``obj`` a finite number, > 0 when ``strict``, else >= 0."""
    bound = "> 0" if strict else ">= 0"
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0 or (strict and v == 0):
            raise ValueError(f"{type(obj).__name__}.{f.name}: expected a finite number {bound}, got {v!r}")


@dataclasses.dataclass(frozen=True)
class LQRWeights:
    """Acceptable deviations (Bryson's rule): q_rad (joint angles, rad), qd_rad_s (rates, rad/s),
    u_Nm (torques, N m), foot_N (the steady-foot products (5), N); terminal_s: the terminal weight
    Q_M = terminal_s Q (s)."""

    q_rad: float = 0.02
    qd_rad_s: float = 0.2
    u_Nm: float = 20.0
    terminal_s: float = 10.0
    foot_N: float = 50.0

    def __post_init__(self):
        check_number_fields(self, strict=True)

    def matrices(self, n: int):
        """(Q (2n, 2n), R (n, n), Q_M (2n, 2n)) for a chain of n links."""
        Q = np.diag(np.r_[np.full(n, self.q_rad**-2.0), np.full(n, self.qd_rad_s**-2.0)])
        return Q, np.eye(n) * self.u_Nm**-2.0, self.terminal_s * Q


DEFAULT_WEIGHTS = LQRWeights()


def linearise(plant: Plant, active: tuple, ref: Reference):
    """(A (M, 2n, 2n), B (M, 2n, n)) of the step along the reference states and torques."""
    jac = jax.jacfwd(lambda x, u: step(plant, active, ref.dt, x, u)[0], argnums=(0, 1))
    return jax.vmap(jac)(ref.x[:-1], ref.u)


def riccati(A, B, Q, R, Q_final, dt, C=None, D=None, W=None):
    """Gains K (M, n, 2n) and cost-to-go P (M+1, 2n, 2n) of the recursion in the module docstring;
    with outputs y_j = C_j dx_j + D_j du_j (C (M, k, 2n), D (M, k, n)) their cost y^T W y dt too."""
    if C is None:
        C, D, W = jnp.zeros((A.shape[0], 1, A.shape[1])), jnp.zeros((A.shape[0], 1, B.shape[2])), jnp.zeros((1, 1))

    def back(P, ABCD):
        Aj, Bj, Cj, Dj = ABCD
        Qj, Rj, Nj = Q + Cj.T @ W @ Cj, R + Dj.T @ W @ Dj, Cj.T @ W @ Dj
        BtP = Bj.T @ P
        K = -jnp.linalg.solve(Rj * dt + BtP @ Bj, BtP @ Aj + Nj.T * dt)
        P_new = Qj * dt + Aj.T @ P @ Aj + (Aj.T @ P @ Bj + Nj * dt) @ K
        return 0.5 * (P_new + P_new.T), (K, P_new)

    P_M = jnp.asarray(Q_final)
    _, (K, P) = jax.lax.scan(back, P_M, (A, B, C, D), reverse=True)
    return K, jnp.concatenate([P, P_M[None]])


def linearise_foot(plant: Plant, active: tuple, ref: Reference):
    """(C (M, 5, 2n), D (M, 5, n)): the steady-foot products (5) of each step, in newtons (the
    centre-of-pressure rows divided by a0f and a0b), against its start state and torque."""
    scale = jnp.array([1.0, 1.0, 1.0, 1.0 / plant.foot.a0f, 1.0 / plant.foot.a0b])
    jac = jax.jacfwd(lambda x, u: scale * step(plant, active, ref.dt, x, u)[1].foot_margins, argnums=(0, 1))
    return jax.vmap(jac)(ref.x[:-1], ref.u)


def tvlqr_gains(plant: Plant, active: tuple, ref: Reference, weights: LQRWeights = DEFAULT_WEIGHTS):
    """TVLQR gains K (M, n, 2n) around ``ref`` for the (nominal) ``plant``."""
    A, B = linearise(plant, active, ref)
    C, D = linearise_foot(plant, active, ref)
    Q, R, Q_final = weights.matrices(plant.model.n)
    W = jnp.eye(5) * weights.foot_N**-2.0
    return riccati(A, B, jnp.asarray(Q), jnp.asarray(R), jnp.asarray(Q_final), ref.dt, C, D, W)[0]
