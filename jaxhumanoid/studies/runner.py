"""The benchmark runner behind ``jaxhumanoid bench``: named suites of cases, each case run
``repeats`` times in alternation with the others, one JSON record per run and a markdown table.

A suite (``Suite``) makes its cases from the run's ``BenchSettings``; a case (``Case``) is a
function that does the work once and returns a ``Measurement``: ``values`` that must not change
from run to run (status, iterations, objective: the paths are deterministic) and ``times`` in
seconds. The runner runs every case once per round, ``repeats`` rounds (a varying load on a
shared machine affects every case alike), records the values of the first round with a check that
the other rounds agree, and per time its median, range and runs. A suite may add a summary of its
cases (ratios of medians, say) and renders its part of the markdown.

The record (``run_record``) carries the commit, whether the work tree had changes and
``runtime.environment()`` (``studies.bench.stamp``), the settings and every suite's cases.
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import pathlib
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from jaxhumanoid.progress import Progress, format_duration
from jaxhumanoid.strategy.problem import STRATEGY_GUESSES
from jaxhumanoid.studies.bench import stamp

DEFAULT_REFERENCE_DIR = "../shared/reference_posing"
TASKS = ("T1", "T2", "T3", "T4")
BACKENDS = ("ipopt", "ipm", "casadi")


@dataclasses.dataclass(frozen=True)
class BenchSettings:
    """What a run of ``jaxhumanoid bench`` is asked for; each suite reads the fields it needs.

    ``N``: the grid of every solve (None: each suite's own, the tasks' N = 100); ``draws``: the
    robustness study's first K draws per task (None: all), the reference-draws suite's draws per
    file (None: its default); ``guess``: the first stage's initial guess of every suite's solves
    (``STRATEGY_GUESSES``; None: ``solve``'s, the task file's and the spec's); ``stage1_options``:
    IPOPT options of stage 1 of 2S in every suite's solves, added to ``solve``'s, the task file's
    and the spec's (None: theirs);
    ``work_dir``: where suites that write files (a sweep, an external script's record) put them."""

    repeats: int = 3
    tasks: tuple[str, ...] = TASKS
    backends: tuple[str, ...] = BACKENDS
    N: int | None = None
    reference_dir: str = DEFAULT_REFERENCE_DIR
    spec: str = "examples/studies/robustness.toml"
    draws: int | None = None
    workers: int = 1
    guess: str | None = None
    stage1_options: Mapping[str, Any] | None = None
    work_dir: str = "bench/work"
    quiet: bool = False

    def __post_init__(self):
        if isinstance(self.repeats, bool) or not isinstance(self.repeats, int) or self.repeats < 1:
            raise ValueError(f"--repeats: expected an integer >= 1, got {self.repeats!r}")
        if self.N is not None and (isinstance(self.N, bool) or not isinstance(self.N, int) or self.N < 3):
            raise ValueError(f"--N: expected an integer number of intervals >= 3, got {self.N!r}")
        if self.draws is not None and self.draws < 1:
            raise ValueError(f"--draws: expected an integer >= 1, got {self.draws!r}")
        if self.guess is not None and self.guess not in STRATEGY_GUESSES:
            raise ValueError(f"--guess: expected one of {', '.join(STRATEGY_GUESSES)}, got {self.guess!r}")
        if self.workers < 1:
            raise ValueError(f"--workers: expected an integer >= 1, got {self.workers!r}")
        unknown = sorted(set(self.backends) - set(BACKENDS))
        if unknown or not self.backends:
            raise ValueError(f"--backends: expected some of {', '.join(BACKENDS)}, got {list(self.backends)}")
        if not self.tasks:
            raise ValueError("--tasks: give at least one task")
        for task in self.tasks:
            if task not in TASKS:
                raise ValueError(f"--tasks: {task!r} not in {', '.join(TASKS)}")


class Measurement(NamedTuple):
    """One run of a case: values that repeat exactly, and times in seconds."""

    values: dict[str, Any]
    times: dict[str, float]


class Case(NamedTuple):
    name: str
    run: Callable[[], Measurement]


class Suite(NamedTuple):
    """``cases(settings)``; ``summary(case records, settings)`` or None; ``table(suite record)`` ->
    markdown; ``repeat``: False for a suite run once whatever ``--repeats`` says (a study, an
    external benchmark that repeats itself)."""

    cases: Callable[[BenchSettings], list[Case]]
    table: Callable[[Mapping[str, Any]], str]
    summary: Callable[[list[dict[str, Any]], BenchSettings], dict[str, Any]] | None = None
    repeat: bool = True
    about: str = ""


def spread(runs: Sequence[float]) -> dict[str, Any]:
    """Median, min and max of a time's runs, and the runs."""
    a = np.asarray(runs, dtype=float)
    return {"median": float(np.median(a)), "min": float(a.min()), "max": float(a.max()), "runs": a.tolist()}


def case_record(name: str, runs: Sequence[Measurement]) -> dict[str, Any]:
    """A case over its runs: the first run's values, whether every run gave the same values (the
    values of those that did not under ``differing``), and ``spread`` of each time."""
    first = runs[0].values
    differing = [m.values for m in runs[1:] if _canonical(m.values) != _canonical(first)]
    rec: dict[str, Any] = {"case": name, "runs": len(runs), **first, "repeats_agree": not differing}
    if differing:
        rec["differing"] = differing
    rec["times"] = {k: spread([m.times[k] for m in runs if k in m.times]) for k in runs[0].times}
    return rec


def _canonical(values: Mapping[str, Any]) -> str:
    return json.dumps(values, sort_keys=True, default=float)


def run_suite(name: str, suite: Suite, cases: Sequence[Case], settings: BenchSettings) -> dict[str, Any]:
    """The ``cases`` of ``suite``, ``settings.repeats`` rounds (one round where ``suite.repeat`` is
    False), with a progress line per case and round; the suite's record."""
    rounds = settings.repeats if suite.repeat else 1
    progress = Progress(len(cases) * rounds, quiet=settings.quiet)
    runs: dict[str, list[Measurement]] = {c.name: [] for c in cases}
    t0 = time.perf_counter()
    for r in range(rounds):
        for case in cases:
            progress.start(f"{name}: {case.name}" + (f" (round {r + 1}/{rounds})" if rounds > 1 else ""))
            m = case.run()
            runs[case.name].append(m)
            progress.finish(_note(m))
    records = [case_record(k, v) for k, v in runs.items()]
    out: dict[str, Any] = {"about": suite.about, "rounds": rounds, "wall_s": time.perf_counter() - t0}
    out["cases"] = records
    if suite.summary is not None:
        out["summary"] = suite.summary(records, settings)
    return out


def _note(m: Measurement) -> str:
    status = m.values.get("status")
    its = m.values.get("iterations")
    parts = [str(status) if status is not None else "", f"iterations {its}" if its is not None else ""]
    total = m.times.get("solve_s")
    parts.append(f"solve {total:.2f} s" if total is not None else "")
    return ", ".join(p for p in parts if p)


def plan_run(names: Sequence[str], suites: Mapping[str, Suite], settings: BenchSettings) -> dict[str, list[Case]]:
    """The cases of the named suites, made before any runs: bad input (an unknown suite, a missing
    folder or spec) is reported before any work."""
    unknown = [n for n in names if n not in suites]
    if unknown or not names:
        raise ValueError(f"--suite: expected some of {', '.join(suites)}, got {list(names)}")
    return {name: suites[name].cases(settings) for name in dict.fromkeys(names)}


def run_record(
    planned: Mapping[str, Sequence[Case]],
    suites: Mapping[str, Suite],
    settings: BenchSettings,
    argv: Sequence[str] = (),
) -> dict[str, Any]:
    """Run the planned suites in turn (``plan_run``): the record of the run (``stamp``: commit,
    dirty flag and environment first, as they were when the run started, which is the code that
    ran)."""
    started = datetime.datetime.now(datetime.UTC)
    stamped = stamp({})
    t0 = time.perf_counter()
    out = {name: run_suite(name, suites[name], cases, settings) for name, cases in planned.items()}
    return {
        **stamped,
        "started": started.isoformat(timespec="seconds"),
        "wall_s": time.perf_counter() - t0,
        "command": list(argv),
        "settings": dataclasses.asdict(settings),
        "suites": out,
    }


def markdown(record: Mapping[str, Any], suites: Mapping[str, Suite]) -> str:
    """The record as markdown: a header with the commit and the environment, one section per suite."""
    env = record.get("environment", {})
    commit = record.get("describe") or (record.get("commit") or "unknown")[:10]
    commit += " (with changes)" if record.get("dirty") and not commit.endswith("-dirty") else ""
    head = [
        f"# jaxhumanoid bench, {record.get('started', '')}",
        "",
        f"commit {commit}; {env.get('cpu', '')}; OMP_NUM_THREADS={env.get('OMP_NUM_THREADS')}; "
        f"python {env.get('python')}; jax {env.get('packages', {}).get('jax')}; "
        f"wall {format_duration(float(record.get('wall_s', 0.0)))}. "
        f"Times: median (min-max) of {record.get('settings', {}).get('repeats')} runs, seconds.",
    ]
    parts = ["\n".join(head)]
    for name, rec in record["suites"].items():
        about = f"\n\n{rec['about']}" if rec.get("about") else ""
        parts.append(f"## {name}{about}\n\n{suites[name].table(rec)}")
    return "\n\n".join(parts) + "\n"


def write_run(record: Mapping[str, Any], text: str, out: str | pathlib.Path) -> tuple[pathlib.Path, pathlib.Path]:
    """``out/<UTC time>-<commit>.json`` and ``.md`` beside it; returns both paths."""
    folder = pathlib.Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    when = str(record.get("started", "")).replace(":", "").replace("-", "").split("+")[0]
    stem = f"{when}-{(record.get('commit') or 'nocommit')[:10]}{'-dirty' if record.get('dirty') else ''}"
    path = folder / f"{stem}.json"
    path.write_text(json.dumps(record, indent=1, default=float) + "\n")
    md = path.with_suffix(".md")
    md.write_text(text)
    return path, md


def fmt_time(t: Mapping[str, Any] | None, digits: int = 2) -> str:
    """A time's spread as ``median (min-max)``; ``-`` where missing."""
    if not t:
        return "-"
    if t["min"] == t["max"]:
        return f"{t['median']:.{digits}f}"
    return f"{t['median']:.{digits}f} ({t['min']:.{digits}f}-{t['max']:.{digits}f})"
