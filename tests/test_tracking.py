"""The tracking layer: the simulator against the transcription and against itself as its step
shrinks, the TVLQR linearisation and Riccati recursion against finite differences and the
algebraic Riccati equation, Monte-Carlo trials on a standing plan (zero perturbation succeeds,
TVLQR holds what the open loop drops, a large perturbation fails), bad inputs and the CLI.

The plan here is standing still in the upright posture for 1 s (N = 10): a static equilibrium,
exact in every discretisation, so the trials test the controller and the checks rather than the
transcription error of a solved plan (which docs/tracking.md measures)."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import jaxhumanoid as jh
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.outputs import tracking_plots
from jaxhumanoid.outputs.cli import main
from jaxhumanoid.strategy.posture import margins
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.tracking import LQRWeights, Perturbation, Plant, linearise, reference, riccati, step, track
from jaxhumanoid.tracking.montecarlo import (
    MAX_SEAT_MOVE,
    START_SPEC,
    Criteria,
    Draw,
    _gains,
    _seat,
    draw_trials,
    perturbed_plant,
    start_blend,
)
from jaxhumanoid.tracking.plan import plant_and_goal, static_plan

BODY, FOOT, LAW = PlanarChain.humanoid(), FootParams.paper(), ContactParams.nominal()
PLANT = Plant(BODY, FOOT, LAW)
SUPINE_ACTIVE = tasks.TASKS["T3"].active  # hip and hand on the ground: stiff contact and friction


def supine_state(seed: int = 0):
    """The T3 start (lying, loaded contacts) with small random rates, and its equilibrium torques."""
    task = tasks.TASKS["T3"]
    rng = np.random.default_rng(seed)
    q = np.asarray(task.start)
    u = np.asarray(tr.equilibrium_torques(tr.default_params(task), jnp.asarray(q), task.active))
    return jnp.asarray(np.r_[q, 0.3 * rng.standard_normal(5)]), jnp.asarray(u + 5 * rng.standard_normal(5))


@pytest.fixture(scope="module")
def stand():
    return static_plan("T2", T=1.0, N=10)


@pytest.fixture(scope="module")
def default_run(stand):
    return track(stand, trials=8, seed=0, substeps=10)


# --- simulator ---------------------------------------------------------------------------------


def test_one_step_is_the_transcription_of_the_plan():
    """With dt = h the step solves (6a)-(6b) of the transcription with the law at the midpoint."""
    x, u = supine_state()
    h = 0.02
    x1, info = jax.jit(lambda x, u: step(PLANT, SUPINE_ACTIVE, h, x, u))(x, u)
    layout = tr.Layout(N=1, active=SUPINE_ACTIVE, augmented=False, clearance=False, pseudo_static=False, n_links=5)
    p = tr.default_params("T3", T=h)
    za, zb = jnp.r_[x, u], jnp.r_[x1, jnp.zeros(5)]
    rows = tr.interval_constraints(layout, za, zb, p)[:10]
    assert float(info.residual) < 1e-10
    assert np.max(np.abs(np.asarray(rows))) < 1e-9
    margins = np.asarray(tr.interval_constraints(layout, za, zb, p)[10:15])
    np.testing.assert_allclose(np.asarray(info.foot_margins), margins, rtol=1e-10, atol=1e-8)


def test_simulator_converges_with_order_two_as_its_step_shrinks():
    """Error at 0.05 s against a 640-step reference, in contact: halving dt quarters it."""
    x0, u = supine_state(1)
    T = 0.05

    @jax.jit
    def run(m):
        dt = T / m
        return jax.lax.fori_loop(0, m, lambda _, x: step(PLANT, SUPINE_ACTIVE, dt, x, u)[0], x0)

    ref = np.asarray(run(640))
    errors = np.array([np.max(np.abs(np.asarray(run(m)) - ref)) for m in (20, 40, 80)])
    orders = np.log2(errors[:-1] / errors[1:])
    assert np.all(orders > 1.7), (errors, orders)  # the stiff friction makes the constant large, not the order low


def test_reference_interpolation_meets_the_plan_nodes(stand):
    ref = reference(stand, 5, hold_s=0.3)
    assert ref.x.shape == (10 * 5 + 1 + 15, 10) and ref.u.shape == (10 * 5 + 15, 5)
    np.testing.assert_allclose(np.asarray(ref.x[::5][:11, :5]), stand.q)


# --- LQR -----------------------------------------------------------------------------------------


def central_differences(f, x, u, eps: float = 1e-4):
    """(dF/dx, dF/du) of f(x, u) by central differences, all points in one batch (the step ends
    with a Newton step from a converged solve, so it is accurate far below eps^2)."""
    n_x, n_u = x.size, u.size
    E = np.eye(n_x + n_u) * eps
    pts = np.concatenate([E, -E])
    out = np.asarray(jax.jit(jax.vmap(f))(x + pts[:, :n_x], u + pts[:, n_x:]))
    J = (out[: n_x + n_u] - out[n_x + n_u :]).T / (2 * eps)
    return J[:, :n_x], J[:, n_x:]


def test_riccati_with_foot_outputs_reaches_the_cross_weighted_solution():
    """Outputs y = C x + D u weighted by W: the recursion reaches scipy's DARE with the cross term
    S = C^T W D dt, and with W = 0 it is the plain recursion."""
    rng = np.random.default_rng(4)
    A = np.eye(4) + 0.05 * rng.standard_normal((4, 4))
    B, C, D = (0.1 * rng.standard_normal(s) for s in ((4, 2), (3, 4), (3, 2)))
    Q, R, W, dt = np.diag([1.0, 2.0, 3.0, 4.0]), np.diag([0.5, 0.2]), np.diag([2.0, 1.0, 3.0]), 0.1
    tile = lambda a: jnp.tile(a, (2000, 1, 1))  # noqa: E731
    K, P = jax.jit(riccati)(tile(A), tile(B), Q, R, Q, dt, tile(C), tile(D), W)
    Qy, Ry, S = (Q + C.T @ W @ C) * dt, (R + D.T @ W @ D) * dt, C.T @ W @ D * dt
    P_are = scipy.linalg.solve_discrete_are(A, B, Qy, Ry, s=S)
    K_are = -np.linalg.solve(Ry + B.T @ P_are @ B, B.T @ P_are @ A + S.T)
    np.testing.assert_allclose(np.asarray(P[0]), P_are, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(K[0]), K_are, rtol=1e-8, atol=1e-10)
    K0, _ = jax.jit(riccati)(tile(A), tile(B), Q, R, Q, dt, tile(C), tile(D), 0 * W)
    K_plain, _ = jax.jit(riccati)(tile(A), tile(B), Q, R, Q, dt)
    np.testing.assert_allclose(np.asarray(K0), np.asarray(K_plain), rtol=1e-12, atol=1e-14)
    assert np.max(np.abs(np.asarray(K[0]) - np.asarray(K_plain[0]))) > 1e-3  # the outputs change the gains


@pytest.mark.slow  # ~35 s of compilation: python -m pytest -q -m slow tests/test_tracking.py
def test_linearisation_matches_finite_differences_in_contact():
    """In contact (stiff law, eps = 1e-6 rad against a penetration scale f0/kappa = 2 mm)."""
    x, u = supine_state(2)
    dt = 0.005
    ref = jh.tracking.Reference(jnp.array([0.0, dt]), jnp.stack([x, x]), u[None])
    A, B = (np.asarray(a[0]) for a in jax.jit(linearise, static_argnums=1)(PLANT, SUPINE_ACTIVE, ref))
    A_fd, B_fd = central_differences(lambda x, u: step(PLANT, SUPINE_ACTIVE, dt, x, u)[0], x, u, eps=1e-6)
    np.testing.assert_allclose(A, A_fd, rtol=1e-3, atol=1e-5 * np.abs(A).max())
    np.testing.assert_allclose(B, B_fd, rtol=1e-3, atol=1e-5 * np.abs(B).max())


def test_riccati_recursion_reaches_the_algebraic_riccati_solution():
    """Time-invariant (A, B): the backward recursion converges to scipy's DARE and its gain."""
    rng = np.random.default_rng(3)
    A = np.eye(4) + 0.05 * rng.standard_normal((4, 4))
    B = 0.1 * rng.standard_normal((4, 2))
    Q, R, dt = np.diag([1.0, 2.0, 3.0, 4.0]), np.diag([0.5, 0.2]), 0.1
    K, P = jax.jit(riccati)(jnp.tile(A, (2000, 1, 1)), jnp.tile(B, (2000, 1, 1)), Q, R, Q, dt)
    P_are = scipy.linalg.solve_discrete_are(A, B, Q * dt, R * dt)
    K_are = -np.linalg.solve(R * dt + B.T @ P_are @ B, B.T @ P_are @ A)
    np.testing.assert_allclose(np.asarray(P[0]), P_are, rtol=1e-8)
    np.testing.assert_allclose(np.asarray(K[0]), K_are, rtol=1e-8, atol=1e-10)


@pytest.mark.slow  # ~35 s of compilation: python -m pytest -q -m slow tests/test_tracking.py
def test_gains_from_finite_difference_linearisation_agree(stand):
    ref = reference(stand, 2)
    K = np.asarray(_gains(PLANT, stand.active, ref, LQRWeights()))
    A, B = central_differences(lambda x, u: step(PLANT, stand.active, ref.dt, x, u)[0], ref.x[0], ref.u[0])
    scale = jnp.array([1.0, 1.0, 1.0, 1.0 / FOOT.a0f, 1.0 / FOOT.a0b])
    foot = lambda x, u: scale * step(PLANT, stand.active, ref.dt, x, u)[1].foot_margins  # noqa: E731
    C, D = central_differences(foot, ref.x[0], ref.u[0])
    M = ref.u.shape[0]
    Q, R, QM = LQRWeights().matrices(5)
    tile = lambda a: jnp.tile(a, (M, 1, 1))  # noqa: E731
    W = np.eye(5) / LQRWeights().foot_N ** 2
    K_fd, _ = jax.jit(riccati)(tile(A), tile(B), Q, R, QM, ref.dt, tile(C), tile(D), W)
    np.testing.assert_allclose(K, np.asarray(K_fd), rtol=1e-5, atol=1e-6 * np.abs(K).max())


# --- Monte-Carlo -----------------------------------------------------------------------------------


def test_zero_perturbation_succeeds_open_and_closed_loop(default_run):
    first = default_run.records[0]
    assert first["perturbation"]["mass_scale"] == [1.0] * 5 and first["perturbation"]["start_offset"] == [0.0] * 5
    assert first["open_loop"]["success"] and first["closed_loop"]["success"]
    assert first["closed_loop"]["final_error"] < 1e-8


def test_tvlqr_holds_what_the_open_loop_drops(default_run):
    assert default_run.closed_loop_success_rate == 1.0
    assert default_run.open_loop_success_rate < 0.5
    reasons = {r["open_loop"]["reason"] for r in default_run.records[1:]}
    assert reasons <= {"foot tips", "foot slips", "foot lifts", "segment through the ground", "goal missed"}


def test_the_start_is_blended_into_the_plan(stand):
    """Each trial starts at rest with the torques that hold it (start_u): with the blend the first
    torque applied is exactly that; without it (the mutation) TVLQR answers the start's offset at once."""
    quiet = Perturbation(torque_noise_Nm=0.0)
    res = track(stand, trials=3, seed=1, perturbation=quiet)
    plain = track(stand, trials=3, seed=1, perturbation=quiet, start_blend_s=0.0)
    for i in (1, 2):
        u_hold = np.asarray(res.records[i]["perturbation"]["start_u"])
        np.testing.assert_allclose(np.asarray(res.closed_loop.u[i][0]), u_hold, rtol=1e-12, atol=1e-9)
        assert np.max(np.abs(np.asarray(plain.closed_loop.u[i][0]) - u_hold)) > 1.0
    w = start_blend(np.array([0.0, 0.25, 0.5, 1.0, 2.0]), 1.0)
    np.testing.assert_allclose(w, [1.0, 0.5 * (1 + np.cos(np.pi / 4)), 0.5, 0.0, 0.0], atol=1e-15)
    assert not np.any(start_blend(np.array([0.0, 1.0]), 0.0))


def test_a_lying_start_is_seated_nearby_for_a_longer_body_and_a_stiffer_ground():
    """The supine start on a body 8 % longer in the forearm and a ground 40 % stiffer: the hand would
    sit centimetres deep; seating moves it back by millimetres (the old unconstrained search
    wandered radians away) and the stiffer law then carries the plan's forces scaled by the mass."""
    task = tasks.TASKS["T3"]
    draw = Draw([1.05] * 5, [1.0, 1.0, 1.0, 1.0, 1.08], 1.4, 1.0, 1.0, [0.0] * 5, [], False)
    trial = perturbed_plant(PLANT, draw)
    assert not margins(trial.model, task.start, task.active, contact=trial.contact, foot=FOOT, spec=START_SPEC).ok
    q, moved = _seat(trial, PLANT, task.start, task.start, task.active)
    assert moved and np.max(np.abs(q - task.start)) < MAX_SEAT_MOVE
    seated = margins(trial.model, q, task.active, contact=trial.contact, foot=FOOT)
    planned = margins(BODY, task.start, task.active, contact=LAW, foot=FOOT)
    np.testing.assert_allclose(seated.forces[:, 1], 1.05 * planned.forces[:, 1], rtol=1e-6)


def test_a_component_left_out_leaves_the_other_draws_unchanged():
    """Each component draws from the generator whatever its size, so an ablation (one component
    alone) sees the same draws of that component as the full perturbation; a zero component draws
    factors of exactly 1. Mutation: masses and lengths drawn apart (not one shared factor)."""
    q0, active = tasks.TASKS["T4"].start, tasks.TASKS["T4"].active
    full, _ = draw_trials(PLANT, q0, active, 4, Perturbation(), seed=3)
    mass, _ = draw_trials(PLANT, q0, active, 4, Perturbation(0.1, 0.0, 0.0, 0.0, 0.0, 0.0), seed=3)
    length, _ = draw_trials(PLANT, q0, active, 4, Perturbation(0.0, 0.1, 0.0, 0.0, 0.0, 0.0), seed=3)
    for f, m, ell in zip(full[1:], mass[1:], length[1:]):
        assert m.mass_scale == f.mass_scale and ell.length_scale == f.length_scale
        assert m.length_scale == [1.0] * 5 and ell.mass_scale == [1.0] * 5
        assert m.kappa_scale == m.mu_scale == ell.f0_scale == 1.0 and not np.any(m.start_offset)
        assert f.mass_scale != f.length_scale


def test_a_large_perturbation_fails(stand):
    """Mutation: torque noise of 400 N m knocks the body over even under TVLQR, and the checks say so."""
    res = track(stand, trials=8, seed=0, substeps=10, perturbation=Perturbation(torque_noise_Nm=400.0))
    assert res.closed_loop_success_rate < 0.5
    assert all(r["closed_loop"]["reason"] for r in res.records[1:] if not r["closed_loop"]["success"])


def test_the_saved_geometry_rebuilds_the_plant(stand, tmp_path):
    stand.save(tmp_path)
    plant, goal = plant_and_goal(Solution.load(tmp_path))
    np.testing.assert_allclose(plant.model.inertia, BODY.inertia)
    assert float(plant.contact.kappa) == LAW.kappa and goal.tolerance == tasks.GOAL_TOLERANCE


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"trials": 0}, "trials"),
        ({"substeps": 0}, "substeps"),
        ({"perturbation": Perturbation}, "perturbation"),
        ({"hold_s": -1.0}, "hold_s"),
        ({"start_blend_s": float("nan")}, "start_blend_s"),
    ],
)
def test_bad_inputs_name_the_field(stand, kwargs, field):
    with pytest.raises(ValueError, match=field):
        track(stand, **kwargs)


def test_bad_perturbation_and_solution_are_refused(tmp_path):
    with pytest.raises(ValueError, match="Perturbation.contact"):
        Perturbation(contact=1.5)
    with pytest.raises(ValueError, match="Criteria.max_depth"):
        Criteria(max_depth=float("nan"))
    with pytest.raises(ValueError, match="solution"):
        track(tmp_path)


def test_cli_writes_tracking_json_and_figures(stand, default_run, tmp_path, capsys):
    stand.save(tmp_path / "plan")
    code = main(["--no-cache", "track", str(tmp_path / "plan"), "--trials", "8", "--out", str(tmp_path / "t")])
    data = json.loads((tmp_path / "t" / "tracking.json").read_text())
    assert code == 0 and data["trials"] == 8 and len(data["records"]) == 8
    assert data["closed_loop_success_rate"] == default_run.closed_loop_success_rate
    assert {"open_loop_success_rate", "perturbation", "criteria", "weights"} <= set(data)
    assert (tmp_path / "t" / "tracking.png").stat().st_size > 0 and (tmp_path / "t" / "tracking.gif").stat().st_size > 0
    assert "closed loop (TVLQR) 100%" in capsys.readouterr().out
    assert main(["--no-cache", "track", str(tmp_path / "nowhere")]) == 2


def test_cli_passes_the_perturbation_and_weights_it_is_given(stand, tmp_path):
    stand.save(tmp_path / "plan")
    argv = ["--no-cache", "track", str(tmp_path / "plan"), "--trials", "2", "--no-figures", "--quiet"]
    assert main([*argv, "--perturb", "length=0", "torque_noise_Nm=12.5", "--lqr", "q_rad=0.05"]) == 0
    data = json.loads((tmp_path / "plan" / "tracking.json").read_text())
    assert data["perturbation"] == {**dataclasses.asdict(Perturbation()), "length": 0.0, "torque_noise_Nm": 12.5}
    assert data["weights"] == {**dataclasses.asdict(LQRWeights()), "q_rad": 0.05}
    assert data["records"][1]["perturbation"]["length_scale"] == [1.0] * stand.n_links


def test_figure_has_a_panel_per_joint_and_the_foot(default_run, stand):
    fig = tracking_plots.plot_tracking(default_run, stand)
    assert len(fig.axes) == 6
