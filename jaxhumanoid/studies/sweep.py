"""Run a study: every case of a spec on an engine, a row per case, resume, ``summary.json``.

    from jaxhumanoid.studies import sweep
    summary = sweep("examples/sweep_small.toml", "out/small", engine="local", workers=2)

writes ``DIR/cases.csv`` (a row per case, appended as each finishes), ``DIR/cases/<id>/`` (each
solution: ``solution.npz`` and ``report.json``, or an inverse fit's ``fit.json``) and
``DIR/summary.json`` (``table.summarise``; rewritten at the end, also after an interruption).
Running it again skips the finished cases. ``solvers`` and ``draws`` run a part of the spec
(``select_cases``): its cases keep their ids, so the rest of the study later resumes from them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import pathlib
import time
from collections.abc import Mapping, Sequence
from typing import Any, TextIO

from jaxhumanoid.progress import Progress
from jaxhumanoid.runtime import writable_dir
from jaxhumanoid.solvers import ipopt_capi
from jaxhumanoid.studies.compare import problem_agreement
from jaxhumanoid.studies.engines import ENGINES, Crash, run_jobs
from jaxhumanoid.studies.run import crashed_row, run_case
from jaxhumanoid.studies.spec import Case, Spec, load_spec
from jaxhumanoid.studies.table import SUMMARY, TABLE, Table, columns, finished_ids, read_table, summarise, write_json


def check_run(spec: Spec, engine: str, workers: int, address: str | None) -> None:
    """The run's settings and the spec's solver options, checked before any work."""
    if engine not in ENGINES:
        raise ValueError(f"--engine: {engine!r} not in {ENGINES}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"--workers: expected an integer >= 1, got {workers!r}")
    if address is not None and engine == "local":
        raise ValueError("--address: the local engine takes no address (give --engine dask)")
    tables = {
        "options": {k: v for c in spec.cases if c.solver in ("ipopt", "casadi") for k, v in c.options},
        "stage1_options": {k: v for c in spec.cases for k, v in c.stage1_options},
    }
    for field, options in tables.items():
        if not options:
            continue
        try:
            ipopt_capi.check_options(options)
        except ValueError as err:
            raise ValueError(f"{field}: {err}") from err


def select_cases(spec: Spec, solvers: Sequence[str] | None = None, draws: int | None = None) -> Spec:
    """The part of ``spec`` solved by ``solvers`` (a subset of the spec's) and, for a spec with
    random draws, its first ``draws`` draws per task (draw i does not depend on their number)."""
    cases = spec.cases
    if solvers is not None:
        have = tuple(dict.fromkeys(c.solver for c in spec.cases))
        bad = [s for s in solvers if s not in have]
        if bad or not solvers:
            raise ValueError(f"--solvers: {bad or list(solvers)} not among the spec's solvers {have}")
        cases = tuple(c for c in cases if c.solver in solvers)
    if draws is not None:
        if any(c.draw is None for c in cases):
            raise ValueError("--draws: the spec has no [random] draws to take a part of")
        if isinstance(draws, bool) or not isinstance(draws, int) or draws < 1:
            raise ValueError(f"--draws: expected an integer >= 1, got {draws!r}")
        cases = tuple(c for c in cases if c.draw is not None and c.draw < draws)
    return dataclasses.replace(spec, cases=cases)


def compile_group(case: Case) -> tuple[tuple, float]:
    """(group, cost) of a case for the local pool: cases that share a task, scheme, solver and
    grid share their problem set-up and compiled functions; the cost grows with the grid."""
    return (case.kind, case.task, case.scheme, case.solver, case.N, case.N1), float(case.N or 100)


def case_label(case: Case) -> str:
    draw = f" draw {case.draw}" if case.draw is not None else ""
    start = f" start {case.start_seed}" if case.start_seed is not None else ""
    grid = f" N={case.N}" if case.N is not None else ""
    return f"{case.id} {case.task} {case.scheme} {case.solver}{grid}{draw}{start}"


def row_message(row: Mapping[str, Any]) -> str:
    if row.get("status") in ("error", "crashed"):
        return f"{row['status']}: {str(row.get('error'))[:120]}"
    its = row.get("iterations") or row.get("iterations_total")
    return f"{row['status']}, iterations {its}, wall {row.get('wall_time_s', float('nan')):.1f} s"


def sweep(
    spec: Spec | str | pathlib.Path,
    out,
    engine: str = "local",
    workers: int = 1,
    address: str | None = None,
    retry_failed: bool = False,
    quiet: bool = False,
    stream: TextIO | None = None,
    cache: bool = True,
    solvers: Sequence[str] | None = None,
    draws: int | None = None,
) -> dict[str, Any]:
    """Run every unfinished case of ``spec`` (a ``Spec`` or a spec file) on ``engine`` with
    ``workers`` worker processes (or the cluster at ``address``); returns the summary (module
    docstring). ``retry_failed`` also re-runs the cases whose last row did not succeed; ``cache``:
    the workers use the persistent compilation cache; ``solvers``, ``draws``: run only that part
    of the spec (``select_cases``)."""
    spec = select_cases(spec if isinstance(spec, Spec) else load_spec(spec), solvers, draws)
    check_run(spec, engine, workers, address)
    out = writable_dir(out)
    table = Table(out / TABLE, columns(spec))
    done = finished_ids(read_table(table.path), retry_failed)
    pending = {c.id: c for c in spec.cases if c.id not in done}
    progress = Progress(len(pending), quiet=quiet, stream=stream)
    where = address or f"{workers} worker{'s' if workers > 1 else ''}"
    progress.note(
        f"{spec.name}: {len(spec.cases)} cases, {len(spec.cases) - len(pending)} finished before, "
        f"running {len(pending)} on {engine} ({where}) -> {out}"
    )
    t0 = time.perf_counter()
    try:
        jobs = [(key, (case, str(out), cache)) for key, case in pending.items()]
        groups = {key: compile_group(case) for key, case in pending.items()}
        with contextlib.closing(run_jobs(run_case, jobs, engine, workers, address, groups)) as results:
            for key, result in results:
                row = crashed_row(pending[key], result.message) if isinstance(result, Crash) else result
                table.append(row)
                progress.completed(case_label(pending[key]), row_message(row))
    finally:
        wall = time.perf_counter() - t0
        rows = read_table(table.path)
        run = {
            "address": address,
            "run_wall_time_s": wall,
            "run_cases": progress.done,
            "skipped_finished": len(spec.cases) - len(pending),
        }
        summary = summarise(spec, rows, engine, workers, run)
        if spec.kind == "solve" and len({c.solver for c in spec.cases}) > 1:
            ids = {c.id for c in spec.cases}
            summary["agreement"] = problem_agreement(r for r in rows if r["id"] in ids)
        write_json(out / SUMMARY, summary)
    progress.note(
        f"{summary['n_finished']}/{summary['n_cases']} cases finished, {summary['n_succeeded']} succeeded, "
        f"{summary['n_errors']} errors, {summary['n_crashed']} crashed; {progress.done} run in {wall:.1f} s "
        f"-> {out / TABLE}, {out / SUMMARY}"
    )
    return summary
