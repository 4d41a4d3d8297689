"""Figures, contact timeline and animation of a solved trajectory.

The tests run on a synthetic but physically plausible ``Solution``: joint angles blend
prone -> crouch -> standing, gaps come from the kinematics, contact forces from the
contact law (3)-(4) applied to those gaps, and the foot reaction from the static balance of
the weight. No JAX is needed and nothing is solved, so the whole file runs in seconds.
"""

from __future__ import annotations

import json
import platform
import sys

import jax
import numpy as np
import pytest
from PIL import Image

from jaxhumanoid.outputs import animation, plots, timeline
from jaxhumanoid.runtime import BLAS_CORETYPE, runs_blas_coretype
from jaxhumanoid.strategy.solution import Solution, StageStats

A = np.array([0.473, 0.422, 0.532, 0.282, 0.355])
NAMES = ("knee", "hip", "shoulder", "elbow", "hand")
GEOMETRY = {"a": A, "names": NAMES, "ankle_height": 0.068, "a0f": 0.200, "a0b": 0.058, "active": np.array([1, 4, 5])}
MASS, G, MU, KAPPA, F0, XHAT = 73.0, 9.81, 1.0, 1e5, 200.0, 0.02


def _relative(theta):
    """Absolute link angles -> relative joint angles q."""
    theta = np.asarray(theta, dtype=float)
    return np.diff(theta, prepend=0.0)


PRONE = _relative([np.pi + np.arcsin(0.068 / 0.473), np.pi, np.pi - 0.25, -np.arcsin(0.131 / 0.282), -np.pi])
PUSH = _relative([np.pi + np.arcsin(0.068 / 0.473), np.pi - 0.7, np.pi - 0.15, -np.pi / 2 - 0.1, -np.pi + 0.2])
KNEEL = _relative([np.pi + np.arcsin(0.068 / 0.473), np.pi / 2 + 0.2, np.pi - 0.4, -np.pi / 2 - 0.2, -np.pi / 2 - 0.3])
SQUAT = _relative([2.2, -0.35, 2.0, -2.2, -2.0])
STANDING = _relative([np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2])
KEYS = [PRONE, PUSH, KNEEL, SQUAT, STANDING]


def _blend(s, keys):
    """Piecewise smoothstep through the key postures, s in [0, 1]."""
    seg = np.minimum((s * (len(keys) - 1)).astype(int), len(keys) - 2)
    local = s * (len(keys) - 1) - seg
    w = (local * local * (3 - 2 * local))[:, None]
    keys = np.asarray(keys)
    return (1 - w) * keys[seg] + w * keys[seg + 1]


def make_solution(n=40, horizon=3.0, warm=True, active=(1, 4, 5), task="T1") -> Solution:
    """A synthetic prone-to-standing Solution with consistent shapes and plausible forces."""
    t = np.linspace(0.0, horizon, n + 1)
    q = _blend(t / horizon, KEYS)
    qd = np.gradient(q, t, axis=0)
    pts = plots.joint_positions(GEOMETRY, q)
    gaps = pts[:, 1:, 1]
    h = np.diff(t)
    gap_mid = 0.5 * (gaps[:-1] + gaps[1:])
    slide = np.diff(pts[:, 1:, 0], axis=0) / h[:, None]
    # law (3) on the gaps; the blend between key postures dips a few cm into the ground, so the
    # penetration is capped at 4 mm (a solver would keep it there: ~460 N)
    f_n = F0 * np.logaddexp2(0.0, -KAPPA * np.maximum(gap_mid, -0.004) / F0)
    f_t = -MU * f_n * np.tanh(slide / XHAT)
    mask = np.zeros(5)
    mask[np.asarray(active, dtype=int) - 1] = 1.0
    f_contact = np.stack([f_t, f_n], axis=-1) * mask[None, :, None]
    f_n0 = np.maximum(MASS * G - f_contact[:, :, 1].sum(axis=1), 0.0)
    tm = plots.midpoints(t)
    u = np.stack([np.sin(2 * np.pi * tm / horizon + j) * (40.0 + 20 * j) for j in range(5)], axis=1)
    f_t0 = 0.4 * f_n0 * np.sin(4 * np.pi * tm / horizon)
    u[:, 0] = f_n0 * (-0.07 + 0.1 * np.sin(2 * np.pi * tm / horizon))
    margins = np.stack([f_n0, MU * f_n0 - f_t0, MU * f_n0 + f_t0, 0.2 * f_n0 + u[:, 0], 0.058 * f_n0 - u[:, 0]], 1)
    warm_start = None
    if warm:
        ws_t = np.linspace(0.0, horizon, 16)
        ws_q = _blend(ws_t / horizon, KEYS)
        ws_q[:, 1:3] += 0.1 * np.sin(np.pi * ws_t / horizon)[:, None]
        warm_start = {"t": t, "q": plots.interpolate(ws_t, ws_q, t)}
    stats = StageStats("dynamic", "Solve_Succeeded", True, 42, 1.5, 3.0, 12.3, 1e-9, 100, 90)
    return Solution(
        task=task,
        scheme="A F+C 2S",
        solver="ipopt",
        t=t,
        q=q,
        qd=qd,
        u=u,
        f_contact=f_contact,
        gaps=gaps,
        foot_reaction=np.stack([f_t0, f_n0], 1),
        foot_margins=margins,
        objective=12.3,
        objective_terms={"effort": 10.0, "accel": 2.3},
        stages=[stats],
        active=tuple(active),
        geometry=dict(GEOMETRY),
        warm_start=warm_start,
    )


@pytest.fixture(scope="module")
def sol():
    return make_solution()


def _png_ok(path, min_width=400):
    assert path.is_file()
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert 10_000 < path.stat().st_size < 3_000_000
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size[0] >= min_width and im.size[1] >= 300
        return im.size


def _has_unit(label):
    return "(" in label and label.rstrip().endswith(")")


# --- geometry helpers ---------------------------------------------------------------------


def test_joint_positions_match_model_kinematics():
    import jax.numpy as jnp

    from jaxhumanoid.model import FootParams, PlanarChain
    from jaxhumanoid.model.kinematics import joint_positions

    model, foot = PlanarChain.humanoid(), FootParams.paper()
    geo = {"a": np.asarray(model.a), "ankle_height": 0.068, "a0f": 0.2, "a0b": 0.058}
    qs = np.random.default_rng(0).uniform(-np.pi, np.pi, (4, 5))
    ours = plots.joint_positions(geo, qs)
    assert ours.shape == (4, 6, 2)
    for q, p in zip(qs, ours):
        np.testing.assert_allclose(p, np.asarray(joint_positions(model, foot, jnp.asarray(q))), atol=1e-12)


def test_standing_posture_is_upright():
    p = plots.joint_positions(GEOMETRY, STANDING)
    np.testing.assert_allclose(p[:4, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(p[3, 1], 0.068 + A[:3].sum())
    assert plots.geometry_of(make_solution(n=4))["head"] == 3  # the shoulder's row in the joint positions
    assert plots.head_centre(p, 3)[1] > p[3, 1]


def test_pack_offsets_places_frames_side_by_side():
    extents = [(-1.8, 0.1), (-0.3, 0.2), (-1.0, 0.4)]
    off = plots.pack_offsets(extents, gap=0.3)
    assert off[0] + extents[0][0] == pytest.approx(0.0)
    for i in range(2):
        assert off[i + 1] + extents[i + 1][0] == pytest.approx(off[i] + extents[i][1] + 0.3)


# --- summary figure -----------------------------------------------------------------------


def test_plot_solution_writes_png_with_labelled_panels(sol, tmp_path):
    path = tmp_path / "figs" / "solution.png"
    fig = plots.plot_solution(sol, path, n_frames=6, dpi=80)
    width, height = _png_ok(path, min_width=1000)
    assert width > height
    strip, angles, torques, forces = fig.axes
    assert strip.get_ylabel() == "y (m)"
    assert "task T1" in fig.get_suptitle() and "ipopt" in fig.get_suptitle() and "12.3" in fig.get_suptitle()
    for ax, unit in ((angles, "(deg)"), (torques, "(N m)"), (forces, "(N)")):
        assert ax.get_xlabel() == "time t (s)" and ax.get_ylabel().endswith(unit)
        assert ax.get_legend() is not None
    assert len(strip.get_legend().get_texts()) == 2
    hand_labels = [t.get_text() for t in forces.get_legend().get_texts() if t.get_text().startswith("hand")]
    assert len(hand_labels) == 3  # |f_n| and |f_t| coloured by sign


def test_plot_solution_without_warm_start_or_contacts():
    s = make_solution(n=20, warm=False, active=())
    fig = plots.plot_solution(s)
    strip, *_, forces = fig.axes
    assert len(strip.get_legend().get_texts()) == 1
    assert forces.get_legend() is None and "no modelled contact forces" in forces.texts[0].get_text()


def test_plot_solution_rejects_bad_input(sol):
    with pytest.raises(ValueError, match="n_frames"):
        plots.plot_solution(sol, n_frames=1)
    bad = make_solution(n=10)
    bad.u = bad.u[:-1]
    with pytest.raises(ValueError, match=r"sol\.u"):
        plots.plot_solution(bad)
    bad = make_solution(n=10)
    del bad.geometry["a0f"]
    with pytest.raises(ValueError, match=r"sol\.geometry"):
        plots.plot_solution(bad)
    with pytest.raises(ValueError, match="path"):
        plots.plot_solution(make_solution(n=10), "figure.jpg", n_frames=2)


def test_plot_after_save_and_load(tmp_path):
    make_solution(n=12).save(tmp_path)
    loaded = Solution.load(tmp_path)
    assert loaded.warm_start is not None
    _png_ok(plots.save_png(plots.plot_solution(loaded, n_frames=4), tmp_path / "loaded.png"))


def test_report_records_the_environment_the_bits_depend_on(tmp_path):
    make_solution(n=12).save(tmp_path)
    env = json.loads((tmp_path / "report.json").read_text())["environment"]
    assert env["packages"]["numpy"] == np.__version__ and env["packages"]["jax"] == jax.__version__
    assert env["python"] == platform.python_version()
    kernels = env["blas_kernels"]
    if sys.platform == "linux":
        assert "numpy.libs" in kernels, kernels  # numpy's bundled OpenBLAS, read in this process
        if runs_blas_coretype():
            assert kernels["numpy.libs"] == BLAS_CORETYPE == env["OPENBLAS_CORETYPE"]


# --- contact timeline ---------------------------------------------------------------------


def test_intervals_from_mask_runs():
    t = np.arange(7.0)  # 6 intervals
    assert timeline.intervals_from_mask(t, [0, 1, 1, 0, 0, 1]) == [(1.0, 3.0), (5.0, 6.0)]
    assert timeline.intervals_from_mask(t, [1] * 6) == [(0.0, 6.0)]
    assert timeline.intervals_from_mask(t, [0] * 6) == []
    with pytest.raises(ValueError, match="mask"):
        timeline.intervals_from_mask(t, [1, 0])


def test_contact_intervals_constructed_case():
    s = make_solution(n=40, horizon=2.0)
    s.f_contact = np.zeros_like(s.f_contact)
    s.f_contact[10:20, 4, 1] = 100.0  # hand pushes on intervals 10..19
    s.f_contact[30:32, 0, 1] = 15.0  # knee force below the 20 N threshold
    s.gaps = np.full_like(s.gaps, 0.3)
    s.gaps[5:9, 1] = 0.0  # hip (no force model) on the ground at nodes 5..8
    s.gaps[5:9, 4] = 0.0  # the hand gap is ignored: it has a force model
    got = timeline.contact_intervals(s)
    assert got == {"knee": [], "hip": [(s.t[5], s.t[8])], "shoulder": [], "elbow": [], "hand": [(s.t[10], s.t[20])]}
    assert timeline.contact_intervals(s, force_threshold=10.0)["knee"] == [(s.t[30], s.t[32])]
    summary = timeline.contact_summary(s)
    assert json.loads(json.dumps(summary))["intervals"]["hand"] == [[0.5, 1.0]]
    assert summary["criterion"] == {"knee": "force", "hip": "gap", "shoulder": "gap", "elbow": "force", "hand": "force"}
    with pytest.raises(ValueError, match="force_threshold"):
        timeline.contact_intervals(s, force_threshold=-1.0)


def test_foot_margins_ratios(sol):
    m = timeline.foot_margins(sol)
    f_n0 = sol.foot_reaction[:, 1]
    loaded = f_n0 >= 1.0
    assert loaded.any() and (~loaded).any()
    np.testing.assert_allclose(m["cop"][loaded], sol.u[loaded, 0] / f_n0[loaded])
    np.testing.assert_allclose(m["friction_slack"][loaded], MU - np.abs(sol.foot_reaction[loaded, 0]) / f_n0[loaded])
    assert np.isnan(m["cop"][~loaded]).all()


def test_plot_contact_timeline_writes_png(sol, tmp_path):
    path = tmp_path / "timeline.png"
    fig = timeline.plot_contact_timeline(sol, path, dpi=80)
    _png_ok(path)
    gantt, fric, cop = fig.axes
    assert [t.get_text().split(" ")[0] for t in gantt.get_yticklabels()] == ["knee", "hip", "shoulder", "elbow", "hand"]
    assert len(gantt.collections) == 5
    assert all(ax.get_xlabel() == "time t (s)" for ax in fig.axes)
    assert gantt.get_ylabel() == "joint in contact"  # categorical axis
    assert _has_unit(fric.get_ylabel()) and cop.get_ylabel().endswith("(m)")


# --- animation ----------------------------------------------------------------------------


def test_animate_writes_small_gif(sol, tmp_path):
    path = animation.animate(sol, tmp_path / "anim" / "motion.gif", fps=10, max_frames=8, dpi=50)
    assert path.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    assert 5_000 < path.stat().st_size < 1_000_000
    with Image.open(path) as im:
        assert im.n_frames == 8 and im.size[0] >= 200


def test_animate_default_frame_budget():
    t = np.linspace(0.0, 1.0, 101)
    times = animation.frame_times(t, 60)
    assert times.size == 60 and times[0] == 0.0 and times[-1] == 1.0
    assert animation.frame_times(t[:11], 60).size == 11


def test_animate_rejects_bad_input(sol, tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="path"):
        animation.animate(sol, tmp_path / "motion.avi")
    with pytest.raises(ValueError, match="fps"):
        animation.animate(sol, tmp_path / "motion.gif", fps=0)
    with pytest.raises(ValueError, match="max_frames"):
        animation.animate(sol, tmp_path / "motion.gif", max_frames=1)
    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    with pytest.raises(RuntimeError, match="ffmpeg"):
        animation.animate(sol, tmp_path / "motion.mp4")


def test_outputs_do_not_load_pyplot():
    import subprocess
    import sys

    code = (
        "import sys, jaxhumanoid.outputs.plots, jaxhumanoid.outputs.timeline, jaxhumanoid.outputs.animation; "
        "assert 'matplotlib.pyplot' not in sys.modules"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_progress_reports_steps_elapsed_and_eta(capsys):
    from jaxhumanoid.progress import Progress

    now = [0.0]
    progress = Progress(3, clock=lambda: now[0])
    for item in progress.iter(["a", "b", "c"], label=str):
        now[0] += 10.0
        progress.note(f"did {item}")
    out = capsys.readouterr().out
    assert "[1/3] a  start" in out and "[3/3] c  done in 10.0 s  did c" in out
    assert "ETA 20.0 s" in out  # after the first 10 s step, two steps are left
    quiet = Progress(2, quiet=True)
    quiet.start("x")
    quiet.finish()
    assert capsys.readouterr().out == "" and len(quiet.lines) == 2
    with pytest.raises(ValueError, match="total"):
        Progress(-1)


def test_iteration_line_rewrites_one_line_per_stage():
    import io

    from jaxhumanoid.progress import IterationLine

    now = [0.0]
    live = io.StringIO()
    line = IterationLine(stream=live, live=True, interval=1.0, clock=lambda: now[0])
    line.status("setting up a long status line")  # shown until the first iterate replaces it
    for k in range(3):
        now[0] += 0.6  # the second call comes 0.6 s after the first: throttled
        line("stage 1", k, 10.0 - k, 1e-3)
    line("stage 2", 0, 5.0, 2e-4)
    line.close()
    text = live.getvalue()
    assert text.count("\n") == 2  # each stage ends its line once
    first, second = text.split("\n")[:2]
    assert first.startswith("\rsetting up a long status line\rstage 1  iteration     0")
    assert "iteration     1" not in first
    assert first.rstrip().endswith("objective  8.000000e+00  infeasibility 1.0e-03")  # the last iterate
    assert "\rstage 2  iteration     0  objective  5.000000e+00  infeasibility 2.0e-04" in second
    log = io.StringIO()  # not a terminal: the final line of each stage only
    plain = IterationLine(stream=log)
    plain.status("setting up")  # a log gets final lines only
    plain("stage 1", 0, 1.0, 1.0)
    plain("stage 1", 1, 0.5, 0.1)
    plain.close()
    assert log.getvalue() == "stage 1  iteration     1  objective  5.000000e-01  infeasibility 1.0e-01\n"
    quiet = io.StringIO()
    silent = IterationLine(stream=quiet, quiet=True, live=True)
    silent.status("setting up")
    silent("stage 1", 0, 1.0, 1.0)
    silent.close()
    assert quiet.getvalue() == ""
