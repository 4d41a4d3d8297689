"""Figures of a solved trajectory in the style of the paper's Figs. 5-8.

Top: a strip of stick-figure frames of the final trajectory (light blue) over the interpolated
stage-1 warm start (red), packed side by side on one ground line. Bottom: joint angles, input
torques and absolute contact forces against time.

The computations are numpy + matplotlib (no JAX): positions are recomputed from
``sol.geometry`` with the conventions of :mod:`jaxhumanoid.model` (O_0 = (0, ankle_height),
theta_l = q_1 + ... + q_l from +x, toes at x = -a0f, heel at x = +a0b), for a chain of any
number n of links, labelled with its joint names. Figures are :class:`matplotlib.figure.Figure`
objects, so no pyplot state or global backend is touched.
"""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle

from jaxhumanoid.model.params import default_joint_names

# Colours of the joints O_1, O_2, ... (cycled beyond ten joints); red is kept for the warm start.
JOINT_COLORS = (
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#17becf",
    "#bcbd22",
    "#7f7f7f",
    "#aec7e8",
)
FINAL_COLOR = "#5aaee8"  # light blue, final trajectory
WARM_COLOR = "#d62728"  # red, stage-1 warm start
PUSH_COLORS = ("#2ca02c", "#d62728")  # distal joint's f_t >= 0 (green), f_t < 0 (red)
HEAD_JOINT = "shoulder"  # a chain with a joint of this name gets a head, drawn beyond it along the trunk
HEAD_RADIUS = 0.10  # m
GEOMETRY_KEYS = ("a", "ankle_height", "a0f", "a0b")


def joint_color(j: int) -> str:
    """Colour of joint O_{j+1} (j counted from 0)."""
    return JOINT_COLORS[j % len(JOINT_COLORS)]


def actuated_names(names) -> tuple[str, ...]:
    """Joint of q_j and u_j for j = 1..n: the ankle O_0, then O_1..O_{n-1}."""
    return ("ankle", *tuple(names)[:-1])


def geometry_of(sol) -> dict[str, Any]:
    """Link lengths a (n,), joint names (n,), the row of the head's joint in the (n + 1, 2) joint
    positions (``head``, None without a shoulder) and the foot dimensions from ``sol.geometry``."""
    geo = getattr(sol, "geometry", None)
    if not isinstance(geo, dict):
        raise ValueError(f"sol.geometry: expected a dict with keys {GEOMETRY_KEYS}, got {type(geo).__name__}")
    missing = [k for k in GEOMETRY_KEYS if k not in geo]
    if missing:
        raise ValueError(f"sol.geometry: missing keys {missing} (need {GEOMETRY_KEYS})")
    a = np.asarray(geo["a"], dtype=float)
    if a.ndim != 1 or a.size < 2:
        raise ValueError(f"sol.geometry['a']: expected the lengths of n >= 2 links, got shape {a.shape}")
    names = tuple(str(x) for x in geo.get("names", default_joint_names(a.size)))
    if len(names) != a.size:
        raise ValueError(f"sol.geometry['names']: expected {a.size} joint names, got {names}")
    out: dict[str, Any] = {"a": a, "names": names, "head": names.index(HEAD_JOINT) + 1 if HEAD_JOINT in names else None}
    for key in GEOMETRY_KEYS[1:]:
        out[key] = float(np.asarray(geo[key]))
    return out


def check_solution(sol) -> int:
    """Check the array shapes of ``sol`` against each other; returns the number of intervals N."""
    t = np.asarray(sol.t, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"sol.t: expected a 1-D time grid with at least 2 nodes, got shape {t.shape}")
    if not np.all(np.diff(t) > 0):
        raise ValueError("sol.t: node times must be strictly increasing")
    n = t.size - 1
    k = geometry_of(sol)["a"].size
    expected = {
        "q": (n + 1, k),
        "qd": (n + 1, k),
        "u": (n, k),
        "f_contact": (n, k, 2),
        "gaps": (n + 1, k),
        "foot_reaction": (n, 2),
        "foot_margins": (n, 5),
    }
    for name, shape in expected.items():
        got = np.shape(getattr(sol, name))
        if got != shape:
            raise ValueError(f"sol.{name}: expected shape {shape} for N = {n} intervals of {k} links, got {got}")
    for i in sol.active:
        if not 1 <= int(i) <= k:
            raise ValueError(f"sol.active: contact indices must be in 1..{k} (O_1..O_{k}), got {tuple(sol.active)}")
    if sol.warm_start is not None:
        wt, wq = np.asarray(sol.warm_start.get("t")), np.asarray(sol.warm_start.get("q"))
        if wt.ndim != 1 or wq.shape != (wt.size, k) or wt.size < 2:
            raise ValueError(f"sol.warm_start: expected t (M,) and q (M, {k}), got shapes {wt.shape} and {wq.shape}")
    return n


def joint_positions(geometry: dict, q) -> np.ndarray:
    """Positions of O_0 (ankle) and O_1..O_n. q: (..., n) -> (..., n + 1, 2)."""
    q = np.asarray(q, dtype=float)
    theta = np.cumsum(q, axis=-1)
    links = np.asarray(geometry["a"])[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=-1)
    o0 = np.array([0.0, geometry["ankle_height"]])
    rel = np.concatenate([np.zeros(q.shape[:-1] + (1, 2)), np.cumsum(links, axis=-2)], axis=-2)
    return o0 + rel


def head_centre(points: np.ndarray, head: int) -> np.ndarray:
    """Centre of the head circle, just beyond joint row ``head`` along the link ending there (the
    trunk). points: (..., n + 1, 2) -> (..., 2)."""
    trunk = points[..., head, :] - points[..., head - 1, :]
    unit = trunk / np.linalg.norm(trunk, axis=-1, keepdims=True)
    return points[..., head, :] + 1.2 * HEAD_RADIUS * unit


def interpolate(t, values, times) -> np.ndarray:
    """Linear interpolation of the rows of ``values`` (len(t), ...) at ``times`` (clamped at the ends)."""
    values = np.asarray(values, dtype=float)
    flat = values.reshape(values.shape[0], -1)
    out = np.stack([np.interp(times, t, col) for col in flat.T], axis=-1)
    return out.reshape((len(times),) + values.shape[1:])


def midpoints(t) -> np.ndarray:
    """Interval midpoints of a node grid, (N+1,) -> (N,)."""
    t = np.asarray(t, dtype=float)
    return 0.5 * (t[:-1] + t[1:])


def warm_start_q(sol, times) -> np.ndarray | None:
    """Warm-start joint angles interpolated at ``times``, or None without a warm start."""
    if sol.warm_start is None:
        return None
    return interpolate(np.asarray(sol.warm_start["t"]), sol.warm_start["q"], times)


def draw_foot(ax, geometry: dict, x: float = 0.0, color: str = "0.25", zorder: float = 2):
    """The steady foot: sole from toe (-a0f) to heel (+a0b) on the ground, ankle above."""
    toe, heel, ankle_y = x - geometry["a0f"], x + geometry["a0b"], geometry["ankle_height"]
    ax.fill([toe, heel, x], [0.0, 0.0, ankle_y], color=color, alpha=0.35, lw=0, zorder=zorder)
    ax.plot([toe, heel], [0.0, 0.0], color=color, lw=3, solid_capstyle="butt", zorder=zorder)
    ax.plot([x], [ankle_y], "o", color=color, ms=3, zorder=zorder + 0.1)


def draw_ground(ax, x0: float, x1: float):
    """Ground line y = 0 with a light hatch below it."""
    ax.axhline(0.0, color="0.3", lw=1, zorder=1)
    ax.fill_between([x0, x1], [-0.06, -0.06], [0.0, 0.0], color="0.88", lw=0, zorder=0)


def draw_stick(ax, points, color, head=None, lw=2.2, alpha=1.0, zorder=3):
    """One stick figure (links, joint dots and, when ``head`` is a joint row, a head); returns
    (line, head patch, head) for :func:`update_stick` (patch and head None without a head)."""
    (line,) = ax.plot(
        points[:, 0],
        points[:, 1],
        "-o",
        color=color,
        lw=lw,
        ms=2.5 * lw / 2.2,
        alpha=alpha,
        zorder=zorder,
        solid_capstyle="round",
        solid_joinstyle="round",
    )
    if head is None:
        return line, None, None
    patch = Circle(
        head_centre(points, head), HEAD_RADIUS, facecolor="none", edgecolor=color, lw=lw, alpha=alpha, zorder=zorder
    )
    ax.add_patch(patch)
    return line, patch, head


def update_stick(artists, points):
    """Move a stick figure drawn by :func:`draw_stick` to new joint positions."""
    line, patch, head = artists
    line.set_data(points[:, 0], points[:, 1])
    if patch is not None:
        patch.center = tuple(head_centre(points, head))


def frame_extent(geometry: dict, points) -> tuple[float, float]:
    """Horizontal extent (xmin, xmax) of one or more stick figures plus the foot."""
    pts = np.asarray(points).reshape(-1, geometry["a"].size + 1, 2)
    parts = [pts[..., 0].ravel(), np.array([-geometry["a0f"], geometry["a0b"]])]
    if geometry["head"] is not None:
        heads = head_centre(pts, geometry["head"])
        parts += [heads[:, 0] - HEAD_RADIUS, heads[:, 0] + HEAD_RADIUS]
    xs = np.concatenate(parts)
    return float(xs.min()), float(xs.max())


def pack_offsets(extents, gap: float) -> np.ndarray:
    """x offsets placing frames with extents [(xmin, xmax), ...] side by side, ``gap`` apart."""
    offsets, right = [], 0.0
    for i, (lo, hi) in enumerate(extents):
        off = -lo if i == 0 else right + gap - lo
        offsets.append(off)
        right = off + hi
    return np.asarray(offsets)


def _title(sol) -> str:
    if not sol.stages:
        state = "no solver statistics"
    else:
        statuses = " + ".join(s.status for s in sol.stages)
        state = "converged" if sol.success else f"NOT converged ({statuses})"
    return (
        f"task {sol.task}  |  scheme {sol.scheme}  |  solver {sol.solver}  |  "
        f"objective J = {float(sol.objective):.4g}  |  {state}"
    )


def _frames_panel(ax, sol, geo, times):
    """Frame strip: final (light blue) over warm start (red), packed along x."""
    pts = joint_positions(geo, interpolate(sol.t, sol.q, times))
    warm_q = warm_start_q(sol, times)
    warm = None if warm_q is None else joint_positions(geo, warm_q)
    both = pts if warm is None else np.stack([pts, warm], axis=1)
    extents = [frame_extent(geo, both[i]) for i in range(len(times))]
    offsets = pack_offsets(extents, gap=0.3)
    shift = np.array([1.0, 0.0])
    for i, ti in enumerate(times):
        draw_foot(ax, geo, offsets[i])
        if warm is not None:
            draw_stick(ax, warm[i] + offsets[i] * shift, WARM_COLOR, geo["head"], lw=1.6, alpha=0.6, zorder=3)
        draw_stick(ax, pts[i] + offsets[i] * shift, FINAL_COLOR, geo["head"], lw=2.4, zorder=4)
        ax.text(offsets[i], -0.1, f"{ti:.2f} s", ha="center", va="top", fontsize=8)
    x0, x1 = -0.15, offsets[-1] + extents[-1][1] + 0.15
    ymax = max(float(both[..., 1].max()) + (2.3 * HEAD_RADIUS if geo["head"] is not None else 0.05), 0.5)
    draw_ground(ax, x0, x1)
    ax.set_xlim(x0, x1)
    ax.set_ylim(-0.28, ymax + 0.05)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xticks([])
    ax.set_ylabel("y (m)")
    ax.set_xlabel("frames at the times shown (each placed at its own x offset, ankle at the foot mark)")
    for side in ("top", "right", "bottom"):
        ax.spines[side].set_visible(False)
    handles = [Line2D([], [], color=FINAL_COLOR, lw=2.4, marker="o", ms=3, label="final trajectory")]
    if warm is not None:
        handles.append(
            Line2D(
                [],
                [],
                color=WARM_COLOR,
                lw=1.6,
                alpha=0.6,
                marker="o",
                ms=3,
                label="warm start (stage 1, interpolated)",
            )
        )
    ax.legend(
        handles=handles, loc="upper right", fontsize=8, frameon=False, ncols=len(handles), bbox_to_anchor=(1.0, 1.12)
    )


def _angles_panel(ax, sol, geo):
    q_deg = np.degrees(np.asarray(sol.q))
    for j, name in enumerate(actuated_names(geo["names"])):
        ax.plot(sol.t, q_deg[:, j], color=joint_color(j), lw=1.5, label=f"$q_{{{j + 1}}}$ ({name})")
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("joint angle (deg)")
    ax.set_title("configuration angles", fontsize=10)
    ax.legend(fontsize=7, ncols=2)


def _torques_panel(ax, sol, geo):
    for j, name in enumerate(actuated_names(geo["names"])):
        ax.stairs(np.asarray(sol.u)[:, j], sol.t, color=joint_color(j), lw=1.5, label=f"$u_{{{j + 1}}}$ ({name})")
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("input torque (N m)")
    ax.set_title("input torques", fontsize=10)
    ax.legend(fontsize=7, ncols=2)


def _signed_segments(t, values, sign_source):
    """Segments of the curve (t, values) and a colour per segment by the sign of ``sign_source``."""
    pts = np.stack([t, values], axis=-1)
    segments = np.stack([pts[:-1], pts[1:]], axis=1)
    mid_sign = 0.5 * (sign_source[:-1] + sign_source[1:])
    colors = [PUSH_COLORS[0] if s >= 0 else PUSH_COLORS[1] for s in mid_sign]
    return segments, colors


def _forces_panel(ax, sol, geo):
    """|f_n| and |f_t| of the active contacts; the distal joint O_n (the hand) pushes and pulls, so
    its f_t is coloured by sign."""
    tm = midpoints(sol.t)
    f = np.asarray(sol.f_contact)
    names = geo["names"]
    handles = []
    for i in sorted(int(k) for k in sol.active):
        name, ft, fn = names[i - 1], f[:, i - 1, 0], f[:, i - 1, 1]
        if i == len(names):
            ax.plot(tm, np.abs(fn), color="0.15", lw=1.4, zorder=3)
            handles.append(Line2D([], [], color="0.15", lw=1.4, label=f"{name} $|f_n|$"))
            if tm.size > 1:
                segs, colors = _signed_segments(tm, np.abs(ft), ft)
                ax.add_collection(LineCollection(segs, colors=colors, lw=2.0, zorder=4))
            handles += [
                Line2D([], [], color=PUSH_COLORS[0], lw=2.0, label=f"{name} $|f_t|$, " + r"$f_t \geq 0$"),
                Line2D([], [], color=PUSH_COLORS[1], lw=2.0, label=f"{name} $|f_t|$, " + r"$f_t < 0$"),
            ]
        else:
            color = joint_color(i - 1)
            ax.plot(tm, np.abs(fn), color=color, lw=1.3)
            ax.plot(tm, np.abs(ft), color=color, lw=1.3, ls=":")
            handles += [
                Line2D([], [], color=color, lw=1.3, label=f"{name} $|f_n|$"),
                Line2D([], [], color=color, lw=1.3, ls=":", label=f"{name} $|f_t|$"),
            ]
    if not handles:
        ax.text(
            0.5,
            0.5,
            "no modelled contact forces\n(no active contacts)",
            transform=ax.transAxes,
            ha="center",
            va="center",
            fontsize=9,
            color="0.4",
        )
    else:
        ax.legend(handles=handles, fontsize=7, ncols=2)
    ax.autoscale_view()  # the LineCollection does not rescale the axes by itself
    ax.set_xlim(float(sol.t[0]), float(sol.t[-1]))
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("time t (s)")
    ax.set_ylabel("absolute contact force (N)")
    ax.set_title("contact forces of the active contacts", fontsize=10)


def plot_solution(sol, path=None, n_frames: int = 8, dpi: int = 120) -> Figure:
    """Paper-style summary figure of ``sol`` (Figs. 5-8); saved as PNG when ``path`` is given.

    n_frames: number of evenly spaced instants in the frame strip (2..40).
    Returns the :class:`~matplotlib.figure.Figure`.
    """
    check_solution(sol)
    if not isinstance(n_frames, (int, np.integer)) or not 2 <= n_frames <= 40:
        raise ValueError(f"n_frames: expected an integer in 2..40, got {n_frames!r}")
    geo = geometry_of(sol)
    t = np.asarray(sol.t, dtype=float)
    times = np.linspace(t[0], t[-1], int(n_frames))

    width = 15.0
    fig = Figure(figsize=(width, 1.0), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 3, height_ratios=[1.0, 1.0])
    ax_frames = fig.add_subplot(grid[0, :])
    _frames_panel(ax_frames, sol, geo, times)
    # strip height follows its data aspect, so that frames keep their true proportions
    (x0, x1), (y0, y1) = ax_frames.get_xlim(), ax_frames.get_ylim()
    strip_h = min(max(width * 0.97 * (y1 - y0) / (x1 - x0), 1.2), 6.0) + 0.6
    panels_h = 3.4
    fig.set_size_inches(width, strip_h + panels_h + 0.4)
    grid.set_height_ratios([strip_h, panels_h])
    _angles_panel(fig.add_subplot(grid[1, 0]), sol, geo)
    _torques_panel(fig.add_subplot(grid[1, 1]), sol, geo)
    _forces_panel(fig.add_subplot(grid[1, 2]), sol, geo)
    fig.suptitle(_title(sol), fontsize=11)
    if path is not None:
        save_png(fig, path, dpi=dpi)
    return fig


def save_png(fig: Figure, path, dpi: int = 120) -> pathlib.Path:
    """Write ``fig`` as PNG to ``path`` (parent directories created); returns the path."""
    path = pathlib.Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"path: expected a .png file name, got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, format="png")
    return path
