"""Study: do the plans of T1-T4 execute? Open loop against TVLQR over perturbed bodies and starts.

    python scripts/study_tracking.py [--tasks T1 T2 T3 T4 | examples/paper/T1.toml ...] [--trials 100]
        [--seed 0] [--plans DIR] [--out docs/tracking.json] [--lqr KEY=VALUE ...]
        [--foot-margin LOAD FRICTION COP] [--N 100] [--contact-force-limit MG|none] [--qp-filter [LOAD FRICTION COP]] [--defects]
        [--ablation [mass length contact friction start_rad torque_noise_Nm]]

The tables are copied into docs/tracking.md, which explains them.

Each task (a built-in key or a task file) is solved with the defaults (A,F+C,2S, N = 100, IPOPT;
a task file's own settings) but stage 1's and the dynamic stages' options, which are the
benchmarks' fixed ``bench_settings`` unless a task file sets its own, on ``--N`` intervals and with
``--foot-margin`` when given, into
``--plans``/<label> (reused when a solution is already there; the label is the key, or the task
file's folder and stem, with the margin, the grid and ``--contact-force-limit`` appended when
given), then ``jaxhumanoid.tracking.track`` runs ``--trials`` perturbed
executions at the default perturbation, open loop and closed loop (and, with ``--qp-filter``,
TVLQR through the steady-foot QP filter of ``jaxhumanoid.tracking.filter``, with its defaults or
the given margin), as one batch each. Writes the
JSON (rates, failure reasons, timings) and a markdown table next to it (``tracking_table.md``); rows of tasks
not run this time are kept from an existing ``--out``. ``--defects`` instead measures how far each
plan is from the simulator interval by interval (``tracking.plan.interval_defects``) and adds it to
the rows (and a table to ``tracking_defects.md``). ``--ablation`` runs the trials once per named
component of the perturbation (default all six), that component at its default size and every
other one zero, one row each, after a row with all of them on the same plan and the same draws:
which uncertainty the plan and the controller do not survive.
"""

from __future__ import annotations

import jaxhumanoid.runtime  # noqa: F401  (first: it pins the BLAS kernels before numpy loads)

# isort: split
import argparse
import collections
import dataclasses
import json
import pathlib
import time

import numpy as np

import jaxhumanoid as jh
from jaxhumanoid.model.foot import FootMargin
from jaxhumanoid.ocp.tasks import with_force_limit
from jaxhumanoid.outputs.cli import force_limit_arg, with_overrides
from jaxhumanoid.progress import Progress
from jaxhumanoid.studies.bench import bench_settings
from jaxhumanoid.tracking import LQRWeights, Perturbation, track
from jaxhumanoid.tracking.filter import SafetyFilter
from jaxhumanoid.tracking.plan import interval_defects


def label(task: str, margin, N, limit=None) -> str:
    """The row's name: the key T1..T4 or the task file's folder_stem, with the margin, the grid and
    the contact-force limit appended when given."""
    path = pathlib.Path(task)
    name = f"{path.parent.name}_{path.stem}" if path.suffix == ".toml" else task
    if margin is not None:
        name += " margin " + "/".join(f"{v:g}" for v in margin)
    return name + (f" N={N}" if N is not None else "") + (f" limit {limit}" if limit is not None else "")


def plan(task: str, plans: pathlib.Path, margin=None, N=None, limit=None) -> pathlib.Path:
    out = plans / label(task, margin, N, limit).replace(" ", "_").replace("/", "-")
    if not (out / "solution.npz").is_file():
        kwargs = jh.load_task_file(task).as_solve_kwargs() if task.endswith(".toml") else {"task": task}
        if limit is not None:
            kwargs["task"] = with_force_limit(kwargs["task"], limit)
        kwargs["settings"] = bench_settings(kwargs.get("settings"))
        if margin is not None:
            kwargs["settings"] = kwargs["settings"].replace(foot_margin=FootMargin(*margin))
        if N is not None:
            kwargs["N"] = N
        sol = jh.solve(**kwargs)
        sol.save(out)
        print(f"{out}: objective {sol.objective:.6g}, {' + '.join(s.status for s in sol.stages)}", flush=True)
    return out


def qp_summary(res) -> dict:
    """The filter's rate, failures and, over the failed trials, where its slack was active."""
    rows = [r["qp_filter"] for r in res.records]
    failed = [q for q in rows if not q["success"]]
    t_fail = sorted(q["t_fail"] for q in failed if q["t_fail"] is not None)
    return {
        "qp_filter_success_rate": res.qp_filter_success_rate,
        "safety_filter": res.safety_filter,
        "qp_filter_median_t_fail_s": t_fail[len(t_fail) // 2] if t_fail else None,
        "qp_filter_goal_reached_rate": sum(q["goal_reached"] for q in rows) / res.trials,
        "qp_filter_failed_after_active_slack": sum(bool(q["filter"]["slack_before_failure"]) for q in failed),
        "qp_filter_failed_at_noise_change": sum(bool(q["filter"]["at_noise_change"]) for q in failed),
        "qp_filter_trials_with_active_slack": sum(q["filter"]["slack_steps"] > 0 for q in rows),
        "qp_filter_max_qp_residual": max(q["filter"]["max_qp_residual"] for q in rows),
    }


def summary(res, wall_s: float, name: str, objective: float) -> dict:
    keys = ("open_loop", "closed_loop") + (("qp_filter",) if res.qp_filter_success_rate is not None else ())
    reasons = {key: dict(collections.Counter(r[key]["reason"] or "success" for r in res.records)) for key in keys}
    first_fail = sorted(r["closed_loop"]["t_fail"] for r in res.records if r["closed_loop"]["t_fail"] is not None)
    return {
        "task": name,
        "plan_objective": objective,
        "trials": res.trials,
        "perturbation": res.perturbation,
        "lqr_weights": res.weights,
        "rejected_draws": res.rejected_draws,
        "open_loop_success_rate": res.open_loop_success_rate,
        "closed_loop_success_rate": res.closed_loop_success_rate,
        "reasons": reasons,
        "closed_loop_goal_reached_rate": sum(r["closed_loop"]["goal_reached"] for r in res.records) / res.trials,
        "closed_loop_median_t_fail_s": first_fail[len(first_fail) // 2] if first_fail else None,
        "wall_s": wall_s,
        "trials_per_s": len(keys) * res.trials / wall_s,
        "timing_s": res.timing_s,
        **(qp_summary(res) if "qp_filter" in keys else {}),
    }


def qp_markdown(rows) -> str:
    """The rows that ran the QP filter: the three policies side by side."""
    lines = [
        "| task | trials | open loop | TVLQR | TVLQR + QP filter | QP filter: first failures "
        "| median time of first failure (s) | failed right after an infeasible QP | failed at a new noise draw "
        "| wall (s) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.get("qp_filter_success_rate") is None:
            continue
        fails = ", ".join(f"{k} {v}" for k, v in sorted(r["reasons"]["qp_filter"].items()) if k != "success")
        t_fail = "-" if r["qp_filter_median_t_fail_s"] is None else f"{r['qp_filter_median_t_fail_s']:.2f}"
        n_failed = r["trials"] - round(r["qp_filter_success_rate"] * r["trials"])
        lines.append(
            f"| {r['task']} | {r['trials']} | {r['open_loop_success_rate']:.0%} | {r['closed_loop_success_rate']:.0%} "
            f"| {r['qp_filter_success_rate']:.0%} | {fails or '-'} | {t_fail} "
            f"| {r['qp_filter_failed_after_active_slack']} of {n_failed} "
            f"| {r.get('qp_filter_failed_at_noise_change', '-')} of {n_failed} | {r['wall_s']:.0f} |"
        )
    return "\n".join(lines) + "\n"


def markdown(rows) -> str:
    lines = [
        "| task | plan objective | trials | open loop success | closed loop success | closed loop: first failures "
        "| median time of first failure (s) | closed loop at the goal at the end | wall (s) | rollouts/s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        fails = ", ".join(f"{k} {v}" for k, v in sorted(r["reasons"]["closed_loop"].items()) if k != "success")
        t_fail = "-" if r["closed_loop_median_t_fail_s"] is None else f"{r['closed_loop_median_t_fail_s']:.2f}"
        objective = f"{r['plan_objective']:.4g}" if "plan_objective" in r else "-"
        lines.append(
            f"| {r['task']} | {objective} | {r['trials']} | {r['open_loop_success_rate']:.0%} | {r['closed_loop_success_rate']:.0%} "
            f"| {fails or '-'} | {t_fail} | {r['closed_loop_goal_reached_rate']:.0%} | {r['wall_s']:.0f} "
            f"| {r['trials_per_s']:.2f} |"
        )
    return "\n".join(lines) + "\n"


COMPONENTS = tuple(f.name for f in dataclasses.fields(Perturbation))


def perturbations(ablation) -> list[tuple[str, Perturbation]]:
    """(row suffix, perturbation) pairs: the default perturbation, or with ``ablation`` (component
    names) the default one and then each named component alone at its default size."""
    if ablation is None:
        return [("", Perturbation())]
    full = Perturbation()
    return [(", all", full)] + [
        (f", {name} only", dataclasses.replace(Perturbation.zero(), **{name: getattr(full, name)}))
        for name in ablation or COMPONENTS
    ]


DEFECT_SUBSTEPS = (1, 10, 40)


def defects(sol) -> dict:
    """Quantiles (50, 90, 99, 100 %) of the per-interval angle defect (rad) at each DEFECT_SUBSTEPS."""
    return {
        str(m): np.quantile(interval_defects(sol, m)[:, 0], [0.5, 0.9, 0.99, 1.0]).tolist() for m in DEFECT_SUBSTEPS
    }


def write_defects(args, rows, out: pathlib.Path) -> None:
    by_task = {r["task"]: r for r in rows}
    for task in args.tasks:
        by_task.setdefault(task, {"task": task})["defects_rad"] = defects(
            jh.Solution.load(plan(task, pathlib.Path(args.plans), args.foot_margin, args.N, args.contact_force_limit))
        )
        print(task, by_task[task]["defects_rad"], flush=True)
    rows = sorted(by_task.values(), key=lambda r: r["task"])
    out.write_text(json.dumps(rows, indent=2) + "\n")
    out.with_name(out.stem + "_defects.md").write_text(defects_markdown(rows))


def defects_markdown(rows) -> str:
    lines = [
        "| task | "
        + " | ".join(f"{m} substep{'s' if m > 1 else ''}: median / 99 % / max" for m in DEFECT_SUBSTEPS)
        + " |",
        "|---|" + "---|" * len(DEFECT_SUBSTEPS),
    ]
    for r in rows:
        if "defects_rad" in r:
            d = r["defects_rad"]
            cells = [f"{d[str(m)][0]:.1e} / {d[str(m)][2]:.2f} / {d[str(m)][3]:.2f}" for m in DEFECT_SUBSTEPS]
            lines.append(f"| {r['task']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="*", default=["T1", "T2", "T3", "T4"])
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--plans", default="out/tracking_plans")
    parser.add_argument("--out", default="docs/tracking.json")
    parser.add_argument(
        "--lqr",
        nargs="+",
        metavar="KEY=VALUE",
        help="TVLQR acceptable deviations, as for jaxhumanoid track (q_rad=0.05 ...; the others LQRWeights')",
    )
    parser.add_argument(
        "--foot-margin",
        nargs=3,
        type=float,
        metavar=("LOAD", "FRICTION", "COP"),
        help="plan with this margin on (5) (model.foot.FootMargin; default the task's own, none)",
    )
    parser.add_argument("--N", type=int, default=None, help="plan intervals (default the task's, 100)")
    parser.add_argument(
        "--contact-force-limit",
        type=force_limit_arg,
        default=None,
        metavar="MG",
        help="plan with this contact-force limit, or 'none' (default the task's own)",
    )
    parser.add_argument(
        "--qp-filter",
        nargs="*",
        type=float,
        default=None,
        metavar="M",
        help="also run TVLQR through the steady-foot QP filter (optionally its margin LOAD FRICTION COP)",
    )
    parser.add_argument(
        "--defects", action="store_true", help="instead: the plans' interval defects against the simulator only"
    )
    parser.add_argument(
        "--ablation",
        nargs="*",
        choices=COMPONENTS,
        default=None,
        metavar="COMPONENT",
        help=f"one row per perturbation component alone (default all of {', '.join(COMPONENTS)})",
    )
    args = parser.parse_args()
    out = pathlib.Path(args.out)
    rows = json.loads(out.read_text()) if out.is_file() else []  # rows of other tasks are kept
    if args.defects:
        write_defects(args, rows, out)
        return
    try:
        weights = with_overrides(LQRWeights(), args.lqr, "--lqr")
    except ValueError as e:
        parser.error(str(e))
    if args.qp_filter is not None and len(args.qp_filter) not in (0, 3):
        parser.error(f"--qp-filter: expected nothing or LOAD FRICTION COP, got {args.qp_filter}")
    safety = None if args.qp_filter is None else SafetyFilter(*args.qp_filter)
    for task in args.tasks:
        src = plan(task, pathlib.Path(args.plans), args.foot_margin, args.N, args.contact_force_limit)
        name = label(task, args.foot_margin, args.N, args.contact_force_limit)
        for suffix, perturbation in perturbations(args.ablation):
            rows = run_row(args, src, name + suffix, perturbation, weights, safety, rows)
            out.write_text(json.dumps(rows, indent=2) + "\n")
            out.with_name(out.stem + "_table.md").write_text(markdown(rows))
            if any(r.get("qp_filter_success_rate") is not None for r in rows):
                out.with_name(out.stem + "_qp_table.md").write_text(qp_markdown(rows))


def run_row(args, src, name: str, perturbation, weights, safety, rows) -> list[dict]:
    """Track the plan in ``src`` under ``perturbation``; ``rows`` with this row (re)placed."""
    t0 = time.perf_counter()
    res = track(
        src,
        trials=args.trials,
        seed=args.seed,
        perturbation=perturbation,
        weights=weights,
        progress=Progress(4 + (safety is not None)),
        safety=safety,
    )
    row = summary(res, time.perf_counter() - t0, name, jh.Solution.load(src).objective)
    print(markdown([row]) + (qp_markdown([row]) if safety is not None else ""), flush=True)
    return sorted([r for r in rows if r["task"] != name] + [row], key=lambda r: r["task"])


if __name__ == "__main__":
    main()
