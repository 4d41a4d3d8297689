"""The public API as a user meets it: own bodies and tasks, task files, clear errors."""

import dataclasses
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

import jaxhumanoid as jh
from jaxhumanoid.model.params import DEG, HUMANOID_RANGES, HUMANOID_STRENGTH, TORQUE_LIMIT
from jaxhumanoid.ocp.tasks import effort_weights
from jaxhumanoid.outputs.cli import build_parser, main, solve_arguments
from jaxhumanoid.runtime import runs_blas_coretype
from jaxhumanoid.strategy.posture import margins
from jaxhumanoid.strategy.settings import CONTINUATION_STEPS

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def four_link() -> jh.PlanarChain:
    """The Table I humanoid without its forearm."""
    h = jh.PlanarChain.humanoid()
    return jh.PlanarChain(
        a=h.a[:4], c=h.c[:4], m=h.m[:4], inertia=h.inertia[:4], names=h.names[:4], q_min=h.q_min[:4], q_max=h.q_max[:4]
    )


def test_a_four_link_chain_squats_from_the_documented_api():
    body = four_link()
    task = squat_task(body)
    sol = jh.solve(task, "A,F+C,1S", model=body, N=20, T=2.0)
    assert sol.success, [s.status for s in sol.stages]
    assert sol.q.shape == (21, 4) and np.all(np.abs(sol.q[-1] - task.goal) <= 0.05 + 1e-7)
    assert np.all(sol.foot_margins > -1e-6)


def squat_task(body) -> jh.Task:
    stand = jh.find_equilibrium(body, np.radians([93, 0, 0, -180]), active=(4,))
    squat = jh.find_equilibrium(body, np.radians([125, -105, 75, -180]), active=(4,))
    return jh.Task("stand-to-squat", stand.q, squat.q, active=(4,), weights=jh.Weights(w_u=1e-3))


def test_weights_are_accepted_as_an_object_or_an_array_and_give_the_same_solve():
    body = four_link()
    task, w = squat_task(body), jh.Weights(w_u=2e-3, w_dqd=3e-2)
    a = jh.solve(task, "A,F+C,1S", model=body, N=20, T=2.0, weights=w)
    b = jh.solve(task, "A,F+C,1S", model=body, N=20, T=2.0, weights=w.as_array(4))
    assert a.success and np.array_equal(a.q, b.q) and a.objective == b.objective


def test_the_own_ipm_solves_a_body_of_other_than_five_links_as_ipopt_does():
    body = four_link()
    task = dataclasses.replace(squat_task(body), goal_tolerance=0.02)
    a = jh.solve(task, "A,F+C,1S", model=body, N=12, T=2.0, solver="ipopt")
    b = jh.solve(task, "A,F+C,1S", model=body, N=12, T=2.0, solver="ipm")
    assert a.success and b.success
    assert np.all(np.abs(a.q[-1] - task.goal) <= 0.02 + 1e-7)
    assert abs(a.objective - b.objective) <= 1e-6 * abs(a.objective) and np.max(np.abs(a.q - b.q)) < 1e-4


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(T="5"), "T"),
        (dict(N=2.5), "N"),
        (dict(settings={"N1": 20}), "settings"),
        (dict(weights=[1.0, 2.0]), "weights"),
        (dict(model="humanoid"), "model"),
        (dict(contact={"kappa": 1.0}), "contact"),
        (dict(options=3), "options"),
        (dict(solver="snopt"), "solver"),
        (dict(task="T9"), "task"),
    ],
)
def test_solve_rejects_bad_arguments_by_name_before_any_work(kwargs, field):
    with pytest.raises(ValueError, match=field):
        jh.solve(**{"task": "T1", **kwargs})


def test_a_negative_link_length_is_rejected_naming_a():
    h = jh.PlanarChain.humanoid()
    with pytest.raises(ValueError, match=r"PlanarChain\.a"):
        jh.PlanarChain(a=[-0.4, 0.5], c=[0.1, 0.1], m=[1.0, 1.0], inertia=[0.1, 0.1])
    with pytest.raises(ValueError, match=r"PlanarChain\.a"):
        dataclasses.replace(h, a=-np.asarray(h.a))


def test_a_start_posture_the_body_cannot_hold_is_moved_to_an_equilibrium():
    heavy_arm = dataclasses.replace(jh.PlanarChain.humanoid(), m=np.array([6.32, 20.7, 36.8, 20.0, 20.0]))
    task = jh.get_task("T3")
    with pytest.warns(UserWarning, match="start posture moved"):
        sol = jh.solve(task, "A,F+C,1S", model=heavy_arm, N=10)
    assert not np.array_equal(sol.q[0], task.start)
    assert jh.find_equilibrium(heavy_arm, sol.q[0], task.active).moved < 1e-6


def solve_task_file(name: str, out: pathlib.Path, *flags: str) -> int:
    """``jaxhumanoid solve --task-file examples/<name>.toml`` with extra flags; the exit status."""
    return main(
        ["--no-cache", "solve", "--task-file", str(EXAMPLES / f"{name}.toml"), "--quiet", "--out", str(out), *flags]
    )


# the 3- and 7-link chains' solves are also run through the API (test_nlinks); the command line's
# task-file path needs one of them in the default run
@pytest.mark.parametrize(
    "name",
    [
        "squat_4link",
        pytest.param("bow_3link", marks=pytest.mark.slow),
        pytest.param("squat_7link", marks=pytest.mark.slow),
    ],
)
def test_example_task_files_solve_from_the_command_line(name, tmp_path):
    out = tmp_path / name
    assert solve_task_file(name, out, "--N", "20") == 0
    sol = jh.Solution.load(out)
    tf = jh.load_task_file(EXAMPLES / f"{name}.toml")
    assert sol.q.shape == (21, tf.model.n) and np.all(np.abs(sol.q[-1] - tf.task.goal) <= 0.05 + 1e-7)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["humanoid_T3_soft", "paper/T1", "paper/T2", "paper/T3", "paper/T4"])
def test_full_size_task_files_solve(name, tmp_path):
    assert solve_task_file(name, tmp_path / name.replace("/", "_")) == 0


@pytest.mark.parametrize("key", ["T1", "T2", "T3", "T4"])
def test_the_built_in_tasks_pose_equilibria_within_adult_ranges_and_strength(key):
    body, task = jh.PlanarChain.humanoid(), jh.get_task(key)
    np.testing.assert_array_equal(body.u_max, HUMANOID_STRENGTH)
    np.testing.assert_allclose(body.q_min, HUMANOID_RANGES[0] * DEG, atol=1e-15)
    assert task.weights.w_u == effort_weights(body.u_max)
    for q in (task.start, task.goal):
        assert np.all(q >= body.q_min) and np.all(q <= body.q_max)
        assert margins(body, q, task.active).ok


@pytest.mark.parametrize("key", ["T1", "T2", "T3", "T4"])
def test_the_paper_task_files_pose_the_tasks_on_the_wide_body(key):
    # the paper's posing: the same standing and prone postures, its own supine one (outside the
    # adult shoulder range), a 1000 N m torque box and one set of weights for every task
    tf, task = jh.load_task_file(EXAMPLES / "paper" / f"{key}.toml"), jh.get_task(key)
    assert tf.task.active == task.active and np.all(tf.model.u_max == TORQUE_LIMIT)
    assert tf.task.weights == jh.Weights() and tf.settings.handover == "direct"
    lying = {"T1": "start", "T2": "goal", "T3": "start", "T4": "goal"}[key]
    standing = "goal" if lying == "start" else "start"
    np.testing.assert_array_equal(getattr(tf.task, standing), getattr(task, standing))
    same_lying = np.array_equal(getattr(tf.task, lying), getattr(task, lying))
    assert same_lying == (key in ("T1", "T2"))
    for q in (tf.task.start, tf.task.goal):
        assert np.all(q >= tf.model.q_min) and np.all(q <= tf.model.q_max)
        assert margins(tf.model, q, tf.task.active).ok
    if key == "T3":
        assert tf.task.start[3] < jh.PlanarChain.humanoid().q_min[3]


def test_handover_settings_come_from_the_task_file_and_the_command_line_overrides_them():
    kw = solve_arguments(build_parser().parse_args(["solve", "--task", "T2"]))
    assert kw["settings"] == jh.SolveSettings()
    s = kw["settings"]
    assert s.handover == "continuation" and s.stage1_solver == "ipopt" and s.guess == "auto"
    path = str(EXAMPLES / "paper" / "T1.toml")
    s = solve_arguments(build_parser().parse_args(["solve", "--task-file", path]))["settings"]
    assert s.handover == "direct" and s.stage1_solver == "same" and s.guess == "linear"
    args = ["solve", "--task-file", path, "--handover", "continuation", "--stage1-solver", "ipm", "--N1", "12"]
    kw = solve_arguments(build_parser().parse_args(args))
    s = kw["settings"]
    assert s.handover == "continuation" and s.stage1_solver == "ipm" and s.guess == "linear" and s.N1 == 12
    assert kw["scheme"] == "A,F+C,2S" and kw["N"] == 100  # solve's own keywords, the file's or the defaults
    with pytest.raises(ValueError, match="stage1_solver"):
        jh.SolveSettings(stage1_solver="mumps")
    with pytest.raises(ValueError, match="N1"):
        solve_arguments(build_parser().parse_args(["solve", "--N1", "2"]))


def test_stage1_options_come_from_the_task_file_and_the_command_line_adds_to_them(tmp_path):
    text = (EXAMPLES / "paper" / "T1.toml").read_text()
    assert "\n[solve]\n" in text and "stage1_options" not in text
    file = tmp_path / "t.toml"
    file.write_text(text.replace("\n[solve]\n", "\n[solve]\nstage1_options = { tol = 1e-6, mu_init = 0.1 }\n"))
    args = ["solve", "--task-file", str(file), "--stage1-option", "mu_init=1e-3", "--stage1-option", "max_iter=50"]
    s = solve_arguments(build_parser().parse_args(args))["settings"]
    assert dict(s.stage1_options) == {"tol": 1e-6, "mu_init": 1e-3, "max_iter": 50}
    assert solve_arguments(build_parser().parse_args(["solve"]))["settings"].stage1_options is None
    for bad in ("mu_init=abc", "mu_init", "no_such_option=1"):
        with pytest.raises(ValueError, match="--stage1-option"):
            solve_arguments(build_parser().parse_args(["solve", "--stage1-option", bad]))


@pytest.mark.slow
@pytest.mark.parametrize("key", ["T1", "T2", "T3", "T4"])
def test_the_three_backends_reach_one_optimum_on_the_built_in_tasks(key):
    sols = {s: jh.solve(key, solver=s) for s in ("ipopt", "ipm", "casadi")}
    assert all(sol.success for sol in sols.values()), {s: sol.status for s, sol in sols.items()}
    ref = sols["ipopt"]
    for sol in sols.values():
        assert abs(sol.objective - ref.objective) <= 1e-6 * abs(ref.objective)
        assert np.abs(sol.q - ref.q).max() <= 1e-4


def test_the_continuation_brings_ipopt_and_the_ipm_to_one_optimum_on_t3():
    # T3 on a coarse grid: the relaxed-law stages by IPOPT, then each backend's continuation
    sols = {s: jh.solve("T3", solver=s, N=30, settings=jh.SolveSettings(N1=15)) for s in ("ipopt", "ipm")}
    assert all(sol.success for sol in sols.values()), {s: sol.status for s, sol in sols.items()}
    # one run of the relaxed-law dynamic solve, one per law of the continuation
    assert [st.attempts for st in sols["ipm"].stages][1:] == [1, CONTINUATION_STEPS]
    assert abs(sols["ipm"].objective - sols["ipopt"].objective) <= 1e-6 * sols["ipopt"].objective
    assert np.abs(sols["ipm"].q - sols["ipopt"].q).max() <= 1e-4


KERNEL_PROBE = """
import jaxhumanoid.runtime, numpy
print(jaxhumanoid.runtime.blas_kernels().get("numpy.libs", "unknown"))
"""


def blas_kernels(coretype: str | None) -> str:
    """The OpenBLAS kernels numpy runs on in a fresh process that imports jaxhumanoid first, with
    ``OPENBLAS_CORETYPE`` unset (None) or set to ``coretype``."""
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_CORETYPE"}
    if coretype is not None:
        env["OPENBLAS_CORETYPE"] = coretype
    out = subprocess.run([sys.executable, "-c", KERNEL_PROBE], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


@pytest.mark.skipif(not runs_blas_coretype(), reason="a CPU without the pinned kernels' instructions")
def test_importing_jaxhumanoid_first_pins_the_blas_kernels_and_a_set_choice_is_kept():
    pinned = blas_kernels(None)
    if pinned == "unknown":
        pytest.skip("numpy is not linked to a bundled OpenBLAS")
    assert pinned == "Haswell"
    assert blas_kernels("Sandybridge") == "Sandybridge"  # the probe reads the kernels in use
