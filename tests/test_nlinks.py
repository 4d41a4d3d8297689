"""Planar chains of n = 2, 3, 5 and 7 links: physics identities, transcription, sparse derivatives,
the CasADi twin and small solves.

The chains: a 2-link (legs, body) and a 3-link (lower leg, thigh, trunk) body of the humanoid's
mass, the paper's humanoid (n = 5), and a 7-link humanoid-like chain with a two-segment trunk
(abdomen; thorax carrying the head) and a hand. Their start postures stand with the centre of
mass 7 cm ahead of the ankle, in the middle of the sole, so they are static equilibria that
satisfy (5) with about 90 N of margin on each of the centre-of-pressure bounds.
"""

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
from jaxhumanoid.model.params import DEG, ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.outputs import plots, timeline
from jaxhumanoid.strategy.handover import interpolate_full
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.validation import checks

FOOT = FootParams.paper()
SOFT = ContactParams(kappa=1e3, f0=200.0, xhat=0.5, mu=0.8)  # forces that do not vanish a metre above ground
NS = (2, 3, 5, 7)


def _rod_inertia(m, a):
    return np.asarray(m) * np.asarray(a) ** 2 / 12.0


CHAINS = {
    2: PlanarChain(
        a=[0.9, 0.85],
        c=[0.45, 0.4],
        m=[27.0, 44.0],
        inertia=_rod_inertia([27.0, 44.0], [0.9, 0.85]),
        names=("hip", "head"),
    ),
    3: PlanarChain(
        a=[0.47, 0.42, 0.75],
        c=[0.21, 0.17, 0.40],
        m=[6.3, 20.7, 44.0],
        inertia=[0.086, 0.40, 2.2],
        names=("knee", "hip", "head"),
    ),
    5: PlanarChain.humanoid(),
    7: PlanarChain(
        a=[0.473, 0.422, 0.25, 0.282, 0.282, 0.265, 0.09],
        c=[0.208, 0.173, 0.11, 0.10, 0.119, 0.115, 0.045],
        m=[6.32, 20.7, 15.0, 21.8, 3.96, 2.4, 0.86],
        inertia=[0.0855, 0.399, 0.09, 0.9, 0.0227, 0.013, 0.0007],
        names=("knee", "hip", "waist", "shoulder", "elbow", "wrist", "hand"),
        q_min=np.array([0.0, -165.0, -45.0, -30.0, -420.0, -160.0, -80.0]) * DEG,
        q_max=np.array([210.0, 5.0, 160.0, 30.0, -100.0, 5.0, 80.0]) * DEG,
    ),
}

# Bent start and straighter goal postures (relative angles, rad), centre of mass at x = -0.07 m.
TASKS = {
    2: tasks.Task("2-link lean-to-upright", [2.007129, -1.459114], [1.658063, -0.064048], ()),
    3: tasks.Task("3-link squat-to-stand", [2.007129, -1.308997, 1.541336], [1.658063, -0.174533, 0.366099], ()),
    5: tasks.get_task("T1"),
    7: tasks.Task(
        "7-link crouch-to-stand",
        [2.094395, -1.570796, 1.717693, 0.0, -3.637555, -0.349066, 0.0],
        [1.623156, -0.05236, 0.192102, 0.0, -3.420962, -0.261799, 0.0],
        (),
    ),
}


def _states(n, count, seed=0):
    rng = np.random.default_rng(seed + n)
    return rng.uniform(-np.pi, np.pi, (count, n)), rng.normal(size=(count, n)), rng.normal(size=(count, n))


# --- parameters ---------------------------------------------------------------------------


def test_chain_defaults_validation_and_pytree():
    chain = PlanarChain(a=[0.5, 0.4, 0.3], c=[0.2, 0.2, 0.1], m=[3.0, 2.0, 1.0], inertia=[0.1, 0.05, 0.01])
    assert chain.n == 3 and chain.names == ("O_1", "O_2", "O_3") and float(chain.g) == 9.81
    np.testing.assert_allclose(chain.q_min, np.array([0.0, -180.0, -180.0]) * DEG)
    np.testing.assert_allclose(chain.q_max, np.array([210.0, 180.0, 180.0]) * DEG)
    grad = jax.grad(lambda c: dyn.inertia_matrix(c, jnp.array([1.0, 0.2, -0.3]))[0, 0])(chain)
    assert grad.m.shape == (3,) and np.all(np.asarray(grad.m) > 0) and grad.names == chain.names
    jitted = jax.jit(lambda c, q: dyn.gravity_vector(c, q))
    assert jitted(chain, jnp.zeros(3)).shape == (3,)
    assert jitted(dataclasses.replace(chain, names=("a", "b", "c")), jnp.zeros(3)).shape == (3,)
    with pytest.raises(ValueError, match=r"PlanarChain\.inertia"):
        dataclasses.replace(chain, inertia=[0.1, 0.1])
    assert dataclasses.replace(chain, m=[1.0, 1.0, 1.0]).total_mass == 3.0


def test_weights_broadcast_to_the_body():
    np.testing.assert_array_equal(tasks.Weights().as_array(3), [1e-3, 1e-3, 1e-3, 1.0, 2e-2, 1e-5])
    np.testing.assert_array_equal(tasks.Weights(w_u=(1.0, 2.0)).as_array(2), [1.0, 2.0, 1.0, 2e-2, 1e-5])
    assert tasks.Weights().as_array(7).shape == (10,)
    with pytest.raises(ValueError, match=r"Weights\.w_u"):
        tasks.Weights(w_u=(1.0, 2.0)).as_array(3)
    with pytest.raises(ValueError, match=r"Weights\.w_u"):
        tasks.Weights(w_u=-1.0)
    assert tr.default_params(TASKS[3], model=CHAINS[3]).weights.shape == (6,)


def test_task_validation_and_ranges():
    with pytest.raises(ValueError, match=r"Task\.active"):
        tasks.Task("x", [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], (4,))
    with pytest.raises(ValueError, match=r"Task\.goal"):
        tasks.Task("x", [1.0, 0.0, 0.0], [1.0, 0.0], ())
    with pytest.raises(ValueError, match="model"):
        build_problem(TASKS[3], "A,F+C,1S", N=5)  # the default body is the 5-link humanoid
    narrow = dataclasses.replace(TASKS[3], q_min=[1.0, -1.5, 0.0], q_max=[2.5, 0.5, 2.0])
    q_min, q_max = narrow.joint_ranges(CHAINS[3])
    np.testing.assert_array_equal(q_min, [1.0, -1.5, 0.0])
    np.testing.assert_array_equal(TASKS[3].joint_ranges(CHAINS[3])[1], CHAINS[3].q_max)


# --- physics ------------------------------------------------------------------------------


@pytest.mark.parametrize("n", NS)
def test_inertia_matrix_spd_and_the_hessian_of_kinetic_energy(n):
    model = CHAINS[n]
    qs, _, _ = _states(n, 10)
    for q in qs:
        B = np.asarray(dyn.inertia_matrix(model, q))
        assert B.shape == (n, n) and np.allclose(B, B.T, atol=1e-13)
        assert np.all(np.linalg.eigvalsh(B) > 1e-5)
        B_ad = jax.hessian(lambda qd: dyn.kinetic_energy(model, q, qd))(jnp.zeros(n))
        assert np.max(np.abs(B - B_ad)) < 1e-12


@pytest.mark.parametrize("n", NS)
def test_passivity_bdot_minus_2c_is_skew(n):
    model = CHAINS[n]
    qs, qds, _ = _states(n, 10)
    for q, qd in zip(qs, qds):
        Bdot = jax.jvp(lambda qq: dyn.inertia_matrix(model, qq), (q,), (qd,))[1]
        C = dyn.coriolis_matrix(model, q, qd)
        S = np.asarray(Bdot - 2 * C)
        assert np.max(np.abs(S + S.T)) < 1e-12
        assert np.allclose(C @ qd, dyn.coriolis_vector(model, q, qd), atol=1e-12)


@pytest.mark.parametrize("n", NS)
def test_energy_balance_power_is_torque_times_rate(n):
    """Along the contact-free dynamics (1), d(T + V)/dt = qd . u."""
    model = CHAINS[n]
    qs, qds, us = _states(n, 6)
    zero_f = jnp.zeros((0, 2))
    for q, qd, u in zip(qs, qds, 20.0 * us):
        rhs = u - dyn.coriolis_vector(model, q, qd) - dyn.gravity_vector(model, q)
        qdd = np.linalg.solve(np.asarray(dyn.inertia_matrix(model, q)), np.asarray(rhs))
        assert np.max(np.abs(dyn.dynamics_residual(model, q, qd, qdd, u, zero_f, ()))) < 1e-9

        def energy(qq, vv):
            return dyn.kinetic_energy(model, qq, vv) + dyn.potential_energy(model, FOOT, qq)

        power = jax.jvp(energy, (jnp.asarray(q), jnp.asarray(qd)), (jnp.asarray(qd), jnp.asarray(qdd)))[1]
        assert float(power) == pytest.approx(float(np.dot(qd, u)), rel=1e-9, abs=1e-9)


@pytest.mark.parametrize("n", NS)
def test_euler_lagrange_and_gravity_from_the_lagrangian(n):
    model = CHAINS[n]
    qs, qds, qdds = _states(n, 5)

    def lagrangian(q, qd):
        return dyn.kinetic_energy(model, q, qd) - dyn.potential_energy(model, FOOT, q)

    for q, qd, qdd in zip(qs, qds, qdds):
        ddt = jax.jvp(lambda qq, vv: jax.grad(lagrangian, argnums=1)(qq, vv), (q, qd), (qd, qdd))[1]
        el = ddt - jax.grad(lagrangian, argnums=0)(q, qd)
        ours = dyn.dynamics_residual(model, q, qd, qdd, jnp.zeros(n), jnp.zeros((0, 2)), ())
        assert np.max(np.abs(el - ours)) < 1e-10
        V = jax.grad(lambda qq: dyn.potential_energy(model, FOOT, qq))(q)
        assert np.max(np.abs(dyn.gravity_vector(model, q) - V)) < 1e-11


@pytest.mark.parametrize("n", NS)
def test_contact_and_foot_formulas(n):
    model = CHAINS[n]
    qs, qds, qdds = _states(n, 4)
    active = tuple(range(1, n + 1, 2))
    weight = float(model.total_mass * model.g)
    for q, qd, qdd in zip(qs, qds, qdds):
        pts = kin.joint_positions(model, FOOT, q)
        assert pts.shape == (n + 1, 2)
        np.testing.assert_allclose(kin.contact_gaps(model, FOOT, q), pts[1:, 1], atol=1e-14)
        f = ct.contact_forces(model, FOOT, SOFT, q, qd, active)
        idx = np.asarray(active) - 1
        np.testing.assert_allclose(f[:, 1], ct.normal_force(SOFT, pts[1:, 1][idx]), rtol=1e-12)
        vel = jax.jvp(lambda qq: kin.joint_positions(model, FOOT, qq), (q,), (qd,))[1][1:]
        np.testing.assert_allclose(f[:, 0], ct.friction_force(SOFT, f[:, 1], vel[idx, 0]), rtol=1e-12)
        # contact generalized forces (2) are the gradient of the virtual work sum_i f_i . O_i(q)
        Q = dyn.generalized_forces(model, q, jnp.zeros(n), f, active)
        work = jax.grad(lambda qq: jnp.sum(kin.joint_positions(model, FOOT, qq)[jnp.asarray(active)] * f))(q)
        assert np.allclose(Q, work, atol=1e-10 * max(1.0, float(jnp.max(jnp.abs(work)))))
        # at rest the foot carries the weight and u_1 is the ankle moment of gravity
        rest = jnp.zeros(n)
        f0 = ft.foot_reaction(model, q, rest, rest, jnp.zeros((0, 2)))
        assert np.allclose(f0, [0.0, weight], atol=1e-10)
        x_com = kin.com_positions(model, FOOT, q)[:, 0]
        ankle_moment = float(model.g * jnp.dot(model.m, x_com))
        assert float(dyn.gravity_vector(model, q)[0]) == pytest.approx(ankle_moment, abs=1e-10)
        # momentum balance with the COM Jacobians
        pdot = jax.jvp(
            lambda qq, vv: jnp.einsum("l,ldj,j->d", model.m, kin.com_jacobians(model, qq), vv), (q, qd), (qd, qdd)
        )[1]
        fc = jnp.asarray(np.random.default_rng(n).normal(size=(2, 2)) * 50)
        expected = pdot + jnp.array([0.0, weight]) - fc.sum(0)
        assert np.allclose(ft.foot_reaction(model, q, qd, qdd, fc), expected, atol=1e-10)


@pytest.mark.parametrize("n", NS)
def test_start_postures_are_equilibria_with_foot_margin(n):
    task, model = TASKS[n], CHAINS[n]
    p = tr.default_params(task, model=model)
    q = jnp.asarray(task.start)
    u = tr.equilibrium_torques(p, q, task.active)
    f = ct.contact_forces(model, p.foot, p.contact, q, jnp.zeros(n), task.active)
    f0 = ft.foot_reaction(model, q, jnp.zeros(n), jnp.zeros(n), f)
    margins = np.asarray(ft.foot_constraints(p.foot, p.contact.mu, f0, u[0]))
    assert np.all(margins > 4.0), margins
    gaps = np.asarray(kin.contact_gaps(model, p.foot, q))
    assert np.all(np.delete(gaps, np.asarray(task.active, dtype=int) - 1) > 0.01)
    q_min, q_max = task.joint_ranges(model)
    for posture in (task.start, task.goal):
        assert np.all((posture > q_min) & (posture < q_max))


# --- transcription and derivatives --------------------------------------------------------


@pytest.mark.parametrize("n", NS)
@pytest.mark.parametrize("scheme", ["E,F,1S", "A,F,1S", "A,F+C,1S"])
def test_layout_counts_and_slices(n, scheme):
    sc, N = parse_scheme(scheme), 10
    active = sc.active_set((1, n), n)
    layout = tr.Layout(
        N=N, active=active, augmented=sc.augmented, clearance=sc.clearance, pseudo_static=False, n_links=n
    )
    nF = len(active) if sc.augmented else 0
    assert int(layout.free_mask().sum()) == 2 * n * (N + 1) + n * N + 2 * nF * N - 3 * n - 2 * n
    sl = layout.stage_slices()
    assert [sl[k].stop - sl[k].start for k in ("q", "qd", "u", "f")] == [n, n, n, 2 * nF]
    assert layout.n_con == 2 * n + 2 * nF + 5 + (n - len(active) if sc.clearance else 0)
    assert tr.midpoint_map(layout).shape == (6 * n + 2 * nF, 2 * layout.s)
    assert active == ((1, n) if sc.clearance else tuple(range(1, n + 1)))


# (n, scheme, pseudo-static): every n, both force schemes, both contact schemes and model (8)
DERIVATIVE_CASES = [(2, "A,F,1S", False), (3, "E,F,1S", True), (5, "A,F+C,1S", False), (7, "A,F+C,1S", False)]


def _problem(n, scheme, pseudo, N, active=None):
    task = TASKS[n] if active is None else dataclasses.replace(TASKS[n], active=active)
    return build_problem(
        task,
        scheme,
        N=N,
        T=3.0,
        pseudo_static=pseudo,
        model=CHAINS[n],
        contact=ContactParams.relaxed() if pseudo else None,
    )


@pytest.mark.parametrize("n,scheme,pseudo", DERIVATIVE_CASES)
def test_sparse_derivatives_equal_dense_and_patterns_complete(n, scheme, pseudo):
    # F+C cases carry contact forces at the first and the last joint
    pr = _problem(n, scheme, pseudo, N=5, active=(1, n))
    nlp, p = pr.nlp, pr.p
    assert pr.layout.n_links == n and p.weights.shape == (n + 3,)
    rng = np.random.default_rng(n)
    # a random point of the box: joints below the ground, so that the contact laws are exercised
    for x in (pr.bounds.x0 + 0.05 * rng.normal(size=nlp.n), checks.sample_points(pr.bounds, 1, seed=n)[0]):
        lam = rng.normal(size=nlp.m)
        J = np.zeros((nlp.m, nlp.n))
        J[nlp.jac_rows, nlp.jac_cols] = np.asarray(jax.jit(nlp.jac_values)(x, p))
        J_dense = np.asarray(jax.jit(jax.jacfwd(nlp.g))(x, p))
        assert np.max(np.abs(J - J_dense)) <= 1e-12 * max(1.0, np.max(np.abs(J_dense)))
        H = np.zeros((nlp.n, nlp.n))
        H[nlp.hess_rows, nlp.hess_cols] = np.asarray(jax.jit(nlp.hess_values)(x, lam, 0.7, p))
        lag = jax.hessian(lambda z, lam, p: 0.7 * nlp.f(z, p) + jnp.dot(lam, nlp.g(z, p)))
        H_dense = np.tril(np.asarray(jax.jit(lag)(x, lam, p)))
        assert np.max(np.abs(H - H_dense)) <= 1e-11 * max(1.0, np.max(np.abs(H_dense)))
    d = nlp.var_stage[nlp.jac_cols] - nlp.con_stage[nlp.jac_rows]
    assert set(np.unique(d)) <= {0, 1}


@pytest.mark.parametrize("n,scheme,pseudo", DERIVATIVE_CASES)
def test_casadi_twin_agrees(n, scheme, pseudo):
    pr = _problem(n, scheme, pseudo, N=4, active=(1, n))
    rows = checks.cross_validate(pr, points=2, x=pr.bounds.x0, seed=3)
    bad = [r for r in rows if not r.ok]
    assert not bad, bad
    assert {r.quantity for r in rows} >= {"f", "g", "jacobian", "hessian (tril)", "jacobian pattern"}


def test_interpolate_full_for_three_links():
    layout = tr.Layout(N=8, active=(1, 3), augmented=True, clearance=True, pseudo_static=False, n_links=3)
    coarse = np.zeros((5, layout.s))
    tc = np.linspace(0.0, 2.0, 5)
    coarse[:, :6] = tc[:, None] * np.arange(1.0, 7.0)  # q, qd: linear in time at the nodes
    coarse[:-1, 6:] = (0.5 * (tc[:-1] + tc[1:]))[:, None] * np.arange(1.0, 8.0)  # u, f at midpoints
    fine = interpolate_full(coarse, 2.0, layout)
    tf = np.linspace(0.0, 2.0, 9)
    np.testing.assert_allclose(fine[:, :6], tf[:, None] * np.arange(1.0, 7.0), atol=1e-14)
    mf = 0.5 * (tf[:-1] + tf[1:])
    inner = (mf >= 0.25) & (mf <= 1.75)  # inside the coarse midpoints; clamped outside
    np.testing.assert_allclose(fine[:-1][inner, 6:], mf[inner, None] * np.arange(1.0, 8.0), atol=1e-14)


# --- small solves -------------------------------------------------------------------------


def _check_solution(sol, n, N, tmp_path):
    task = TASKS[n]
    assert sol.success, [s.status for s in sol.stages]
    assert sol.q.shape == (N + 1, n) and sol.u.shape == (N, n) and sol.f_contact.shape == (N, n, 2)
    np.testing.assert_allclose(sol.q[0], task.start, atol=1e-12)
    assert np.all(np.abs(sol.q[-1] - task.goal) <= tasks.GOAL_TOLERANCE + 1e-7)
    assert np.allclose(sol.qd[-1], 0.0) and np.allclose(sol.qd[-2], 0.0)
    assert np.all(sol.foot_margins > -1e-6) and np.all(sol.gaps > -1e-6)
    assert sol.report()["n_links"] == n and sol.geometry["names"] == CHAINS[n].names
    sol.save(tmp_path)
    loaded = Solution.load(tmp_path)
    assert loaded.geometry["names"] == CHAINS[n].names
    np.testing.assert_array_equal(loaded.q, sol.q)
    return loaded


def test_two_links_lean_to_upright_one_stage(tmp_path):
    sol = solve(TASKS[2], "A,F+C,1S", N=15, T=3.0, model=CHAINS[2])
    _check_solution(sol, 2, 15, tmp_path)


def test_three_links_squat_to_stand_two_stages(tmp_path):
    sol = solve(TASKS[3], "A,F+C,2S", N=15, T=3.0, model=CHAINS[3], settings=SolveSettings(N1=8))
    _check_solution(sol, 3, 15, tmp_path)
    assert len(sol.stages) == 3 and sol.warm_start["q"].shape == (16, 3)  # stage 1, relaxed law, continuation


def test_seven_links_crouch_to_stand_and_its_figures(tmp_path):
    sol = _check_solution(solve(TASKS[7], "A,F+C,1S", N=15, T=3.0, model=CHAINS[7]), 7, 15, tmp_path)
    fig = plots.plot_solution(sol, n_frames=3)
    _, angles, torques, _ = fig.axes
    assert [t.get_text() for t in angles.get_legend().get_texts()][3] == "$q_{4}$ (waist)"  # q_j acts at O_{j-1}
    assert len(torques.get_legend().get_texts()) == 7
    gantt = timeline.plot_contact_timeline(sol).axes[0]
    assert [t.get_text().split(" ")[0] for t in gantt.get_yticklabels()] == list(CHAINS[7].names)
    assert set(timeline.contact_intervals(sol)) == set(CHAINS[7].names)
