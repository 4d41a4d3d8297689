"""The steady-foot safety filter: its interior-point QP against scipy and its own KKT conditions,
the filter leaving an admissible torque alone, a torque that violates (5) made to keep it, the
filtered policy on the standing plan (unperturbed and perturbed trials keep the foot), bad inputs
and the command line."""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.outputs.cli import main
from jaxhumanoid.tracking import Plant, track
from jaxhumanoid.tracking.filter import SafetyFilter, filter_torque, foot_rows, solve_qp
from jaxhumanoid.tracking.plan import static_plan

PLANT = Plant(PlanarChain.humanoid(), FootParams.paper(), ContactParams.nominal())
TASK = tasks.TASKS["T1"]  # lying prone: knee, elbow and hand loaded, stiff contact and friction
DT = 0.005
FILTER = SafetyFilter()
EXACT = SafetyFilter(noise_Nm=0.0)  # no robust torque margin: the answer sits on the rows


@pytest.fixture(scope="module")
def prone():
    """The T1 start at rest, its equilibrium torques, and the filter and its rows, jitted."""
    q = np.asarray(TASK.start)
    u = np.asarray(tr.equilibrium_torques(tr.default_params(TASK), jnp.asarray(q), TASK.active))
    u_max = jnp.asarray(PLANT.model.u_max)
    rows = jax.jit(lambda x, u: foot_rows(PLANT, TASK.active, DT, x, u, EXACT))
    filt = jax.jit(lambda x, u: filter_torque(PLANT, TASK.active, DT, x, u, u_max, EXACT))
    return jnp.asarray(np.r_[q, np.zeros(5)]), jnp.asarray(u), rows, filt


def random_qp(rng, p: int = 10, m: int = 20):
    """A strictly convex QP with a feasible set that is not empty (b below A z_f)."""
    L = rng.standard_normal((p, p))
    A, z_f = rng.standard_normal((m, p)), rng.standard_normal(p)
    return L @ L.T + np.eye(p), 3 * rng.standard_normal(p), A, A @ z_f - rng.uniform(0, 1, m)


def test_interior_point_qp_meets_its_kkt_conditions_and_matches_scipy():
    rng = np.random.default_rng(0)
    solve = jax.jit(solve_qp, static_argnames="iterations")
    for _ in range(6):
        H, g, A, b = random_qp(rng)
        z, lam, residual = (np.asarray(a) for a in solve(H, g, A, b))
        w = A @ z - b
        assert residual < 1e-9
        np.testing.assert_allclose(H @ z + g, A.T @ lam, atol=1e-9)  # stationarity
        assert np.all(w > -1e-9) and np.all(lam > -1e-9) and np.max(np.abs(w * lam)) < 1e-9
        ref = scipy.optimize.minimize(
            lambda z: 0.5 * z @ H @ z + g @ z,
            np.zeros(g.size),
            jac=lambda z: H @ z + g,
            constraints=[{"type": "ineq", "fun": lambda z: A @ z - b, "jac": lambda z: A}],
            method="SLSQP",
            options={"ftol": 1e-14, "maxiter": 500},
        )
        np.testing.assert_allclose(z, ref.x, atol=1e-6)


def test_an_admissible_torque_passes_unchanged(prone):
    x, u, rows, filt = prone
    assert np.all(np.asarray(rows(x, u)) > 0.01)  # the lying start keeps its foot with the margin
    u_f, info, _ = filt(x, u)
    assert np.array_equal(np.asarray(u_f), np.asarray(u))
    assert float(info.change) == 0.0 and float(info.slack) == 0.0


def test_a_torque_that_tips_the_foot_is_filtered_to_one_that_keeps_it(prone):
    """Mutation: 60 N m more at the ankle puts the centre of pressure past the toe margin (5c);
    the filtered torque keeps every row, at most the needed distance from the asked one."""
    x, u, rows, filt = prone
    bad = u + jnp.array([-60.0, 0.0, 0.0, 0.0, 0.0])
    assert float(jnp.min(rows(x, bad))) < -0.01
    u_f, info, _ = filt(x, bad)
    once = float(jnp.min(rows(x, u_f)))  # the rows of the nonlinear step, not the linearised ones
    assert abs(once) < 1e-5  # within the linearisation error of the answer on the rows
    assert float(info.slack) < 1e-9 and float(info.residual) < 1e-9
    assert 0.0 < float(info.change) < 60.0
    twice = dataclasses.replace(EXACT, passes=2)
    u_max = jnp.asarray(PLANT.model.u_max)
    u_2, _, _ = jax.jit(lambda x, u: filter_torque(PLANT, TASK.active, DT, x, u, u_max, twice))(x, bad)
    assert abs(float(jnp.min(rows(x, u_2)))) < 1e-3 * abs(once)  # linearised again at the answer


def test_filtered_trials_on_the_standing_plan_keep_the_foot(stand_run):
    first = stand_run.records[0]
    assert first["qp_filter"]["success"] and first["qp_filter"]["final_error"] < 1e-8
    assert stand_run.qp_filter_success_rate == 1.0 and stand_run.closed_loop_success_rate == 1.0
    assert all(r["qp_filter"]["filter"]["slack_steps"] == 0 for r in stand_run.records)
    data = stand_run.to_json()
    assert data["qp_filter_success_rate"] == 1.0 and data["safety_filter"]["cop"] == FILTER.cop
    assert {"open_loop_success_rate", "closed_loop_success_rate"} <= set(data)


@pytest.fixture(scope="module")
def stand_run():
    return track(static_plan("T2", T=1.0, N=10), trials=4, seed=0, safety=FILTER)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"iterations": 0}, "SafetyFilter.iterations"),
        ({"passes": 1.5}, "SafetyFilter.passes"),
        ({"slack_weight": -1.0}, "SafetyFilter.slack_weight"),
        ({"friction": 1.2}, "FootMargin.friction"),
        ({"noise_Nm": float("nan")}, "SafetyFilter.noise_Nm"),
        ({"observer": 1}, "SafetyFilter.observer"),
    ],
)
def test_bad_filter_settings_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        SafetyFilter(**kwargs)


def test_track_refuses_a_filter_of_the_wrong_type():
    with pytest.raises(ValueError, match="safety"):
        track(static_plan("T2", T=1.0, N=10), trials=1, safety={"cop": 0.01})


def test_cli_controller_qp_records_the_filter(stand_run, tmp_path, capsys):
    static_plan("T2", T=1.0, N=10).save(tmp_path / "plan")
    args = ["--no-cache", "track", str(tmp_path / "plan"), "--trials", "4", "--controller", "qp", "--no-figures"]
    assert main(args) == 0
    data = json.loads((tmp_path / "plan" / "tracking.json").read_text())
    assert data["qp_filter_success_rate"] == stand_run.qp_filter_success_rate
    assert "qp_filter" in data["records"][1] and "TVLQR + QP filter 100%" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_:
        main(["--no-cache", "track", str(tmp_path / "plan"), "--controller", "lqp"])
    assert exit_.value.code == 2
