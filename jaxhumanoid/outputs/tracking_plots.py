"""Figures of a Monte-Carlo tracking run (``jaxhumanoid.tracking.track``).

``plot_tracking``: one panel per joint angle, the plan (black) against every trial simulated open
loop (thin red) and under TVLQR (thin blue), each line drawn up to the trial's first failure
(a cross marks it); the goal box (grey band) at the end. The last panel gives the tightest of the
five steady-foot products (5) per step in units of body weight (the foot's own weight added, as
the success test does): below zero the foot lifts, slips or tips. ``animate_trial`` writes an
animation of one closed-loop trial with ``outputs.animation.animate``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from jaxhumanoid.outputs.animation import animate
from jaxhumanoid.outputs.plots import actuated_names, joint_color, save_png
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.tracking.montecarlo import Criteria, tightest_foot_margin

OPEN_COLOR = "#d62728"
CLOSED_COLOR = "#1f77b4"
PLAN_COLOR = "black"


def _cut(values, t_fail, t):
    """values (M+1, ...) with NaN after t_fail (None: kept whole)."""
    out = np.array(values, dtype=float)
    if t_fail is not None:
        out[t > t_fail + 1e-12] = np.nan
    return out


def plot_tracking(res, sol: Solution, path=None, max_lines: int = 100, dpi: int = 110) -> Figure:
    """The ensemble figure of the module docstring; ``max_lines`` trials drawn per policy."""
    t = np.asarray(res.reference.t)
    n = sol.n_links
    names = actuated_names(sol.geometry["names"])
    ncols = 3
    nrows = int(np.ceil((n + 1) / ncols))
    fig = Figure(figsize=(4.2 * ncols, 2.9 * nrows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(nrows, ncols, i + 1) for i in range(n + 1)]
    shown = range(min(res.trials, max_lines))
    crit = Criteria(**res.criteria)
    for key, rollout, color in (
        ("open_loop", res.open_loop, OPEN_COLOR),
        ("closed_loop", res.closed_loop, CLOSED_COLOR),
    ):
        for i in shown:
            rec = res.records[i][key]
            q = _cut(np.degrees(np.asarray(rollout.x[i])[:, :n]), rec["t_fail"], t)
            slack = _cut(tightest_foot_margin(rollout.foot_margins[i], res.trial_plant(i), crit), rec["t_fail"], t[1:])
            for j in range(n):
                axes[j].plot(t, q[:, j], color=color, lw=0.5, alpha=0.35)
            axes[n].plot(t[1:], slack, color=color, lw=0.5, alpha=0.35)
            if rec["t_fail"] is not None:
                k = int(np.searchsorted(t, rec["t_fail"])) - 1
                for j in range(n):
                    axes[j].plot(t[k], q[k, j], "x", color=color, ms=3, alpha=0.6)
    plan_slack = tightest_foot_margin(sol.foot_margins, res.plant, crit)
    for j in range(n):
        ax = axes[j]
        ax.plot(sol.t, np.degrees(np.asarray(sol.q)[:, j]), color=PLAN_COLOR, lw=1.6)
        g, tol = np.degrees(res.goal.q[j]), np.degrees(res.goal.tolerance + res.criteria["goal_slack"])
        ax.axhspan(g - tol, g + tol, xmin=0.93, color="0.6", alpha=0.4, lw=0)
        ax.set_title(f"$q_{{{j + 1}}}$ ({names[j]})", fontsize=9, color=joint_color(j))
        ax.set_ylabel("deg")
    axes[n].plot(np.asarray(sol.t)[:-1], plan_slack, color=PLAN_COLOR, lw=1.6, drawstyle="steps-post")
    axes[n].axhline(0.0, color="0.3", lw=0.8)
    axes[n].set_ylim(-0.5, 1.0)
    axes[n].set_title("tightest steady-foot margin (5) / M g", fontsize=9)
    for ax in axes:
        ax.set_xlabel("t (s)")
    fig.suptitle(
        f"task {res.task}: {res.trials} perturbed trials, success open loop {res.open_loop_success_rate:.0%} (red), "
        f"TVLQR {res.closed_loop_success_rate:.0%} (blue); plan black, x = first failure",
        fontsize=10,
    )
    if path is not None:
        save_png(fig, path, dpi=dpi)
    return fig


def animate_trial(res, sol: Solution, path, trial: int | None = None, max_frames: int = 60):
    """An animation of one closed-loop trial (default the first perturbed one) on its own body."""
    trial = (1 if res.trials > 1 else 0) if trial is None else int(trial)
    if not 0 <= trial < res.trials:
        raise ValueError(f"trial: expected an index in 0..{res.trials - 1}, got {trial}")
    m = res.substeps
    x = np.asarray(res.closed_loop.x[trial])[::m]
    u = np.asarray(res.closed_loop.u[trial])[::m]
    n, N = sol.n_links, x.shape[0] - 1
    scale = np.asarray(res.records[trial]["perturbation"]["length_scale"])
    run = dataclasses.replace(
        sol,
        t=np.asarray(res.reference.t)[::m],
        q=x[:, :n],
        qd=x[:, n:],
        u=u[:N],
        f_contact=np.zeros((N, n, 2)),
        gaps=np.zeros((N + 1, n)),
        foot_reaction=np.zeros((N, 2)),
        foot_margins=np.zeros((N, 5)),
        warm_start=None,
        geometry={**sol.geometry, "a": np.asarray(sol.geometry["a"]) * scale},
        scheme=f"closed loop, trial {trial}",
        solver="TVLQR",
    )
    return animate(run, path, max_frames=max_frames, show_forces=False, show_warm_start=False)
