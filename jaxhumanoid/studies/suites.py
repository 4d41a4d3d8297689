"""The suites of ``jaxhumanoid bench`` (``SUITES``; the runner is ``studies.runner``).

- ``reference``: each ``T*.toml`` of the reference-posing folder solved by each backend, beside
  that folder's README figures (an independent implementation's iterations, times and optima);
- ``reference-draws``: the same files over perturbed cost weights, per backend: draws solved,
  draws at the best optimum found, and the distribution of the iterations;
- ``table2``: A,F+C,2S against A,F+C,1S on the tasks, with IPOPT and the IPM, and 2S's time
  over 1S's;
- ``agreement``: A,F+C,2S by every backend from the one stage-1 point (stage 1 runs on IPOPT
  whatever the backend, ``solve``'s default): the spread of the optima and of the joint angles;
- ``robustness``: the robustness study (``jaxhumanoid sweep``, its first ``--draws`` per task):
  success, agreement of the backends and iterations per task;
- ``iteration``, ``compile``: the maintained scripts that time an iteration's parts and a cold
  start (``scripts/bench_iteration.py``), run as they are, their JSON records embedded.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.strategy.taskfile import solve_kwargs
from jaxhumanoid.studies.bench import REPO
from jaxhumanoid.studies.compare import Outcome, agreement
from jaxhumanoid.studies.runner import BenchSettings, Case, Measurement, Suite, fmt_time, spread
from jaxhumanoid.studies.spec import Case as StudyCase
from jaxhumanoid.studies.spec import Spec, load_spec
from jaxhumanoid.studies.sweep import select_cases, sweep

SCHEME_2S, SCHEME_1S = "A,F+C,2S", "A,F+C,1S"


# ------------------------------------------------------------------------------- one solve
def measured_solve(kwargs: Mapping[str, Any]) -> tuple[Measurement, Solution]:
    """``solve(**kwargs)`` once: status, per-stage iterations and objective as values; per-stage
    and total solve time and the last stage's time per iteration (ms) as times."""
    sol = solve(**kwargs)
    rep = sol.report()
    its, secs = rep["iterations"], rep["solve_time_s"]
    times = {f"stage{i + 1}_s": float(t) for i, t in enumerate(secs)}
    times["solve_s"] = float(sum(secs))
    times["last_stage_ms_per_iteration"] = 1e3 * float(secs[-1]) / max(int(its[-1]), 1)
    values = {
        "status": rep["status"],
        "success": rep["success"],
        "stage_status": rep["stage_status"],
        "iterations": its,
        "objective": rep["objective"],
    }
    return Measurement(values, times), sol


def _solve_case(name: str, kwargs: Mapping[str, Any]) -> Case:
    return Case(name, lambda: measured_solve(kwargs)[0])


def _grid(settings: BenchSettings) -> dict[str, int]:
    return {} if settings.N is None else {"N": settings.N}


def _builtin(settings: BenchSettings) -> dict[str, Any]:
    """``solve``'s keywords of a built-in task's solve: the run's grid, initial guess and stage-1
    options."""
    if settings.guess is None and settings.stage1_options is None:
        return _grid(settings)
    strategy = SolveSettings(stage1_options=settings.stage1_options)
    return _grid(settings) | {"settings": strategy.replace(guess=settings.guess or strategy.guess)}


def _its(values: Mapping[str, Any]) -> str:
    return "+".join(str(i) for i in values["iterations"])


def _status(values: Mapping[str, Any]) -> str:
    return "ok" if values["success"] else f"**{values['status']}**"


# ------------------------------------------------------------------------------- reference
_NUM = r"\s*([\d.]+)\s*"
_ROW = re.compile(rf"^\|\s*(T\d)\s*\|\s*(\d+)\s*\|\s*(\d+)\s*\|{_NUM}\+{_NUM}={_NUM}\|{_NUM}\|{_NUM}ms")


def reference_figures(text: str) -> dict[str, dict[str, Any]]:
    """The reference implementation's A,F+C,2S figures from its README's table (columns: task,
    stage 1 and stage 2 iterations, solve time "s1 + s2 = total", objective, stage-2 ms per
    iteration); tasks whose row does not parse are left out."""
    out = {}
    for line in text.splitlines():
        m = _ROW.match(line.strip())
        if m:
            task, i1, i2, t1, t2, tt, obj, ms = m.groups()
            out[task] = {
                "iterations": [int(i1), int(i2)],
                "solve_s": [float(t1), float(t2)],
                "solve_total_s": float(tt),
                "objective": float(obj),
                "stage2_ms_per_iteration": float(ms),
            }
    return out


def _reference_files(settings: BenchSettings) -> list[pathlib.Path]:
    folder = pathlib.Path(settings.reference_dir)
    files = sorted(folder.glob("T*.toml"))
    if not files:
        raise ValueError(f"--reference-dir: no T*.toml in {str(folder)!r}")
    wanted = [f for f in files if f.stem in settings.tasks]
    if not wanted:
        have = [f.stem for f in files]
        raise ValueError(f"--tasks: none of {list(settings.tasks)} in {str(folder)!r} (it has {have})")
    return wanted


def _reference_kwargs(path: pathlib.Path, backend: str, settings: BenchSettings) -> dict[str, Any]:
    """``solve``'s keywords of a task file on ``backend``: the file's, with the run's grid, and
    the run's initial guess and stage-1 options in place of the file's where the run sets them."""
    kwargs = {**solve_kwargs(str(path)), "solver": backend, **_grid(settings)}
    strategy: SolveSettings = kwargs.get("settings") or SolveSettings()
    if settings.guess is not None:
        strategy = strategy.replace(guess=settings.guess)
    if settings.stage1_options is not None:
        strategy = strategy.replace(stage1_options=strategy.merged_stage1_options(settings.stage1_options))
    return kwargs | {"settings": strategy}


def reference_cases(settings: BenchSettings) -> list[Case]:
    files = _reference_files(settings)
    return [_solve_case(f"{f.stem} {b}", _reference_kwargs(f, b, settings)) for f in files for b in settings.backends]


def _readme_figures(settings: BenchSettings) -> tuple[pathlib.Path, dict[str, dict[str, Any]]]:
    """The reference folder's README and its figures (none where it has no README)."""
    readme = pathlib.Path(settings.reference_dir) / "README.md"
    return readme, reference_figures(readme.read_text()) if readme.is_file() else {}


def reference_summary(cases: list[dict[str, Any]], settings: BenchSettings) -> dict[str, Any]:
    readme, figures = _readme_figures(settings)
    ratios = {}
    for c in cases:
        ref = figures.get(c["case"].split()[0])
        if ref:
            ratios[c["case"]] = {
                "solve_time_over_reference": c["times"]["solve_s"]["median"] / ref["solve_total_s"],
                "last_stage_ms_per_iteration_over_reference": c["times"]["last_stage_ms_per_iteration"]["median"]
                / ref["stage2_ms_per_iteration"],
                "objective_rel_diff": abs(c["objective"] - ref["objective"]) / abs(ref["objective"]),
            }
    return {"reference": figures, "source": str(readme), "ratios": ratios}


def reference_table(rec: Mapping[str, Any]) -> str:
    figures = rec.get("summary", {}).get("reference", {})
    lines = [
        "| task | backend | status | iterations | solve s (sum of stages) | objective | last stage ms / iteration "
        "| reference: iterations | solve s | objective | ms / iteration |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in rec["cases"]:
        task, backend = c["case"].split()
        ref = figures.get(task)
        ref_cells = (
            f"{'+'.join(map(str, ref['iterations']))} | {ref['solve_total_s']:.1f} | {ref['objective']:.6g} "
            f"| {ref['stage2_ms_per_iteration']:.1f}"
            if ref
            else "- | - | - | -"
        )
        lines.append(
            f"| {task} | {backend} | {_status(c)} | {_its(c)} | {fmt_time(c['times']['solve_s'])} | "
            f"{c['objective']:.6g} | {fmt_time(c['times']['last_stage_ms_per_iteration'], 1)} | {ref_cells} |"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------------- reference draws
# The reference-posing problems are chaotic: a rounding-level change moves their iterations and
# optima. Draw 0 is each file as posed; draw d >= 1 multiplies each cost weight of (7) by
# 1 + REFERENCE_DRAW_SIGMA * z, z standard normal of seed d (the same draws for every backend).
REFERENCE_DRAW_SIGMA = 0.01
DEFAULT_REFERENCE_DRAWS = 6
# An optimum within this relative distance of the best one found for a draw counts as reached.
SAME_OPTIMUM_RTOL = 5e-3


def reference_draw_weights(kwargs: Mapping[str, Any], draw: int) -> np.ndarray | None:
    """The cost weights of ``draw`` for a task file's ``solve`` keywords (None for draw 0: the
    file's own)."""
    if draw == 0:
        return None
    task = kwargs["task"]
    w = task.weights.as_array(kwargs["model"].n if kwargs.get("model") is not None else task.n)
    return w * (1.0 + REFERENCE_DRAW_SIGMA * np.random.default_rng(draw).standard_normal(w.shape))


def _reference_draws_run(path: pathlib.Path, backend: str, settings: BenchSettings) -> Measurement:
    kwargs = _reference_kwargs(path, backend, settings)
    runs, total = [], 0.0
    for d in range(settings.draws or DEFAULT_REFERENCE_DRAWS):
        m, _ = measured_solve({**kwargs, "weights": reference_draw_weights(kwargs, d)})
        runs.append({k: m.values[k] for k in ("status", "success", "iterations", "objective")})
        total += m.times["solve_s"]
    return Measurement({"draws": runs}, {"solve_s": total})


def reference_draws_cases(settings: BenchSettings) -> list[Case]:
    def case(f: pathlib.Path, b: str) -> Case:
        return Case(f"{f.stem} {b}", lambda: _reference_draws_run(f, b, settings))

    return [case(f, b) for f in _reference_files(settings) for b in settings.backends]


def reference_draws_summary(cases: list[dict[str, Any]], settings: BenchSettings) -> dict[str, Any]:
    """Per task file and backend: draws solved, draws at the best optimum any backend found for
    the draw (within ``SAME_OPTIMUM_RTOL``), median and largest total iterations; and the
    independent implementation's figures for draw 0."""
    _, figures = _readme_figures(settings)
    best: dict[tuple[str, int], float] = {}
    for c in cases:
        task = c["case"].split()[0]
        for d, r in enumerate(c["draws"]):
            if r["success"]:
                best[task, d] = min(best.get((task, d), np.inf), r["objective"])
    out = {}
    for c in cases:
        task = c["case"].split()[0]
        draws = c["draws"]
        totals = [sum(r["iterations"]) for r in draws]
        at_best = [
            bool(r["success"] and r["objective"] <= best[task, d] + SAME_OPTIMUM_RTOL * abs(best[task, d]))
            for d, r in enumerate(draws)
        ]
        ref = figures.get(task)
        out[c["case"]] = {
            "draws": len(draws),
            "solved": sum(bool(r["success"]) for r in draws),
            "at_best": sum(at_best),
            "median_iterations": float(np.median(totals)),
            "max_iterations": int(max(totals)),
            "draw0_iterations": totals[0],
            "draw0_objective": draws[0]["objective"],
            "reference_iterations": sum(ref["iterations"]) if ref else None,
            "reference_objective": ref["objective"] if ref else None,
        }
    return {"sigma": REFERENCE_DRAW_SIGMA, "rtol": SAME_OPTIMUM_RTOL, "per_case": out}


def reference_draws_table(rec: Mapping[str, Any]) -> str:
    s = rec["summary"]
    lines = [
        f"Draw 0 as posed; draws 1.. with each weight times 1 + {s['sigma']:g} z. At the best optimum: "
        f"within {s['rtol']:g} of the lowest objective any backend reached on the draw.",
        "",
        "| task | backend | solved | at the best optimum | total iterations: median (max) "
        "| draw 0: iterations, objective | reference: iterations, objective |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, r in s["per_case"].items():
        task, backend = key.split()
        ref = (
            f"{r['reference_iterations']}, {r['reference_objective']:.6g}"
            if r["reference_iterations"] is not None
            else "-"
        )
        lines.append(
            f"| {task} | {backend} | {r['solved']} of {r['draws']} | {r['at_best']} of {r['draws']} "
            f"| {r['median_iterations']:g} ({r['max_iterations']}) | {r['draw0_iterations']}, "
            f"{r['draw0_objective']:.6g} | {ref} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------------------- table2
def _table2_backends(settings: BenchSettings) -> list[str]:
    return [b for b in settings.backends if b != "casadi"] or list(settings.backends)


def table2_cases(settings: BenchSettings) -> list[Case]:
    return [
        _solve_case(f"{t} {s} {b}", {"task": t, "scheme": s, "solver": b, **_builtin(settings)})
        for t in settings.tasks
        for b in _table2_backends(settings)
        for s in (SCHEME_2S, SCHEME_1S)
    ]


def table2_summary(cases: list[dict[str, Any]], settings: BenchSettings) -> dict[str, Any]:
    by = {c["case"]: c for c in cases}
    out = {}
    for t in settings.tasks:
        for b in _table2_backends(settings):
            two, one = by[f"{t} {SCHEME_2S} {b}"], by[f"{t} {SCHEME_1S} {b}"]
            out[f"{t} {b}"] = {
                "time_2S_over_1S": two["times"]["solve_s"]["median"] / one["times"]["solve_s"]["median"],
                "both_succeeded": bool(two["success"] and one["success"]),
            }
    return {"ratios": out}


def table2_table(rec: Mapping[str, Any]) -> str:
    by = {c["case"]: c for c in rec["cases"]}
    lines = [
        "| task | solver | 2S: status | iterations | solve s | objective "
        "| 1S: status | iterations | solve s | objective | 2S / 1S time |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, ratio in rec["summary"]["ratios"].items():
        t, b = key.split()
        cells = []
        for s in (SCHEME_2S, SCHEME_1S):
            c = by[f"{t} {s} {b}"]
            cells.append(f"{_status(c)} | {_its(c)} | {fmt_time(c['times']['solve_s'])} | {c['objective']:.6g}")
        lines.append(f"| {t} | {b} | {' | '.join(cells)} | {ratio['time_2S_over_1S']:.2f} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------- agreement
def _agreement_run(task: str, settings: BenchSettings) -> Measurement:
    values: dict[str, Any] = {}
    times: dict[str, float] = {}
    outcomes = {}
    for b in settings.backends:
        m, sol = measured_solve({"task": task, "scheme": SCHEME_2S, "solver": b, **_builtin(settings)})
        values[b] = {k: m.values[k] for k in ("status", "success", "iterations", "objective")}
        times[f"{b}_solve_s"] = m.times["solve_s"]
        outcomes[b] = Outcome(bool(sol.success), float(sol.objective), np.asarray(sol.q))
    objs = np.array([o.objective for o in outcomes.values()])
    qs = [np.asarray(o.q) for o in outcomes.values()]
    values["objective_spread"] = float((objs.max() - objs.min()) / max(np.abs(objs).max(), 1e-300))
    values["max_dq_rad"] = float(max((np.max(np.abs(a - b)) for a in qs for b in qs), default=0.0))
    values["same_optimum"] = agreement(outcomes)["agrees"]
    return Measurement(values, times)


def agreement_cases(settings: BenchSettings) -> list[Case]:
    def case(task: str) -> Case:
        return Case(task, lambda: _agreement_run(task, settings))

    return [case(t) for t in settings.tasks]


def agreement_table(rec: Mapping[str, Any]) -> str:
    backends = [k[: -len("_solve_s")] for k in rec["cases"][0]["times"]] if rec["cases"] else []
    head = " | ".join(f"{b}: iterations, solve s, objective" for b in backends)
    lines = [
        f"| task | {head} | objective spread | max joint-angle difference (rad) | same optimum |",
        "|---|" + "---|" * (len(backends) + 3),
    ]
    for c in rec["cases"]:
        cells = [
            f"{_its(c[b])}, {fmt_time(c['times'][f'{b}_solve_s'])}, {c[b]['objective']:.6g}"
            + ("" if c[b]["success"] else f" **{c[b]['status']}**")
            for b in backends
        ]
        lines.append(
            f"| {c['case']} | {' | '.join(cells)} | {c['objective_spread']:.1e} | {c['max_dq_rad']:.1e} "
            f"| {'yes' if c['same_optimum'] else 'no'} |"
        )
    return "\n".join(lines)


# ------------------------------------------------------------------------------ robustness
def robustness_cases(settings: BenchSettings) -> list[Case]:
    spec = robustness_spec(settings)  # a missing or bad spec is bad input, reported before any work
    return [Case("sweep", lambda: _robustness_run(spec, settings))]


def robustness_spec(settings: BenchSettings) -> Spec:
    """The study's cases on the run's tasks, backends and first ``draws`` draws, with the run's
    ``guess`` where it sets one and its ``stage1_options`` added to the spec's."""
    spec = select_cases(load_spec(settings.spec), list(settings.backends), settings.draws)
    changes: dict[str, Any] = {} if settings.guess is None else {"guess": settings.guess}
    cases = tuple(
        dataclasses.replace(c, **changes, **_stage1_options(c, settings.stage1_options))
        for c in spec.cases
        if c.task in settings.tasks
    )
    if not cases:
        raise ValueError(f"--tasks: none of {list(settings.tasks)} in the study {settings.spec!r}")
    return dataclasses.replace(spec, cases=cases)


def _stage1_options(case: StudyCase, options: Mapping[str, Any] | None) -> dict[str, Any]:
    """``dataclasses.replace``'s keywords that add ``options`` to the case's stage-1 options."""
    if not options:
        return {}
    return {"stage1_options": tuple(sorted({**dict(case.stage1_options), **options}.items()))}


def _robustness_run(spec: Spec, settings: BenchSettings) -> Measurement:
    out = pathlib.Path(settings.work_dir) / f"robustness-{time.strftime('%Y%m%dT%H%M%S')}"
    t0 = time.perf_counter()
    s = sweep(spec, out, workers=settings.workers, quiet=settings.quiet)
    per_task: dict[str, Any] = {}
    for key, stats in s["per_task_solver"].items():
        task, _scheme, solver = key.split()
        per_task.setdefault(task, {})[solver] = {
            "success_rate": stats["success_rate"],
            "cases": stats["cases"],
            "median_iterations": (stats.get("iterations") or {}).get("median"),
        }
    for task, agree in s.get("agreement", {}).items():
        per_task.setdefault(task, {})["agreement"] = agree["agree_fraction"]
    values = {"folder": str(out), "n_cases": s["n_cases"], "n_succeeded": s["n_succeeded"], "per_task": per_task}
    return Measurement(values, {"wall_s": time.perf_counter() - t0})


def robustness_table(rec: Mapping[str, Any]) -> str:
    c = rec["cases"][0]
    solvers = sorted({s for v in c["per_task"].values() for s in v if s != "agreement"})
    head = " | ".join(f"{s}: succeeded, median iterations" for s in solvers)
    lines = [f"| task | {head} | every backend at one optimum |", "|---|" + "---|" * (len(solvers) + 1)]
    for task, v in sorted(c["per_task"].items()):
        cells = [
            f"{v[s]['success_rate']:.0%} of {v[s]['cases']}, {v[s]['median_iterations']}" if s in v else "-"
            for s in solvers
        ]
        agree = f"{v['agreement']:.0%}" if "agreement" in v else "-"
        lines.append(f"| {task} | {' | '.join(cells)} | {agree} |")
    return "\n".join(lines) + f"\n\nCases and summary: `{c['folder']}`."


# ------------------------------------------------------------------------ external scripts
def external_case(name: str, script: str, args: list[str]) -> Case:
    """A maintained script run as it is (``python scripts/<script> --out FILE ARGS``) once, its JSON
    record embedded; skipped (with the reason) where the script is not in this checkout."""

    def run() -> Measurement:
        path = REPO / "scripts" / script
        if not path.is_file():
            return Measurement({"skipped": f"{path} not found"}, {})
        with tempfile.TemporaryDirectory() as tmp:
            out = pathlib.Path(tmp) / "record.json"
            t0 = time.perf_counter()
            proc = subprocess.run([sys.executable, str(path), "--out", str(out), *args], cwd=REPO, text=True)
            wall = time.perf_counter() - t0
            record = json.loads(out.read_text()) if out.is_file() else None
        return Measurement(
            {"script": script, "args": args, "returncode": proc.returncode, "record": record}, {"wall_s": wall}
        )

    return Case(name, run)


def external_table(rec: Mapping[str, Any]) -> str:
    lines = []
    for c in rec["cases"]:
        if "skipped" in c:
            lines.append(f"- {c['case']}: skipped ({c['skipped']})")
        else:
            what = "record embedded in the JSON" if c["record"] is not None else "no record"
            lines.append(
                f"- {c['case']}: `scripts/{c['script']} {' '.join(c['args'])}` exited {c['returncode']} after "
                f"{fmt_time(c['times'].get('wall_s'), 0)} s; {what}"
            )
    return "\n".join(lines)


COMPILE_COLUMNS = (
    ("compile_wall_s", "reported compile, wall s"),
    ("compile_cpu_s", "reported compile, CPU s"),
    ("process_wall_s (wall run)", "process, wall s"),
    ("process_cpu_s (wall run)", "process, CPU s"),
)


def _embedded(rec: Mapping[str, Any], part: str) -> list[list[dict[str, Any]]]:
    """The non-empty ``part`` of each case's embedded script record (e.g. ``"compile"``)."""
    parts = [(c.get("record") or {}).get(part) or [] for c in rec["cases"]]
    return [p for p in parts if p]


def compile_table(rec: Mapping[str, Any]) -> str:
    """``external_table`` with, per variant of the embedded record, the spread over its runs of the
    compile time a cold ``jaxhumanoid solve`` reports (wall clock, and CPU time) and of the whole
    process's wall and CPU time."""
    lines = [external_table(rec)]
    for rows in _embedded(rec, "compile"):
        lines += ["", "| variant | runs | " + " | ".join(h for _, h in COMPILE_COLUMNS) + " |"]
        lines.append("|---" * (2 + len(COMPILE_COLUMNS)) + "|")
        for v in dict.fromkeys(r["variant"] for r in rows):
            mine = [r for r in rows if r["variant"] == v]
            values = [[r[k] for r in mine if k in r] for k, _ in COMPILE_COLUMNS]
            cells = [fmt_time(spread(vals), 1) if vals else "-" for vals in values]
            lines.append(f"| {v} | {len(mine)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


ITERATION_COLUMNS = (
    ("stage 2 OverallAlgorithm cpu", "stage 2: all"),
    ("stage 2 Function Evaluations cpu", "evaluations"),
    ("stage 2 PDSystemSolverTotal cpu", "KKT solves"),
    ("stage 1 OverallAlgorithm cpu", "stage 1: all"),
    ("stage 1 Function Evaluations cpu", "evaluations"),
)


def iteration_cases(settings: BenchSettings) -> list[Case]:
    """``scripts/bench_iteration.py`` on the reference posing's files where ``--reference-dir``
    has them (the NLPs the independent implementation's per-iteration figures are for), else on
    the built-in tasks."""
    args = ["--tasks", *settings.tasks, "--runs", str(settings.repeats)]
    if any((pathlib.Path(settings.reference_dir) / f"{t}.toml").is_file() for t in settings.tasks):
        args += ["--task-dir", settings.reference_dir]
    return [external_case("bench_iteration", "bench_iteration.py", args)]


def iteration_summary(cases: list[dict[str, Any]], settings: BenchSettings) -> dict[str, Any]:
    """The independent implementation's figures, where the solves were the reference posing's."""
    on_reference = any("--task-dir" in c.get("args", []) for c in cases)
    return {"reference": _readme_figures(settings)[1] if on_reference else {}}


def iteration_table(rec: Mapping[str, Any]) -> str:
    """``external_table`` with, per task and variant of the embedded record's whole solves, IPOPT's
    CPU milliseconds per iteration of stage 2 (all, function evaluations, KKT solves) and of stage 1
    (all, function evaluations): median (min-max) over the runs; beside them, on the reference
    posing, the independent implementation's stage-2 time per iteration (its README) and the ratio."""
    figures = rec.get("summary", {}).get("reference", {})
    lines = [external_table(rec)]
    for entries in _embedded(rec, "solve"):
        head = " | ".join(h for _, h in ITERATION_COLUMNS)
        lines += ["", "IPOPT's CPU ms per iteration (its timing statistics), median (min-max) over the runs:", ""]
        lines.append(f"| task | variant | runs | stage-2 iterations | {head} | independent, stage 2 | ratio |")
        lines.append("|---" * (6 + len(ITERATION_COLUMNS)) + "|")
        for e in entries:
            its = "/".join(str(i) for i in e.get("stage 2 iterations", []))
            cells = " | ".join(fmt_time(e.get(f"{k} ms/it")) for k, _ in ITERATION_COLUMNS)
            ref = figures.get(e["task"], {}).get("stage2_ms_per_iteration")
            ours = e.get(f"{ITERATION_COLUMNS[0][0]} ms/it")
            ratio = f"{ours['median'] / ref:.2f}" if ref and ours else "-"
            lines.append(f"| {e['task']} | {e['variant']} | {e['runs']} | {its} | {cells} | {ref or '-'} | {ratio} |")
    return "\n".join(lines)


SUITES: dict[str, Suite] = {
    "reference": Suite(
        reference_cases,
        reference_table,
        reference_summary,
        about="Each reference-posing task file (its scheme, grid, options and stage-1 solver) on each backend.",
    ),
    "reference-draws": Suite(
        reference_draws_cases,
        reference_draws_table,
        reference_draws_summary,
        repeat=False,
        about="Each reference-posing task file on each backend over perturbed weights (``--draws``, default 6).",
    ),
    "table2": Suite(table2_cases, table2_table, table2_summary, about="A,F+C,2S against A,F+C,1S, N = 100, T = 5 s."),
    "agreement": Suite(
        agreement_cases, agreement_table, about="A,F+C,2S by every backend from one stage-1 point (IPOPT's)."
    ),
    "robustness": Suite(
        robustness_cases,
        robustness_table,
        repeat=False,
        about="The robustness study (perturbed weights, law, grid, horizon and start), once.",
    ),
    "iteration": Suite(
        iteration_cases,
        iteration_table,
        iteration_summary,
        repeat=False,
        about="An IPOPT iteration's parts and whole solves per iteration (`scripts/bench_iteration.py`), on the "
        "reference posing's files where `--reference-dir` has them.",
    ),
    "compile": Suite(
        lambda s: [
            external_case(
                "cold compile",
                "bench_iteration.py",
                ["--parts", "compile", "--runs", str(s.repeats), "--variant", "ipopt", "--variant", "ipm,solver:ipm"],
            )
        ],
        compile_table,
        repeat=False,
        about="A cold start's compile time with IPOPT and with the IPM (`scripts/bench_iteration.py --parts compile`).",
    ),
}
DEFAULT_SUITES = ("reference", "table2", "agreement")
