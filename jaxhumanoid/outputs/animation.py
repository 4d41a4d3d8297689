"""Animation of a solved trajectory: GIF (matplotlib + pillow) or MP4 (ffmpeg).

The stick figure moves over the ground with the steady foot drawn, optional arrows for the
contact forces at the active joints and the ground reaction at the foot's centre of pressure,
a time stamp, and the stage-1 warm start as a faint red ghost when the solution has one.
Frames are evenly spaced in time (at most ``max_frames``), so files stay small.
"""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np
from matplotlib.animation import FFMpegWriter, PillowWriter, writers
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from jaxhumanoid.outputs.plots import (
    FINAL_COLOR,
    HEAD_RADIUS,
    WARM_COLOR,
    check_solution,
    draw_foot,
    draw_ground,
    draw_stick,
    geometry_of,
    interpolate,
    joint_positions,
    midpoints,
    update_stick,
    warm_start_q,
)

CONTACT_ARROW_COLOR = "#e67e22"
FOOT_ARROW_COLOR = "0.35"
ARROW_LENGTH_M = 0.5  # default: the largest force is drawn this long


def frame_times(t, max_frames: int) -> np.ndarray:
    """At most ``max_frames`` instants evenly spread over [t_0, t_N]."""
    t = np.asarray(t, dtype=float)
    return np.linspace(t[0], t[-1], min(int(max_frames), t.size))


def _writer(path: pathlib.Path, fps: float):
    suffix = path.suffix.lower()
    if suffix == ".gif":
        return PillowWriter(fps=fps)  # type: ignore[arg-type]  # a float rate works; the stubs say int
    if suffix == ".mp4":
        if not writers.is_available("ffmpeg"):
            raise RuntimeError(
                f"cannot write {path}: MP4 needs ffmpeg on PATH, which was not found; install ffmpeg or ask for a .gif"
            )
        return FFMpegWriter(fps=fps)  # type: ignore[arg-type]
    raise ValueError(f"path: expected a file name ending in .gif or .mp4, got {str(path)!r}")


def _forces_at(sol, times):
    """Contact forces (F, k, 2) of the active joints and foot reaction (F, 2), centre of pressure (F,)."""
    tm = midpoints(sol.t)
    active = np.array(sorted(int(i) for i in sol.active), dtype=int) - 1
    f_contact = interpolate(tm, np.asarray(sol.f_contact)[:, active], times)
    foot = interpolate(tm, sol.foot_reaction, times)
    u1 = interpolate(tm, np.asarray(sol.u)[:, :1], times)[:, 0]
    cop = np.where(foot[:, 1] > 1.0, u1 / np.maximum(foot[:, 1], 1.0), 0.0)
    return active, f_contact, foot, cop


def _limits(geo, clouds):
    pts = np.concatenate([c.reshape(-1, 2) for c in clouds])
    x0 = min(pts[:, 0].min() - HEAD_RADIUS, -geo["a0f"]) - 0.2
    x1 = max(pts[:, 0].max() + HEAD_RADIUS, geo["a0b"]) + 0.2
    y1 = max(pts[:, 1].max() + 2.3 * HEAD_RADIUS, 0.5) + 0.15
    return (x0, x1), (-0.15, y1)


def animate(
    sol,
    path,
    fps: float = 15.0,
    max_frames: int = 60,
    show_forces: bool = True,
    show_warm_start: bool = True,
    dpi: int = 80,
    force_scale: float | None = None,
) -> pathlib.Path:
    """Write an animation of ``sol`` to ``path`` (.gif, or .mp4 when ffmpeg is available).

    fps: frames per second; max_frames: frame budget (>= 2; the frames are evenly spaced in time);
    show_forces: draw contact and foot-reaction forces as arrows, ``force_scale`` m per N
    (default: the largest force is 0.5 m long); show_warm_start: faint red ghost of the warm start.
    Returns the path written.
    """
    check_solution(sol)
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps: expected a positive frame rate, got {fps!r}")
    if not isinstance(max_frames, (int, np.integer)) or max_frames < 2:
        raise ValueError(f"max_frames: expected an integer >= 2, got {max_frames!r}")
    if force_scale is not None and (not np.isfinite(force_scale) or force_scale <= 0):
        raise ValueError(f"force_scale: expected a positive length per force (m/N), got {force_scale!r}")
    path = pathlib.Path(path)
    writer = _writer(path, fps)
    geo = geometry_of(sol)
    times = frame_times(sol.t, max_frames)
    pts = joint_positions(geo, interpolate(sol.t, sol.q, times))
    warm_q = warm_start_q(sol, times) if show_warm_start else None
    warm = None if warm_q is None else joint_positions(geo, warm_q)
    (x0, x1), (y0, y1) = _limits(geo, [pts] if warm is None else [pts, warm])

    width = 6.0
    height = float(np.clip(width * (y1 - y0) / (x1 - x0), 2.5, 6.0)) + 0.5
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    draw_ground(ax, x0, x1)
    draw_foot(ax, geo)
    ghost = None if warm is None else draw_stick(ax, warm[0], WARM_COLOR, geo["head"], lw=1.6, alpha=0.3, zorder=3)
    figure = draw_stick(ax, pts[0], FINAL_COLOR, geo["head"], lw=2.6, zorder=4)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)  (facing -x, toes at -a0f)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"task {sol.task}  |  {sol.scheme}  |  {sol.solver}", fontsize=9)
    stamp = ax.text(0.02, 0.97, "", transform=ax.transAxes, va="top", fontsize=9, family="monospace")
    handles = [Line2D([], [], color=FINAL_COLOR, lw=2.6, label="trajectory")]
    if ghost is not None:
        handles.append(Line2D([], [], color=WARM_COLOR, lw=1.6, alpha=0.3, label="warm start"))

    arrows = None
    if show_forces:
        active, f_contact, foot, cop = _forces_at(sol, times)
        largest = max(float(np.abs(f_contact).max(initial=0.0)), float(np.abs(foot).max(initial=0.0)), 1.0)
        scale = force_scale if force_scale is not None else ARROW_LENGTH_M / largest
        quiver: dict[str, Any] = {
            "angles": "xy",
            "scale_units": "xy",
            "scale": 1.0 / scale,
            "width": 0.006,
            "zorder": 5,
        }
        contact_q = ax.quiver(
            np.zeros(active.size),
            np.zeros(active.size),
            np.zeros(active.size),
            np.zeros(active.size),
            color=CONTACT_ARROW_COLOR,
            **quiver,
        )
        foot_q = ax.quiver([0.0], [0.0], [0.0], [0.0], color=FOOT_ARROW_COLOR, **quiver)
        arrows = (contact_q, foot_q)
        handles += [
            Line2D([], [], color=CONTACT_ARROW_COLOR, lw=2, label="contact force"),
            Line2D([], [], color=FOOT_ARROW_COLOR, lw=2, label="foot reaction (at CoP)"),
        ]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=7, frameon=False)

    fig.canvas.draw()
    fig.set_layout_engine("none")  # freeze the layout so that frames do not jitter
    path.parent.mkdir(parents=True, exist_ok=True)
    with writer.saving(fig, str(path), dpi):
        for k, tk in enumerate(times):
            update_stick(figure, pts[k])
            if ghost is not None and warm is not None:
                update_stick(ghost, warm[k])
            if arrows is not None:
                at = pts[k, active + 1] if active.size else np.zeros((0, 2))
                arrows[0].set_offsets(at)
                arrows[0].set_UVC(f_contact[k, :, 0], f_contact[k, :, 1])
                arrows[1].set_offsets([[cop[k], 0.0]])
                arrows[1].set_UVC([foot[k, 0]], [foot[k, 1]])
            stamp.set_text(f"t = {tk:5.2f} s")
            writer.grab_frame()
    return path
