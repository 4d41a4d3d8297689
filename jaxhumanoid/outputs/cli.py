"""Command line: ``jaxhumanoid solve | table2 | tasks | posture | animate | track | check | sweep | bench``
(also ``python -m jaxhumanoid``).

Exit status: 0 done, 1 failed (a solve that did not converge, or an error raised while working,
``RunFailed``: files written so far stay), 2 bad input, rejected before any work.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import signal
import sys
import time

import numpy as np

from jaxhumanoid.diff import sensitivity_table
from jaxhumanoid.model.foot import FootMargin
from jaxhumanoid.model.params import PlanarChain
from jaxhumanoid.ocp.scaling import SCALINGS
from jaxhumanoid.ocp.scheme import TABLE2_SCHEMES, parse_scheme
from jaxhumanoid.ocp.tasks import NO_FORCE_LIMIT, TASKS, get_task, with_force_limit
from jaxhumanoid.outputs import plots, timeline, tracking_plots
from jaxhumanoid.outputs.animation import animate
from jaxhumanoid.outputs.bench_command import add_bench_parser
from jaxhumanoid.outputs.exits import RunFailed, working
from jaxhumanoid.outputs.flags import parse_pairs, stage1_options_arg
from jaxhumanoid.progress import IterationLine, Progress
from jaxhumanoid.runtime import enable_compilation_cache, writable_dir
from jaxhumanoid.solvers import ipopt_capi
from jaxhumanoid.strategy.posture import find_equilibrium
from jaxhumanoid.strategy.problem import STRATEGY_GUESSES, Problem, problem_from_settings, stage_problem
from jaxhumanoid.strategy.settings import HANDOVERS, SolveSettings
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.strategy.solve import check_arguments, solve
from jaxhumanoid.strategy.taskfile import load_task_file, solve_kwargs, task_files
from jaxhumanoid.studies import ENGINES, sweep
from jaxhumanoid.tracking import montecarlo
from jaxhumanoid.tracking.filter import SafetyFilter
from jaxhumanoid.tracking.lqr import LQRWeights
from jaxhumanoid.validation import checks

# The grid of ``check --sensitivities``: the coarsest tried on which the 1S reference solve converges
# on all four built-in tasks (at N = 15 and 20, T2's and T4's end infeasible).
SENSITIVITY_N = 25

# Table II of the paper: (iterations, seconds) per task and scheme; None = failed.
PAPER_TABLE2: dict[str, dict[str, tuple[str, str] | None]] = {
    "T1": {"E,F,1S": None, "A,F,1S": ("417", "1239"), "A,F+C,1S": ("287", "488"), "A,F+C,2S": ("272+31", "11+40=51")},
    "T2": {"E,F,1S": None, "A,F,1S": ("242", "735"), "A,F+C,1S": ("193", "382"), "A,F+C,2S": ("93+51", "4+81=85")},
    "T3": {
        "E,F,1S": ("331", "691"),
        "A,F,1S": ("208", "742"),
        "A,F+C,1S": ("694", "1262"),
        "A,F+C,2S": ("47+129", "2+210=212"),
    },
    "T4": {
        "E,F,1S": ("311", "520"),
        "A,F,1S": ("340", "1056"),
        "A,F+C,1S": ("360", "696"),
        "A,F+C,2S": ("175+27", "8+37=45"),
    },
}


def with_overrides(default, pairs, flag: str):
    """The dataclass instance ``default`` with the fields named by ``flag key=value`` pairs replaced
    (each value a number; the dataclass checks its range)."""
    opts = parse_pairs(pairs, flag)
    fields = [f.name for f in dataclasses.fields(default)]
    for key, val in opts.items():
        if key not in fields:
            raise ValueError(f"{flag}: unknown key {key!r}; expected one of {', '.join(fields)}")
        if isinstance(val, str):
            raise ValueError(f"{flag}: {key} expects a number, got {val!r}")
    return dataclasses.replace(default, **opts)


def checked_options(args) -> dict:
    """The ``--ipopt-option`` pairs, checked by IPOPT itself for the IPOPT-based solvers before
    any problem is built (the own IPM checks its options when it builds them)."""
    opts = parse_pairs(args.ipopt_option)
    if args.solver in ("ipopt", "casadi"):
        ipopt_capi.check_options(opts)
    return opts


def _write_figures(sol, out: pathlib.Path, with_animation: bool):
    plots.plot_solution(sol, path=out / "solution.png")
    timeline.plot_contact_timeline(sol, path=out / "contacts.png")
    if with_animation:
        animate(sol, out / "animation.gif")


def _save(sol, out: pathlib.Path) -> dict:
    sol.save(out)
    report = json.loads((out / "report.json").read_text())
    report["contacts"] = timeline.contact_summary(sol)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    return report


# ``solve``'s own keywords that ``solve`` flags set, with solve's defaults
SOLVE_DEFAULTS = {"scheme": "A,F+C,2S", "solver": "ipopt", "N": 100, "T": 5.0}
# the ``SolveSettings`` fields that ``solve`` flags set (``--foot-margin`` too)
SETTINGS_FLAGS = ("N1", "guess", "handover", "stage1_solver", "scaling")


def solve_arguments(args) -> dict:
    """The keyword arguments of ``solve`` from the command line: a ``--task-file`` gives the body,
    the laws, the task and its settings; flags given on the command line override the file."""
    base: dict = {"task": args.task or "T1"}
    keywords, settings = dict(SOLVE_DEFAULTS), SolveSettings()
    if args.task_file:
        if args.task:
            raise ValueError("--task, --task-file: give one of them")
        base = load_task_file(args.task_file).as_solve_kwargs()
        keywords.update({k: base.pop(k) for k in list(base) if k in SOLVE_DEFAULTS})
        settings = base.pop("settings")
    keywords.update({k: getattr(args, k) for k in SOLVE_DEFAULTS if getattr(args, k) is not None})
    flags = {k: getattr(args, k) for k in SETTINGS_FLAGS if getattr(args, k, None) is not None}
    if getattr(args, "foot_margin", None) is not None:
        flags["foot_margin"] = FootMargin(*args.foot_margin)
    stage1 = stage1_options_arg(getattr(args, "stage1_option", None))
    if stage1 is not None:
        flags["stage1_options"] = settings.merged_stage1_options(stage1)
    settings = SolveSettings.from_mapping({**_fields(settings), **flags}, "command line")
    if getattr(args, "contact_force_limit", None) is not None:
        base["task"] = with_force_limit(base["task"], args.contact_force_limit)
    return {**base, **keywords, "settings": settings}


def _fields(settings: SolveSettings) -> dict:
    """The fields of ``settings`` by name (the values themselves, not copies)."""
    return {f.name: getattr(settings, f.name) for f in dataclasses.fields(settings)}


def force_limit_arg(text: str) -> float | str:
    """``--contact-force-limit``: MG body weights, or ``none``, which lifts a task's own limit."""
    if text.strip().lower() == NO_FORCE_LIMIT:
        return NO_FORCE_LIMIT
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected body weights (a number) or {NO_FORCE_LIMIT!r}, got {text!r}"
        ) from None


def cmd_solve(args) -> int:
    out = writable_dir(args.out)
    kwargs = solve_arguments(args)
    args.solver = kwargs["solver"]
    options = {**(kwargs.pop("options", None) or {}), **checked_options(args)}
    check_arguments(**kwargs)  # as solve checks them, before any work: status 2
    t0 = time.perf_counter()
    line = IterationLine(quiet=args.quiet or args.verbose)
    line.status("setting up the problems and compiling them (cached for later runs)")
    try:
        with working():
            sol = solve(**kwargs, options=options or None, verbose=args.verbose, progress=line)
    finally:
        line.close()
    report = _save(sol, out)
    _write_figures(sol, out, args.animate)
    if not args.quiet:
        its = "+".join(str(i) for i in report["iterations"])
        times = "+".join(f"{t:.2f}" for t in report["solve_time_s"])
        print(
            f"{report['task']} {report['scheme']} {report['solver']}: {' + '.join(report['stage_status'])} "
            f"iterations {its}, solve {times} s (compile {report['compile_time_s']:.1f} s), "
            f"objective {report['objective']:.6g}, max violation {report['max_constraint_violation']:.1e}, "
            f"wall {time.perf_counter() - t0:.1f} s -> {out}"
        )
    return 0 if sol.success else 1


def _table2_markdown(records) -> str:
    lines = [
        "| task | scheme | ours: status | ours: iterations | ours: solve time (s) "
        "| paper: iterations | paper: time (s) |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in records:
        paper = PAPER_TABLE2.get(r["task"], {}).get(r["scheme"])
        p_it, p_t = paper if paper else ("failed", "failed")
        its = "+".join(str(i) for i in r["iterations"])
        times = "+".join(f"{t:.2f}" for t in r["solve_time_s"])
        status = " + ".join(r.get("stage_status", [r["status"]]))
        lines.append(f"| {r['task']} | {r['scheme']} | {status} | {its} | {times} | {p_it} | {p_t} |")
    return "\n".join(lines) + "\n"


def cmd_table2(args) -> int:
    out = writable_dir(args.out)
    options = checked_options(args)
    tasks = args.tasks or ["T1", "T2", "T3", "T4"]
    schemes = args.schemes or list(TABLE2_SCHEMES)
    cells = [(t, s) for t in tasks for s in schemes]
    progress = Progress(len(cells), quiet=args.quiet)
    # a task file brings its own body, law, weights and settings; the table's scheme, solver and N
    # replace the file's
    given = {t: solve_kwargs(t) for t in tasks}
    for task, scheme in cells:
        check_arguments(**{**given[task], "scheme": scheme, "solver": args.solver, "N": args.N})
    with working():
        _table2_cells(args, out=out, given=given, cells=cells, options=options, progress=progress)
    if not args.quiet:
        print(_table2_markdown(json.loads((out / "table2.json").read_text())))
    return 0


def _table2_cells(args, *, out: pathlib.Path, given: dict, cells: list, options: dict, progress: Progress) -> None:
    """Solve every cell, table2.json rewritten after each (a failure keeps the cells before it)."""
    records: list[dict] = []
    for task, scheme in progress.iter(cells, label=lambda c: f"{c[0]} {c[1]}"):
        kw = given[task]
        merged = {**(kw.get("options") or {}), **options} or None
        sol = solve(**{**kw, "scheme": scheme, "solver": args.solver, "N": args.N, "options": merged})
        name = task if isinstance(kw["task"], str) else kw["task"].name
        cell_dir = out / f"{name}_{scheme.replace(',', '_').replace('+', 'p')}"
        rec = _save(sol, cell_dir)
        records.append(rec)
        progress.note(
            f"{' + '.join(rec['stage_status'])}, iterations {'+'.join(map(str, rec['iterations']))}, "
            f"solve {'+'.join(f'{t:.1f}' for t in rec['solve_time_s'])} s"
        )
        (out / "table2.json").write_text(json.dumps(records, indent=2) + "\n")
    (out / "table2.md").write_text(_table2_markdown(records))


def cmd_tasks(args) -> int:
    print(f"{'task':<32} {'links':>5}  {'active':<10} source")
    for key, task in TASKS.items():
        print(f"{key + ' ' + task.name:<32} {task.n:>5}  {str(list(task.active)):<10} built in")
    for path in task_files(args.dir):
        tf = load_task_file(path)
        print(f"{tf.task.name:<32} {tf.model.n:>5}  {str(list(tf.task.active)):<10} {path}")
    return 0


def _posture_row(name: str, eq) -> dict:
    m = eq.nominal
    print(
        f"{name}: q = {np.round(eq.q, 4).tolist()} rad (moved {eq.moved:.2e}), foot load {m.load:.2f} M g, "
        f"friction use {m.friction:.2f}, centre of pressure {m.cop:+.3f} m, torques {np.round(m.u, 1).tolist()} N m, "
        f"relaxed law ok: {eq.relaxed.ok}"
    )
    return {
        "q": eq.q.tolist(),
        "moved": eq.moved,
        "u": m.u.tolist(),
        "foot_reaction": m.foot_reaction.tolist(),
        "load": m.load,
        "friction": m.friction,
        "cop": m.cop,
        "q_relaxed": eq.q_relaxed.tolist(),
        "relaxed_ok": eq.relaxed.ok,
    }


def cmd_posture(args) -> int:
    if args.task and args.task_file:
        raise ValueError("--task, --task-file: give one of them")
    if args.task_file:
        tf = load_task_file(args.task_file)
        task, model, contact, foot = tf.task, tf.model, tf.contact, tf.foot
    else:
        task, model, contact, foot = get_task(args.task or "T1"), PlanarChain.humanoid(), None, None
    q_min, q_max = task.joint_ranges(model)
    rows = {}
    for name, q in (("start", task.start), ("goal", task.goal)):
        with working():
            eq = find_equilibrium(model, q, task.active, contact=contact, foot=foot, q_min=q_min, q_max=q_max)
        rows[name] = _posture_row(name, eq)
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps(rows, indent=2) + "\n")
    return 0


def cmd_animate(args) -> int:
    src = pathlib.Path(args.dir)
    if not (src / "solution.npz").is_file():
        what = "has no solution.npz" if src.is_dir() else "is not a directory"
        raise ValueError(f"dir: {str(src)!r} {what}; give a directory written by `jaxhumanoid solve`")
    sol = Solution.load(args.dir)
    with working():
        path = animate(sol, pathlib.Path(args.dir) / args.name)
    if not args.quiet:
        print(f"wrote {path}")
    return 0


def cmd_track(args) -> int:
    perturbation = with_overrides(montecarlo.Perturbation(), args.perturb, "--perturb")
    weights = with_overrides(LQRWeights(), args.lqr, "--lqr")
    sol = montecarlo.as_solution(args.dir)
    out = writable_dir(args.out or args.dir)
    safety = SafetyFilter() if args.controller == "qp" else None
    progress = Progress(4 + (safety is not None) + (0 if args.no_figures else 1), quiet=args.quiet)
    with working():
        res = _track(args, sol, out=out, perturbation=perturbation, weights=weights, safety=safety, progress=progress)
    if not args.quiet:
        print(
            f"{res.task}: {res.trials} trials, success open loop {res.open_loop_success_rate:.0%}, "
            f"closed loop (TVLQR) {res.closed_loop_success_rate:.0%}"
            + ("" if res.qp_filter_success_rate is None else f", TVLQR + QP filter {res.qp_filter_success_rate:.0%}")
            + f" -> {out / 'tracking.json'}"
        )
    return 0


def _track(args, sol, *, out: pathlib.Path, perturbation, weights, safety, progress: Progress):
    """The Monte-Carlo trials of ``track``, saved, and their figures."""
    res = montecarlo.track(
        sol,
        trials=args.trials,
        seed=args.seed,
        substeps=args.substeps,
        perturbation=perturbation,
        weights=weights,
        progress=progress,
        safety=safety,
    )
    res.save(out)
    if not args.no_figures:
        progress.start("figure and animation")
        tracking_plots.plot_tracking(res, sol, path=out / "tracking.png")
        tracking_plots.animate_trial(res, sol, out / "tracking.gif")
        progress.finish()
    return res


def _file_problems(files: list, scheme: str, N: int) -> list[Problem]:
    """The problems of loaded task files on ``scheme`` and ``N`` intervals."""
    return [problem_from_settings(tf.as_solve_kwargs(), scheme, N) for tf in files]


def cmd_check(args) -> int:
    if args.task_file and not args.sensitivities:
        raise ValueError("--task-file: only with --sensitivities")
    if args.task and args.task_file:
        raise ValueError("--task, --task-file: give one of them")
    tasks: list = [args.task] if args.task else ["T1", "T2", "T3", "T4"]
    for task in tasks:
        get_task(task)
    for scheme in [args.scheme] if args.scheme else []:
        parse_scheme(f"{scheme},1S")
    if args.N is not None and args.N < 3:
        raise ValueError(f"--N: expected an integer number of intervals >= 3, got {args.N}")
    if args.sensitivities:
        scheme = f"{args.scheme or 'A,F+C'},1S"
        N = args.N or SENSITIVITY_N
        files = [load_task_file(path) for path in args.task_file or []]
        with working():
            tasks = _file_problems(files, scheme, N) if files else tasks
            rows, outs = sensitivity_table(tasks, scheme, N=N, eps=args.eps)
        results = {"rows": rows, "results": outs}
    else:
        schemes = [args.scheme] if args.scheme else ["E,F", "A,F", "A,F+C"]
        cases = [(t, f"{s},1S", False) for t in tasks for s in schemes]
        cases += [(t, "A,F+C,2S", True) for t in tasks]  # the pseudo-static stage-1 problem
        N = args.N or 8
        problems = ((checks.case_label(t, s, ps, N), stage_problem(t, s, N, ps)) for t, s, ps in cases)
        with working():
            rows = checks.check_table(problems, points=args.points)
        results = {"rows": rows}
    print(checks.format_table(rows))
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps(results, indent=2, default=float) + "\n")
    failed = [r for r in rows if not r["ok"]]
    print(f"{len(rows) - len(failed)} passed, {len(failed)} failed")
    return 0 if not failed else 1


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def cmd_sweep(args) -> int:
    """Exit 0 when every case of the spec has a row (failed cases included: they are results),
    1 when some are pending, 130 when interrupted by Ctrl-C or SIGTERM (the running cases stop with
    it, the finished rows are kept: re-run to resume)."""
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        summary = sweep(
            args.spec,
            args.out,
            engine=args.engine,
            workers=args.workers,
            address=args.address,
            retry_failed=args.retry_failed,
            quiet=args.quiet,
            cache=not args.no_cache,
            solvers=args.solvers,
            draws=args.draws,
        )
    except KeyboardInterrupt:
        print(f"jaxhumanoid: interrupted; the same command resumes the study in {args.out}", file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0 if summary["n_pending"] == 0 else 1


def _common(p, grid: bool = True) -> None:
    """The options that several subcommands share."""
    if grid:
        p.add_argument("--N", type=int, default=100, help="number of intervals of the (final) grid (default 100)")
        p.add_argument("--solver", default="ipopt", choices=["ipopt", "ipm", "casadi"])
    p.add_argument("--ipopt-option", action="append", metavar="KEY=VALUE", help="IPOPT option, repeatable")
    p.add_argument("--quiet", action="store_true")


def _add_solve_parser(sub) -> None:
    p = sub.add_parser("solve", help="solve one task with one strategy")
    p.add_argument(
        "--task",
        default=None,
        help="T1..T4 or prone-to-stand, stand-to-prone, supine-to-stand, stand-to-supine (default T1)",
    )
    p.add_argument(
        "--task-file",
        default=None,
        help="a TOML file with a body, a task and its settings (examples/*.toml); flags given here override the file",
    )
    p.add_argument("--scheme", default=None, help="e.g. A,F+C,2S (default) | A,F+C,1S | A,F,1S | E,F,1S")
    p.add_argument("--T", type=float, default=None, help="horizon in seconds (default 5)")
    p.add_argument("--N1", type=int, default=None, help="intervals of stage 1 of 2S (default min(30, N))")
    p.add_argument("--N", type=int, default=None, help="number of intervals of the (final) grid (default 100)")
    p.add_argument("--solver", default=None, choices=["ipopt", "ipm", "casadi"], help="default ipopt")
    p.add_argument(
        "--guess",
        default=None,
        choices=list(STRATEGY_GUESSES),
        help="initial guess: auto (default; 2S: stage 1 from static_path, and from inverse_dynamics as well where "
        "that run kept the path's detour, the lower objective handed over; 1S: inverse_dynamics), inverse_dynamics "
        "(torques and forces that satisfy its dynamics), linear, static_path (postures the body can hold at rest, "
        "where a path of them is found), or both (2S: stage 1 from inverse_dynamics and from static_path)",
    )
    p.add_argument(
        "--handover",
        default=None,
        choices=list(HANDOVERS),
        help="2S from stage 1 to stage 2: continuation in the contact law (default) or direct (the paper's)",
    )
    p.add_argument(
        "--stage1-solver",
        default=None,
        choices=["ipopt", "ipm", "casadi", "same"],
        help="the solver of 2S's relaxed-law stages (default ipopt); same: --solver",
    )
    p.add_argument(
        "--stage1-option",
        action="append",
        metavar="KEY=VALUE",
        help="IPOPT option of stage 1 of 2S only, on top of --ipopt-option and a task file's; repeatable",
    )
    p.add_argument(
        "--scaling",
        default=None,
        choices=list(SCALINGS),
        help="none (default): the NLPs as posed; physical: in units of O(1) (torques in 10 N m, forces in 100 N)",
    )
    p.add_argument(
        "--foot-margin",
        nargs=3,
        type=float,
        default=None,
        metavar=("LOAD", "FRICTION", "COP"),
        help="keep the foot inside (5): a load (body weights), a fraction of the friction cone unused, the "
        "centre of pressure COP m from toe and heel (default 0 0 0; overrides a task file's [foot_margin])",
    )
    p.add_argument(
        "--contact-force-limit",
        type=force_limit_arg,
        default=None,
        metavar="MG",
        help="cap every body contact's normal force at MG body weights, or 'none' for no cap (overrides "
        "the task's own limit: T3's 2, a task file's [task] contact_force_limit)",
    )
    p.add_argument("--out", default="out/solve")
    p.add_argument("--animate", action="store_true", help="also write animation.gif")
    p.add_argument("--verbose", action="store_true", help="print IPOPT's iteration log")
    _common(p, grid=False)
    p.set_defaults(func=cmd_solve)


def _add_check_parser(sub) -> None:
    p = sub.add_parser("check", help="cross-validate JAX against CasADi and finite differences")
    p.add_argument("--task", default=None, help="one task (default: all four)")
    p.add_argument(
        "--scheme",
        default=None,
        help="E,F | A,F | A,F+C (default: all three, plus the pseudo-static stage 1; A,F+C with --sensitivities)",
    )
    p.add_argument(
        "--N", type=int, default=None, help=f"grid intervals (default 8; {SENSITIVITY_N} with --sensitivities)"
    )
    p.add_argument("--points", type=int, default=2, help="random points per case")
    p.add_argument(
        "--sensitivities",
        action="store_true",
        help="instead: KKT sensitivities of the optimal trajectory against finite differences of re-solves "
        "(1S, every parameter group)",
    )
    p.add_argument("--eps", type=float, default=1e-5, help="finite-difference step of --sensitivities (relative)")
    p.add_argument(
        "--task-file", nargs="+", default=None, help="with --sensitivities: task files instead of the built-in tasks"
    )
    p.add_argument(
        "--out", default=None, help="also write the rows (with --sensitivities: and the full results) as JSON"
    )
    p.set_defaults(func=cmd_check)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxhumanoid", description="Two-stage trajectory optimisation of a planar humanoid (JAX)."
    )
    parser.add_argument("--no-cache", action="store_true", help="do not use the persistent JAX compilation cache")
    sub = parser.add_subparsers(dest="command", required=True)

    _add_solve_parser(sub)

    p = sub.add_parser("tasks", help="list the built-in tasks and the task files of a folder")
    p.add_argument("--dir", default="examples", help="folder of task files (default examples)")
    p.set_defaults(func=cmd_tasks)

    p = sub.add_parser("posture", help="the static equilibrium nearest to a task's start (and goal) posture")
    p.add_argument("--task", default=None, help="T1..T4 (default T1)")
    p.add_argument("--task-file", default=None, help="a TOML task file")
    p.add_argument("--out", default=None, help="also write the postures and margins as JSON")
    p.set_defaults(func=cmd_posture)

    p = sub.add_parser("table2", help="run the 16 cells of the paper's Table II")
    p.add_argument("--out", default="out/table2")
    p.add_argument("--tasks", nargs="*", help="T1..T4 (default all) or task files, e.g. examples/paper/T1.toml")
    p.add_argument("--schemes", nargs="*")
    _common(p)
    p.set_defaults(func=cmd_table2)

    p = sub.add_parser("animate", help="write an animation of a saved solution")
    p.add_argument("dir", help="directory written by `jaxhumanoid solve`")
    p.add_argument("--name", default="animation.gif")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_animate)

    p = sub.add_parser("track", help="execute a saved plan in simulation: open loop and TVLQR over perturbed trials")
    p.add_argument("dir", help="directory written by `jaxhumanoid solve`")
    p.add_argument("--trials", type=int, default=100, help="perturbed trials (default 100; trial 0 is unperturbed)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--substeps", type=int, default=10, help="simulator steps per plan interval (default 10)")
    p.add_argument(
        "--controller",
        choices=("tvlqr", "qp"),
        default="tvlqr",
        help="tvlqr: open loop and TVLQR (default); qp: also TVLQR through the steady-foot QP filter",
    )
    p.add_argument(
        "--perturb",
        nargs="+",
        metavar="KEY=VALUE",
        help="half-widths of the trials' draws, the others as default: mass, length, contact, friction (fractions), "
        "start_rad (rad), torque_noise_Nm (N m); e.g. --perturb length=0 torque_noise_Nm=0",
    )
    p.add_argument(
        "--lqr",
        nargs="+",
        metavar="KEY=VALUE",
        help="TVLQR's acceptable deviations, the others as default: q_rad, qd_rad_s, u_Nm, foot_N, terminal_s",
    )
    p.add_argument("--out", default=None, help="where tracking.json, .png and .gif go (default DIR)")
    p.add_argument("--no-figures", action="store_true", help="write tracking.json only")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_track)

    _add_check_parser(sub)

    add_bench_parser(sub)

    p = sub.add_parser("sweep", help="run a study: every case of a TOML spec, on worker processes or a cluster")
    p.add_argument("spec", help="the study's TOML file (examples/sweep_small.toml; format in studies/spec.py)")
    p.add_argument("--out", required=True, help="folder of cases.csv, summary.json and cases/<id>/; re-runs resume")
    p.add_argument("--engine", default="local", choices=ENGINES, help="local: spawned processes (default); dask")
    p.add_argument("--address", default=None, help="a running Dask scheduler (default: start a local cluster)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (local pool or local cluster)")
    p.add_argument("--retry-failed", action="store_true", help="also re-run the cases that failed or crashed")
    p.add_argument("--solvers", nargs="+", default=None, help="run only these of the spec's solvers")
    p.add_argument("--draws", type=int, default=None, help="run only the first K random draws per task")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_sweep)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if not args.no_cache:
        enable_compilation_cache()
    try:
        return int(args.func(args) or 0)
    except ValueError as err:
        print(f"jaxhumanoid: error: {err}", file=sys.stderr)
        return 2
    except RunFailed as err:
        print(f"jaxhumanoid: failed: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
