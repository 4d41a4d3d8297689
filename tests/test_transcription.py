"""Transcription, schemes, sparse derivatives and the end-to-end solve."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401
from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.scheme import Scheme, parse_scheme
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import build_problem, with_sweeps


@pytest.mark.parametrize(
    "task,scheme,expected",
    [
        ("T1", "E,F,1S", 1485),
        ("T1", "A,F,1S", 2485),
        ("T1", "A,F+C,1S", 2085),
        ("T3", "A,F+C,1S", 1885),
        ("T4", "E,F+C,1S", 1485),
    ],
)
def test_variable_count_matches_paper_formula(task, scheme, expected):
    pr = build_problem(task, scheme, N=100)
    n, N, nF = 5, 100, len(pr.layout.active) if pr.layout.augmented else 0
    assert pr.nlp.n == 2 * n * (N + 1) + n * N + 2 * nF * N - 3 * n - 2 * n == expected


def test_scheme_parsing_and_errors():
    assert parse_scheme("A,F+C,2S") == Scheme("A", "F+C", 2)
    assert parse_scheme("e-f-1s") == Scheme("E", "F", 1)
    with pytest.raises(ValueError, match="scheme"):
        parse_scheme("B,F,1S")
    with pytest.raises(ValueError, match="task"):
        tasks.get_task("T9")
    assert tasks.get_task("supine-to-stand").key == "T3"
    with pytest.raises(ValueError, match="N"):
        build_problem("T1", "A,F,1S", N=2)


CASES = [("T1", "E,F,1S", False), ("T1", "A,F,1S", False), ("T3", "A,F+C,1S", False), ("T2", "A,F+C,2S", True)]


# every scheme with the joint sweeps; the grouped ones on A,F+C, dynamic and pseudo-static
SWEEP_CASES = [(*case, "joint") for case in CASES] + [(*case, "grouped") for case in CASES[2:]]


@pytest.mark.parametrize("task,scheme,pseudo,sweeps", SWEEP_CASES)
def test_sparse_derivatives_equal_dense_and_patterns_complete(task, scheme, pseudo, sweeps):
    pr = build_problem(task, scheme, N=6, pseudo_static=pseudo, contact=ContactParams.relaxed() if pseudo else None)
    pr = with_sweeps(pr, sweeps)
    nlp, p = pr.nlp, pr.p
    rng = np.random.default_rng(1)
    x = pr.bounds.x0 + 0.05 * rng.normal(size=nlp.n)
    lam = rng.normal(size=nlp.m)
    J = np.zeros((nlp.m, nlp.n))
    J[nlp.jac_rows, nlp.jac_cols] = np.asarray(jax.jit(nlp.jac_values)(x, p))
    J_dense = np.asarray(jax.jit(jax.jacfwd(nlp.g))(x, p))
    assert np.max(np.abs(J - J_dense)) <= 1e-12 * max(1.0, np.max(np.abs(J_dense)))
    in_pattern = np.isin(np.arange(J.size), nlp.jac_rows * nlp.n + nlp.jac_cols).reshape(J.shape)
    assert not np.any((J_dense != 0) & ~in_pattern)
    H = np.zeros((nlp.n, nlp.n))
    H[nlp.hess_rows, nlp.hess_cols] = np.asarray(jax.jit(nlp.hess_values)(x, lam, 0.7, p))
    lag = jax.hessian(lambda z, lam, p: 0.7 * nlp.f(z, p) + jnp.dot(lam, nlp.g(z, p)))
    H_dense = np.tril(np.asarray(jax.jit(lag)(x, lam, p)))
    assert np.max(np.abs(H - H_dense)) <= 1e-11 * max(1.0, np.max(np.abs(H_dense)))
    assert np.all(nlp.hess_rows >= nlp.hess_cols)
    # gradient against central differences
    i = rng.choice(nlp.n, 8, replace=False)
    eps = 1e-6
    f = jax.jit(nlp.f)
    fd = [(f(x + eps * np.eye(nlp.n)[k], p) - f(x - eps * np.eye(nlp.n)[k], p)) / (2 * eps) for k in i]
    assert np.allclose(np.asarray(jax.jit(nlp.grad)(x, p))[i], fd, rtol=1e-6, atol=1e-6)


def test_grouped_sweeps_agree_with_joint_and_reject_bad_names():
    pr = build_problem("T1", "A,F+C,1S", N=8)
    joint = with_sweeps(pr, "joint").nlp
    assert joint is not pr.nlp and with_sweeps(pr, "grouped").nlp is pr.nlp  # grouped: the default
    grouped = pr.nlp
    assert np.array_equal(grouped.jac_rows, joint.jac_rows) and np.array_equal(grouped.hess_cols, joint.hess_cols)
    rng = np.random.default_rng(2)
    x, lam = pr.bounds.x0 + 0.05 * rng.normal(size=pr.nlp.n), rng.normal(size=pr.nlp.m)
    for a, b in (
        (jax.jit(grouped.jac_values)(x, pr.p), jax.jit(joint.jac_values)(x, pr.p)),
        (jax.jit(grouped.hess_values)(x, lam, 1.0, pr.p), jax.jit(joint.hess_values)(x, lam, 1.0, pr.p)),
    ):
        assert np.max(np.abs(np.asarray(a) - np.asarray(b))) <= 1e-13 * np.max(np.abs(np.asarray(b)))
    idx = np.sort(np.concatenate(tr.midpoint_groups(pr.layout)))
    assert np.array_equal(idx, np.arange(tr.midpoint_map(pr.layout).shape[0]))
    with pytest.raises(ValueError, match="sweeps"):
        with_sweeps(pr, "fast")


def test_stage_structure_is_block_tridiagonal():
    pr = build_problem("T1", "A,F,1S", N=8)
    nlp = pr.nlp
    d = nlp.var_stage[nlp.jac_cols] - nlp.con_stage[nlp.jac_rows]
    assert set(np.unique(d)) <= {0, 1}
    assert np.max(np.abs(nlp.var_stage[nlp.hess_rows] - nlp.var_stage[nlp.hess_cols])) <= 1


def test_initial_guess_respects_frozen_first_interval_and_bounds():
    pr = build_problem("T1", "A,F+C,1S", N=20)
    Z = pr.full(pr.bounds.x0)
    assert np.allclose(Z[1, 0:5], Z[0, 0:5])
    assert np.all(pr.bounds.x0 >= pr.bounds.xl) and np.all(pr.bounds.x0 <= pr.bounds.xu)
    g0 = np.asarray(jax.jit(pr.nlp.g)(pr.bounds.x0, pr.p)).reshape(20, -1)
    assert np.max(np.abs(g0[0, :5])) < 1e-12  # (6a) holds on the frozen interval


@pytest.mark.parametrize("key", ["T1", "T2", "T3", "T4"])
def test_start_postures_are_equilibria_with_foot_margin(key):
    task = tasks.get_task(key)
    p = tr.default_params(task)
    for contact in ("nominal", "relaxed"):
        q = np.asarray(task.start)
        if contact == "relaxed":
            q, shift = reseat_for_contact(p, q, task.active, ContactParams.relaxed())
            assert shift < 0.02  # millimetres, not a new posture
        pc = tr.default_params(task, contact=getattr(ContactParams, contact)())
        u = tr.equilibrium_torques(pc, jnp.asarray(q), task.active)
        f = ct.contact_forces(pc.model, pc.foot, pc.contact, jnp.asarray(q), jnp.zeros(5), task.active)
        f0 = ft.foot_reaction(pc.model, jnp.asarray(q), jnp.zeros(5), jnp.zeros(5), f)
        margins = np.asarray(ft.foot_constraints(pc.foot, pc.contact.mu, f0, u[0]))
        assert np.all(margins > 0.04 * 100.0), (key, contact, margins)
        gaps = np.asarray(kin.contact_gaps(pc.model, pc.foot, jnp.asarray(q)))
        others = [i - 1 for i in range(1, 6) if i not in task.active]
        assert np.all(gaps[others] > 0.01)  # clearance joints are off the ground
        assert np.all((q > pc.model.q_min) & (q < pc.model.q_max))


@pytest.mark.parametrize("pseudo", [False, True])
def test_inverse_dynamics_guess_satisfies_dynamics_and_force_rows(pseudo):
    # the guess's torques and forces zero the rows of (6b) (or (8)) and of the contact law on every
    # interval after the frozen first one; the linear guess (u = f = 0) leaves them at gravity's size
    kw = dict(N=12, pseudo_static=pseudo, contact=ContactParams.relaxed() if pseudo else None)
    linear = build_problem("T1", "A,F+C,1S", guess="linear", **kw)
    guessed = build_problem("T1", "A,F+C,1S", **kw)  # the default guess
    L = linear.layout
    n, nf = L.n_links, L.n_f
    dyn_rows = slice(n, 2 * n + nf)  # (6b)/(8), then the force rows of scheme A

    def rows(x):
        return np.asarray(linear.nlp.g(x, linear.p)).reshape(L.N, L.n_con)[1:, dyn_rows]

    Z = tr.inverse_dynamics_guess(L, linear.full(linear.bounds.x0), linear.p)
    assert np.max(np.abs(rows(tr.free_from_full(L, jnp.asarray(Z))))) < 1e-9  # unclipped by the torque box
    assert np.max(np.abs(rows(linear.bounds.x0))) > 10.0
    u = guessed.full(guessed.bounds.x0)[1:, L.stage_slices()["u"]]  # the free intervals: the first is the start's
    assert np.all(np.abs(u) <= np.asarray(guessed.model.u_max) + 1e-12)  # x0 stays within the box
    with pytest.raises(ValueError, match="guess"):
        build_problem("T1", "A,F+C,1S", N=12, guess="zero")
