"""The command line: the README's main job end to end, and bad input reported before any work."""

import json

import numpy as np

from jaxhumanoid.model.params import HUMANOID_STRENGTH
from jaxhumanoid.ocp import tasks
from jaxhumanoid.outputs.cli import main
from jaxhumanoid.strategy.solution import Solution


def test_cli_solve_two_stage_t1(tmp_path):
    """The README's main job: T1 with A,F+C,2S converges, report.json and figures are written."""
    out = tmp_path / "T1"
    assert main(["--no-cache", "solve", "--task", "T1", "--out", str(out), "--quiet"]) == 0
    report = json.loads((out / "report.json").read_text())
    for key in (
        "task",
        "scheme",
        "solver",
        "success",
        "status",
        "iterations",
        "solve_time_s",
        "compile_time_s",
        "objective",
        "n_variables",
        "n_constraints",
        "max_constraint_violation",
    ):
        assert key in report
    assert report["success"] and report["status"] == "Solve_Succeeded"
    # stage 1, the dynamic stage under the relaxed law, the continuation to the nominal law
    assert len(report["iterations"]) == 3 and report["n_variables"] == 2085
    # the peak loads: torques within the body's strengths; T1 has no contact-force limit, so the
    # contacts are only bounded by what a person pushing up from the ground plausibly carries
    peaks = report["peaks"]
    assert np.all(np.array(peaks["torque_Nm"]) <= HUMANOID_STRENGTH * (1 + 1e-6))  # IPOPT relaxes bounds by 1e-8
    assert 0.5 < peaks["contact_normal_force_body_weights"] < 3.0
    assert report["max_constraint_violation"] < 1e-5  # IPOPT relaxes bounds by 1e-8 relative (160 N m)
    sol = Solution.load(out)
    goal = tasks.get_task("T1").goal
    assert np.all(np.abs(sol.q[-1] - goal) <= tasks.GOAL_TOLERANCE + 1e-7)
    assert np.all(sol.foot_margins > -1e-6)
    assert np.allclose(sol.qd[-1], 0) and np.allclose(sol.qd[-2], 0)
    for name in ("solution.png", "contacts.png"):
        assert (out / name).stat().st_size > 10_000


def test_cli_reports_bad_input_clearly(capsys):
    assert main(["--no-cache", "solve", "--task", "T7", "--out", "/tmp/never"]) == 2
    assert "task" in capsys.readouterr().err


def test_bad_input_is_reported_before_any_work(capsys, tmp_path):
    """Each bad input ends with a one-line error naming the field and exit status 2, at once."""
    cases = [
        (["solve", "--out", "/proc/jaxhumanoid-test"], "--out"),
        (["solve", "--ipopt-option", "tol", "--out", str(tmp_path)], "--ipopt-option"),
        (["solve", "--ipopt-option", "tol_x=1", "--out", str(tmp_path)], "tol_x"),
        (["solve", "--solver", "casadi", "--ipopt-option", "mu_strategy=fast", "--out", str(tmp_path)], "mu_strategy"),
        (["animate", str(tmp_path / "missing")], "dir"),
        (["animate", str(tmp_path)], "solution.npz"),
        (["track", str(tmp_path), "--perturb", "mass"], "--perturb"),
        (["track", str(tmp_path), "--perturb", "weight=0.1"], "mass, length, contact"),
        (["track", str(tmp_path), "--perturb", "mass=2"], "Perturbation.mass"),
        (["track", str(tmp_path), "--lqr", "q_rad=small"], "--lqr"),
        (["track", str(tmp_path), "--lqr", "u_Nm=0"], "LQRWeights.u_Nm"),
        (["check", "--task-file", "examples/paper/T1.toml"], "--task-file"),
        (["check", "--sensitivities", "--task", "T1", "--task-file", "examples/paper/T1.toml"], "--task"),
        (["check", "--sensitivities", "--task-file", str(tmp_path / "missing.toml")], "missing.toml"),
    ]
    for argv, field in cases:
        assert main(["--no-cache", *argv]) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("jaxhumanoid: error:") and field in err[0], (argv, err)
    assert not list(tmp_path.iterdir()), "nothing may be written before the inputs are checked"
