"""Physics identities of the paper's humanoid (``PlanarChain.humanoid()``); tests/test_nlinks.py checks
them for chains of other lengths."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import dynamics as dyn
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import (
    DEG,
    HUMANOID_RANGES,
    HUMANOID_STRENGTH,
    TORQUE_LIMIT,
    ContactParams,
    FootParams,
    PlanarChain,
)

MODEL = PlanarChain.humanoid()
FOOT = FootParams.paper()
NOMINAL = ContactParams.nominal()
ALL = (1, 2, 3, 4, 5)
RNG = np.random.default_rng(42)
QS = RNG.uniform(-np.pi, np.pi, size=(50, 5))
QDS = RNG.normal(size=(50, 5))


def test_inertia_matrix_symmetric_positive_definite():
    B = jax.vmap(lambda q: dyn.inertia_matrix(MODEL, q))(QS)
    assert np.allclose(B, np.swapaxes(B, 1, 2), atol=1e-13)
    assert np.all(np.linalg.eigvalsh(B) > 1e-3)


def test_pattern_form_equals_autodiff_of_kinetic_energy():
    for q in QS:
        B_ad = jax.hessian(lambda qd: dyn.kinetic_energy(MODEL, q, qd))(jnp.zeros(5))
        assert np.max(np.abs(dyn.inertia_matrix(MODEL, q) - B_ad)) < 1e-12


def test_pattern_form_matches_paper_formula_entrywise():
    """M_l[r, s] = m_l (sum_{i>=max(r,s)} (a_i^l)^2 + sum_{i != j} a_i^l a_j^l cos(qbar)) + I_l."""
    q = QS[0]
    theta = np.cumsum(q)
    A = np.asarray(kin.com_lever(MODEL))
    B = np.zeros((5, 5))
    for l in range(5):
        for r in range(5):
            for s in range(5):
                if r > l or s > l:
                    continue
                total = sum(A[l, i] ** 2 for i in range(max(r, s), l + 1))
                total += sum(
                    A[l, i] * A[l, j] * np.cos(theta[i] - theta[j])
                    for i in range(r, l + 1)
                    for j in range(s, l + 1)
                    if i != j
                )
                B[r, s] += MODEL.m[l] * total + MODEL.inertia[l]
    assert np.max(np.abs(B - np.asarray(dyn.inertia_matrix(MODEL, q)))) < 1e-12


def test_bdot_minus_2c_is_skew_symmetric():
    for q, qd in zip(QS[:20], QDS[:20]):
        Bdot = jax.jvp(lambda qq: dyn.inertia_matrix(MODEL, qq), (q,), (qd,))[1]
        N = Bdot - 2 * dyn.coriolis_matrix(MODEL, q, qd)
        assert np.max(np.abs(N + N.T)) < 1e-12
        assert np.allclose(dyn.coriolis_matrix(MODEL, q, qd) @ qd, dyn.coriolis_vector(MODEL, q, qd), atol=1e-12)


def test_euler_lagrange_equations_from_lagrangian():
    """B qdd + C qd + G equals d/dt dL/dqd - dL/dq computed by autodiff of T - V."""

    def lagrangian(q, qd):
        return dyn.kinetic_energy(MODEL, q, qd) - dyn.potential_energy(MODEL, FOOT, q)

    for q, qd in zip(QS[:10], QDS[:10]):
        qdd = RNG.normal(size=5)
        dL_dqd = lambda qq, vv: jax.grad(lagrangian, argnums=1)(qq, vv)
        ddt = jax.jvp(dL_dqd, (q, qd), (qd, qdd))[1]
        el = ddt - jax.grad(lagrangian, argnums=0)(q, qd)
        ours = dyn.dynamics_residual(MODEL, q, qd, qdd, jnp.zeros(5), jnp.zeros((0, 2)), ())
        assert np.max(np.abs(el - ours)) < 1e-10


def test_gravity_is_gradient_of_potential():
    for q in QS[:20]:
        dV = jax.grad(lambda qq: dyn.potential_energy(MODEL, FOOT, qq))(q)
        assert np.max(np.abs(dyn.gravity_vector(MODEL, q) - dV)) < 1e-11


def _midpoint_energies(q0, h, steps):
    """Unactuated, contact-free chain integrated with the implicit midpoint rule (6)."""

    def energy(q, qd):
        return dyn.kinetic_energy(MODEL, q, qd) + dyn.potential_energy(MODEL, FOOT, q)

    def residual(z, q0, qd0):
        q1, qd1 = z[:5], z[5:]
        qb, qdb = 0.5 * (q0 + q1), 0.5 * (qd0 + qd1)
        r_a = q1 - q0 - h * qdb
        r_b = dyn.inertia_matrix(MODEL, qb) @ (qd1 - qd0) + h * (
            dyn.coriolis_vector(MODEL, qb, qdb) + dyn.gravity_vector(MODEL, qb)
        )
        return jnp.concatenate([r_a, r_b])

    def step(carry, _):
        q0, qd0 = carry
        z = jnp.concatenate([q0 + h * qd0, qd0])
        for _ in range(6):
            z = z - jnp.linalg.solve(jax.jacfwd(residual)(z, q0, qd0), residual(z, q0, qd0))
        return (z[:5], z[5:]), energy(z[:5], z[5:])

    e0 = energy(q0, jnp.zeros(5))
    _, energies = jax.jit(lambda c: jax.lax.scan(step, c, None, length=steps))((q0, jnp.zeros(5)))
    return np.asarray(energies) - float(e0)


def test_implicit_midpoint_conserves_energy_of_free_chain():
    """Energy error of the symplectic rule stays bounded (no drift) and shrinks as h^2."""
    q0 = jnp.array([-1.2, 0.5, -0.4, 0.6, 0.4])  # released from rest, swinging below the ankle
    scale = float(MODEL.total_mass * MODEL.g)
    err_coarse = _midpoint_energies(q0, 2e-3, 1500)  # 3 s
    err_fine = _midpoint_energies(q0, 1e-3, 3000)
    assert np.max(np.abs(err_fine)) / scale < 1e-4
    ratio = np.max(np.abs(err_coarse)) / np.max(np.abs(err_fine))
    assert 3.0 < ratio < 5.0  # second order
    # bounded, not drifting: the last second is no worse than the first
    third = err_fine.size // 3
    assert np.max(np.abs(err_fine[-third:])) < 2.0 * np.max(np.abs(err_fine[:third])) + 1e-9


def test_contact_law_matches_paper_numbers():
    weight = float(MODEL.total_mass * MODEL.g)
    assert abs(weight - 696.9) < 0.1
    assert float(ct.normal_force(NOMINAL, 0.0)) == pytest.approx(200.0, rel=1e-14)
    assert float(ct.normal_force(NOMINAL, 0.010)) == pytest.approx(8.88, abs=0.01)  # "approximately 9 N"
    # the force carrying the whole weight comes at y of about -7 mm
    y = np.linspace(-0.01, 0.0, 100001)
    y_w = y[np.argmin(np.abs(np.asarray(ct.normal_force(NOMINAL, y)) - weight))]
    assert -0.0075 < y_w < -0.0065
    # f_t is 76% of mu f_n at xd = xhat
    ratio = float(ct.friction_force(NOMINAL, 1.0, NOMINAL.xhat)) / -NOMINAL.mu
    assert ratio == pytest.approx(np.tanh(1.0), rel=1e-14) and abs(ratio - 0.76) < 0.005


def test_contact_law_no_overflow():
    y = jnp.linspace(-1.0, 1.0, 2001)
    f = ct.normal_force(NOMINAL, y)
    df = jax.vmap(jax.grad(lambda yy: ct.normal_force(NOMINAL, yy)))(y)
    d2f = jax.vmap(jax.grad(jax.grad(lambda yy: ct.normal_force(NOMINAL, yy))))(y)
    for arr in (f, df, d2f):
        assert np.all(np.isfinite(arr))
    assert float(f[0]) == pytest.approx(NOMINAL.kappa * 1.0, rel=1e-6)  # asymptote -kappa y
    assert np.all(np.asarray(f) >= 0) and float(df[0]) == pytest.approx(-NOMINAL.kappa, rel=1e-9)


def test_motionless_body_foot_reaction_is_weight():
    for q in QS[:10]:
        f0 = ft.foot_reaction(MODEL, q, jnp.zeros(5), jnp.zeros(5), jnp.zeros((0, 2)))
        assert np.allclose(f0, [0.0, MODEL.total_mass * MODEL.g], atol=1e-10)
        # u_1 at rest equals the ankle moment of gravity: sum of m_l g x_COM_l about the ankle
        u1 = dyn.gravity_vector(MODEL, q)[0]
        x_com = kin.com_positions(MODEL, FOOT, q)[:, 0]
        assert float(u1) == pytest.approx(float(MODEL.g * jnp.dot(MODEL.m, -x_com) * -1.0), abs=1e-10)


def test_foot_reaction_is_momentum_balance():
    """f_c0 = d/dt(total momentum) + weight - contact forces, with the momentum from COM Jacobians."""
    for q, qd in zip(QS[:5], QDS[:5]):
        qdd = RNG.normal(size=5)
        fc = jnp.asarray(RNG.normal(size=(2, 2)) * 50)

        def momentum(qq, vv):
            return jnp.einsum("l,ldj,j->d", MODEL.m, kin.com_jacobians(MODEL, qq), vv)

        pdot = jax.jvp(momentum, (q, qd), (qd, qdd))[1]
        expected = pdot + jnp.array([0.0, MODEL.total_mass * MODEL.g]) - fc.sum(0)
        assert np.allclose(ft.foot_reaction(MODEL, q, qd, qdd, fc), expected, atol=1e-10)


def test_contact_generalized_forces_are_virtual_work():
    """Q from (2) equals d/dq of the virtual work sum_i f_i . O_i(q)."""
    active = (1, 3, 5)
    for q in QS[:5]:
        f = jnp.asarray(RNG.normal(size=(3, 2)))

        def work(qq):
            return jnp.sum(kin.joint_positions(MODEL, FOOT, qq)[jnp.array(active)] * f)

        Q = dyn.generalized_forces(MODEL, q, jnp.zeros(5), f, active)
        assert np.allclose(Q, jax.grad(work)(q), atol=1e-12)


def _central_fd(fun, x, eps=1e-6):
    cols = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = eps
        cols.append((np.asarray(fun(x + e)) - np.asarray(fun(x - e))) / (2 * eps))
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize(
    "name,fun",
    [
        ("B", lambda z: dyn.inertia_matrix(MODEL, z[:5]).ravel()),
        ("Cqd", lambda z: dyn.coriolis_vector(MODEL, z[:5], z[5:])),
        ("G", lambda z: dyn.gravity_vector(MODEL, z[:5])),
        (
            "Q",
            lambda z: dyn.generalized_forces(
                MODEL, z[:5], z[5:], ct.contact_forces(MODEL, FOOT, NOMINAL, z[:5], z[5:], ALL), ALL
            ),
        ),
        ("contact", lambda z: ct.contact_forces(MODEL, FOOT, NOMINAL, z[:5], 0.01 * z[5:], ALL).ravel()),
        ("foot", lambda z: ft.foot_reaction(MODEL, z[:5], z[5:], z[5:] ** 2, jnp.zeros((0, 2)))),
    ],
)
def test_first_and_second_derivatives_match_finite_differences(name, fun):
    # a posture near the ground so the contact law is in its steep region
    z = np.concatenate([np.array([3.25, -0.25, -0.3, -4.5, -1.37]), RNG.normal(size=5) * 0.3])
    J = np.asarray(jax.jacfwd(fun)(jnp.asarray(z)))
    J_fd = _central_fd(fun, z)
    assert np.max(np.abs(J - J_fd)) <= 1e-6 * max(1.0, np.max(np.abs(J)))
    # second order: FD of the jacobian against the Hessian
    H = np.asarray(jax.jacfwd(jax.jacfwd(fun))(jnp.asarray(z)))
    H_fd = _central_fd(lambda x: np.asarray(jax.jacfwd(fun)(jnp.asarray(x))), z)
    assert np.max(np.abs(H - H_fd)) <= 1e-6 * max(1.0, np.max(np.abs(H)))


def test_functions_jit_and_vmap_over_stages():
    q, qd = jnp.asarray(QS), jnp.asarray(QDS)
    f_b = jax.jit(jax.vmap(lambda a: dyn.inertia_matrix(MODEL, a)))
    assert f_b(q).shape == (50, 5, 5)
    assert np.allclose(f_b(q)[3], dyn.inertia_matrix(MODEL, q[3]))
    f_c = jax.jit(jax.vmap(lambda a, b: ct.contact_forces(MODEL, FOOT, NOMINAL, a, b, (2, 5))))
    assert f_c(q, qd).shape == (50, 2, 2)


def test_parameters_are_differentiable_pytrees():
    """d f_n / d kappa and d B / d m through the parameter pytrees."""
    g = jax.grad(lambda c: ct.normal_force(c, -0.005))(NOMINAL)
    assert np.isfinite(g.kappa) and g.kappa > 0
    gm = jax.grad(lambda m: dyn.inertia_matrix(m, jnp.asarray(QS[0]))[0, 0])(MODEL)
    assert gm.m.shape == (5,) and np.all(np.asarray(gm.m) > 0)


@pytest.mark.parametrize(
    "make,field",
    [
        (lambda: PlanarChain(a=[0.4, 0.4, 0.5, 0.3], c=[0.2] * 5, m=[1.0] * 5, inertia=[0.1] * 5), "PlanarChain.c"),
        (lambda: PlanarChain(a=[0.4], c=[0.2], m=[1.0], inertia=[0.1]), "PlanarChain.a"),
        (lambda: PlanarChain(a=[0.4, -0.4], c=[0.2] * 2, m=[1.0] * 2, inertia=[0.1] * 2), "PlanarChain.a"),
        (
            lambda: PlanarChain(a=[0.4] * 5, c=[0.2] * 5, m=[1.0, -1.0, 1.0, 1.0, 1.0], inertia=[0.1] * 5),
            "PlanarChain.m",
        ),
        (
            lambda: PlanarChain(a=[0.4] * 5, c=[0.2] * 5, m=[1.0] * 5, inertia=[0.1, np.nan, 0.1, 0.1, 0.1]),
            "PlanarChain.inertia",
        ),
        (lambda: PlanarChain(a=[0.4] * 5, c=[0.5] * 5, m=[1.0] * 5, inertia=[0.1] * 5), "PlanarChain.c"),
        (lambda: PlanarChain(a=[0.4] * 2, c=[0.2] * 2, m=[1.0] * 2, inertia=[0.1] * 2, g=-1.0), "PlanarChain.g"),
        (
            lambda: PlanarChain(a=[0.4] * 3, c=[0.2] * 3, m=[1.0] * 3, inertia=[0.1] * 3, names=("a", "b")),
            "PlanarChain.names",
        ),
        (
            lambda: PlanarChain(a=[0.4] * 3, c=[0.2] * 3, m=[1.0] * 3, inertia=[0.1] * 3, names=("a", "b", "a")),
            "PlanarChain.names",
        ),
        (
            lambda: PlanarChain(
                a=[0.4] * 2, c=[0.2] * 2, m=[1.0] * 2, inertia=[0.1] * 2, q_min=[0.0, 1.0], q_max=[1.0, 1.0]
            ),
            "PlanarChain.q_min",
        ),
        (
            lambda: PlanarChain(a=[0.4] * 2, c=[0.2] * 2, m=[1.0] * 2, inertia=[0.1] * 2, q_max=[1.0, 1.0, 1.0]),
            "PlanarChain.q_max",
        ),
        (lambda: ContactParams(kappa=-1.0, f0=200.0, xhat=0.02, mu=1.0), "ContactParams.kappa"),
        (lambda: ContactParams(kappa=1e5, f0="x", xhat=0.02, mu=1.0), "ContactParams.f0"),
        (lambda: FootParams(a0f=0.2, a0b=0.058, ankle_height=0.0), "FootParams.ankle_height"),
    ],
)
def test_bad_parameters_raise_clear_errors(make, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        make()


def test_humanoid_is_table_one_with_named_joints_and_ranges():
    assert MODEL.n == 5 and MODEL.names == ("knee", "hip", "shoulder", "elbow", "hand")
    assert float(MODEL.total_mass) == pytest.approx(71.04)
    assert np.all(MODEL.q_min < MODEL.q_max) and MODEL.q_min.shape == MODEL.q_max.shape == (5,)
    # the names are static: not a leaf, part of the tree structure
    leaves = jax.tree_util.tree_leaves(MODEL)
    assert all(isinstance(leaf, np.ndarray) for leaf in leaves) and len(leaves) == 8
    # adult strengths, weaker in the arms than in the legs, and adult ranges; a chain that gives no
    # strengths gets the wide torque box
    np.testing.assert_array_equal(MODEL.u_max, HUMANOID_STRENGTH)
    assert np.all(HUMANOID_STRENGTH[3:] < HUMANOID_STRENGTH[:3].min())
    np.testing.assert_allclose(MODEL.q_min, HUMANOID_RANGES[0] * DEG, atol=1e-15)
    np.testing.assert_allclose(MODEL.q_max, HUMANOID_RANGES[1] * DEG, atol=1e-15)
    generic = PlanarChain(a=MODEL.a, c=MODEL.c, m=MODEL.m, inertia=MODEL.inertia)
    assert np.all(generic.u_max == TORQUE_LIMIT)
    with pytest.raises(ValueError, match=r"PlanarChain\.u_max"):
        dataclasses.replace(MODEL, u_max=np.array([300.0, 500.0, 400.0, 160.0, 0.0]))
    heavier = dataclasses.replace(MODEL, m=2 * MODEL.m)
    assert heavier.names == MODEL.names and float(heavier.total_mass) == pytest.approx(2 * 71.04)
    with pytest.raises(ValueError, match=r"PlanarChain\.m"):
        dataclasses.replace(MODEL, m=-MODEL.m)
