"""The contact sequence the solver discovered, and the steady-foot margins over time.

A joint O_i is "in contact" on interval [t_k, t_k+1] when

* it has a modelled contact force (i in ``sol.active``): its normal force at the midpoint is
  above ``force_threshold`` (N);
* otherwise: its midpoint gap (y_k + y_k+1) / 2 is below ``gap_threshold`` (m).

Both criteria are evaluated at the collocation midpoints, where the transcription evaluates
the contact laws, so runs of contact intervals k = a..b map to the time span [t_a, t_b+1].
"""

from __future__ import annotations

import pathlib

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from jaxhumanoid.outputs.plots import check_solution, geometry_of, joint_color, midpoints, save_png

FORCE_THRESHOLD_N = 20.0
GAP_THRESHOLD_M = 0.005
UNLOADED_N = 1.0  # below this foot normal force, the foot ratios are not defined


def _check_thresholds(force_threshold, gap_threshold):
    if not np.isfinite(force_threshold) or force_threshold < 0:
        raise ValueError(f"force_threshold: expected a finite value >= 0 (N), got {force_threshold!r}")
    if not np.isfinite(gap_threshold):
        raise ValueError(f"gap_threshold: expected a finite value (m), got {gap_threshold!r}")


def intervals_from_mask(t, mask) -> list[tuple[float, float]]:
    """Time spans of the runs of True in ``mask`` (N,) over the intervals of the node grid ``t`` (N+1,)."""
    t, mask = np.asarray(t, dtype=float), np.asarray(mask, dtype=bool)
    if mask.shape != (t.size - 1,):
        raise ValueError(f"mask: expected shape ({t.size - 1},) for {t.size} nodes, got {mask.shape}")
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    starts = np.flatnonzero(np.diff(padded) == 1)
    ends = np.flatnonzero(np.diff(padded) == -1)  # exclusive interval index = node index of the end
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def contact_mask(sol, force_threshold: float = FORCE_THRESHOLD_N, gap_threshold: float = GAP_THRESHOLD_M):
    """Boolean (N, n) contact state of O_1..O_n on each interval, and the criterion used per joint."""
    check_solution(sol)
    _check_thresholds(force_threshold, gap_threshold)
    f_n = np.asarray(sol.f_contact, dtype=float)[:, :, 1]
    gaps = np.asarray(sol.gaps, dtype=float)
    gap_mid = 0.5 * (gaps[:-1] + gaps[1:])
    active = {int(i) for i in sol.active}
    mask = np.empty(f_n.shape, dtype=bool)
    criteria = []
    for j in range(f_n.shape[1]):
        if j + 1 in active:
            mask[:, j] = f_n[:, j] > force_threshold
            criteria.append("force")
        else:
            mask[:, j] = gap_mid[:, j] < gap_threshold
            criteria.append("gap")
    return mask, tuple(criteria)


def contact_intervals(
    sol, force_threshold: float = FORCE_THRESHOLD_N, gap_threshold: float = GAP_THRESHOLD_M
) -> dict[str, list[tuple[float, float]]]:
    """Contact spans per joint name: {"knee": [(t_start, t_end), ...], ..., "hand": [...]} (seconds).

    Joints in ``sol.active`` are in contact where f_n > ``force_threshold`` (N); the others where
    the gap is below ``gap_threshold`` (m). JSON-serialisable (tuples become lists).
    """
    mask, _ = contact_mask(sol, force_threshold, gap_threshold)
    return {name: intervals_from_mask(sol.t, mask[:, j]) for j, name in enumerate(geometry_of(sol)["names"])}


def contact_summary(sol, force_threshold: float = FORCE_THRESHOLD_N, gap_threshold: float = GAP_THRESHOLD_M) -> dict:
    """JSON-ready record of the contact sequence for report.json."""
    mask, criteria = contact_mask(sol, force_threshold, gap_threshold)
    names = geometry_of(sol)["names"]
    return {
        "force_threshold_N": float(force_threshold),
        "gap_threshold_m": float(gap_threshold),
        "criterion": dict(zip(names, criteria)),
        "intervals": {
            name: [list(span) for span in intervals_from_mask(sol.t, mask[:, j])] for j, name in enumerate(names)
        },
    }


def foot_margins(sol) -> dict[str, np.ndarray]:
    """Steady-foot quantities at the interval midpoints.

    f_n0 (N); friction_slack = min(mu f_n0 - f_t0, mu f_n0 + f_t0) / f_n0 (>= 0 inside the cone);
    cop = u_1 / f_n0 (m), inside the sole when -a0f <= cop <= a0b. Ratios are NaN where the foot
    is unloaded (f_n0 < 1 N).
    """
    check_solution(sol)
    f_n0 = np.asarray(sol.foot_reaction, dtype=float)[:, 1]
    margins = np.asarray(sol.foot_margins, dtype=float)
    loaded = f_n0 >= UNLOADED_N
    safe = np.where(loaded, f_n0, 1.0)
    slack = np.where(loaded, np.minimum(margins[:, 1], margins[:, 2]) / safe, np.nan)
    cop = np.where(loaded, np.asarray(sol.u, dtype=float)[:, 0] / safe, np.nan)
    return {"t": midpoints(sol.t), "f_n0": f_n0, "friction_slack": slack, "cop": cop}


def _gantt_panel(ax, sol, mask, criteria, names):
    t = np.asarray(sol.t, dtype=float)
    for j in range(len(names)):
        spans = [(a, b - a) for a, b in intervals_from_mask(t, mask[:, j])]
        by_force = criteria[j] == "force"
        ax.broken_barh(
            spans,
            (j - 0.35, 0.7),
            facecolors=joint_color(j) if by_force else "none",
            edgecolors=joint_color(j),
            hatch=None if by_force else "///",
            lw=1.0,
        )
    labels = [f"{name} (O$_{{{j + 1}}}$)" for j, name in enumerate(names)]
    ax.set_yticks(range(len(names)), labels)
    ax.set_ylim(len(names) - 0.4, -0.6)
    ax.set_xlim(t[0], t[-1])
    ax.grid(axis="x", color="0.9")
    ax.set_ylabel("joint in contact")
    ax.set_xlabel("time t (s)")
    handles = [
        Patch(facecolor="0.5", edgecolor="0.5", label="f$_n$ > force threshold (active contact)"),
        Patch(facecolor="none", edgecolor="0.5", hatch="///", label="gap < gap threshold (no force model)"),
    ]
    ax.legend(handles=handles, fontsize=7, loc="upper right", bbox_to_anchor=(1.0, 1.28), ncols=2, frameon=False)


def _unloaded_spans(ax, t, values):
    """Grey bands over the intervals of the node grid ``t`` where the ratio is undefined."""
    for a, b in intervals_from_mask(t, np.isnan(values)):
        ax.axvspan(a, b, color="0.85", lw=0)


def _friction_panel(ax, t, margins, mu_label):
    tm, slack = margins["t"], margins["friction_slack"]
    _unloaded_spans(ax, t, slack)
    ax.plot(tm, slack, ".-", color="#1f77b4", lw=1.5, ms=3, label=r"min($\mu f_{n0} \mp f_{t0}$) / $f_{n0}$")
    ax.axhline(0.0, color="#d62728", lw=1.0, ls="--", label="cone boundary (slack = 0)")
    ax.set_ylabel("friction-cone slack (-)")
    ax.set_xlabel("time t (s)")
    ax.set_title(f"steady foot: friction cone (5b){mu_label}", fontsize=9)
    ax.legend(fontsize=7, loc="best")


def _cop_panel(ax, t, margins, geo):
    tm, cop = margins["t"], margins["cop"]
    _unloaded_spans(ax, t, cop)
    ax.axhspan(-geo["a0f"], geo["a0b"], color="#2ca02c", alpha=0.12, lw=0, label="sole [-a0f, a0b]")
    ax.axhline(-geo["a0f"], color="#2ca02c", lw=1.0, ls="--")
    ax.axhline(geo["a0b"], color="#2ca02c", lw=1.0, ls="--")
    ax.plot(tm, cop, ".-", color="#9467bd", lw=1.5, ms=3, label=r"$u_1 / f_{n0}$")
    for y, label, va in ((-geo["a0f"], "toe (-a0f)", "bottom"), (geo["a0b"], "heel (a0b)", "top")):
        ax.annotate(label, xy=(0.005, y), xycoords=("axes fraction", "data"), va=va, fontsize=7, color="#2ca02c")
    ax.set_ylabel("centre of pressure x (m)")
    ax.set_xlabel("time t (s)")
    ax.set_title("steady foot: centre of pressure under the sole (5c); grey = foot unloaded", fontsize=9)
    ax.legend(fontsize=7, loc="best")


def plot_contact_timeline(
    sol, path=None, force_threshold: float = FORCE_THRESHOLD_N, gap_threshold: float = GAP_THRESHOLD_M, dpi: int = 120
) -> Figure:
    """Gantt chart of the contacts of O_1..O_n (the humanoid: knee ... hand) plus the steady-foot margins.

    Saved as PNG when ``path`` is given; returns the :class:`~matplotlib.figure.Figure`.
    """
    mask, criteria = contact_mask(sol, force_threshold, gap_threshold)
    geo = geometry_of(sol)
    margins = foot_margins(sol)
    mu = sol.geometry.get("mu")
    mu_label = "" if mu is None else rf", $\mu$ = {float(np.asarray(mu)):g}"
    fig = Figure(figsize=(10, 6.3 + 0.24 * len(geo["names"])), layout="constrained")
    FigureCanvasAgg(fig)
    ax_gantt, ax_fric, ax_cop = fig.subplots(3, 1, sharex=True, height_ratios=[1.2, 1.0, 1.0])
    _gantt_panel(ax_gantt, sol, mask, criteria, geo["names"])
    _friction_panel(ax_fric, sol.t, margins, mu_label)
    _cop_panel(ax_cop, sol.t, margins, geo)
    ax_gantt.tick_params(labelbottom=True)
    ax_fric.tick_params(labelbottom=True)
    fig.suptitle(
        f"contact sequence  |  task {sol.task}, scheme {sol.scheme}, solver {sol.solver}  |  "
        f"thresholds: f$_n$ > {force_threshold:g} N, gap < {gap_threshold * 1e3:g} mm",
        fontsize=10,
    )
    if path is not None:
        save_png(fig, pathlib.Path(path), dpi=dpi)
    return fig
