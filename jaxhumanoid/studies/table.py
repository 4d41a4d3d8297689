"""The study's table (``DIR/cases.csv``, one row per finished case, appended as each finishes so
that a crash loses nothing), resume, and ``DIR/summary.json``.

Columns: the case's parameters (``CASE_COLUMNS`` and one per perturbation factor), then what
the run gave (``RESULT_COLUMNS``; an inverse study adds ``INVERSE_COLUMNS``). ``status`` is the
last stage's solver status, ``error`` for an exception (message in ``error``) or ``crashed``
for a worker that died. A case is finished when the table has a row for its id; a re-run skips
finished cases (with ``retry_failed``: only the successful ones). When a case has several rows
(retried), the last one counts.
"""

from __future__ import annotations

import csv
import json
import math
import os
import pathlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from jaxhumanoid.studies.spec import Spec

TABLE = "cases.csv"
SUMMARY = "summary.json"
CASE_COLUMNS = (
    "id", "problem", "kind", "task", "scheme", "solver", "N", "T", "N1", "draw", "method", "start_seed", "options",
)  # fmt: skip
RESULT_COLUMNS = (
    "status", "success", "error", "iterations", "iterations_total", "stage_status", "solve_time_s", "compile_time_s",
    "wall_time_s", "objective", "max_constraint_violation", "peak_torque_Nm", "peak_contact_force_body_weights",
    "start_moved", "redraws", "path", "worker", "warnings",
)  # fmt: skip
INVERSE_COLUMNS = ("loss_initial", "loss_final", "max_rel_weight_error", "max_abs_q_error_rad", "w_recovered")
# read back as text whatever they look like: a hex id such as "67257e895274" or "123456789012"
# also reads as a number, and then no longer matches its case (resume would re-run it forever)
TEXT_COLUMNS = ("id", "problem", "kind", "task", "scheme", "solver", "method", "status", "path", "worker")


def columns(spec: Spec) -> list[str]:
    """The table's columns for ``spec``."""
    extra = INVERSE_COLUMNS if spec.kind == "inverse" else ()
    return [*CASE_COLUMNS, *spec.factor_names, *RESULT_COLUMNS, *extra]


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _value(text: str) -> Any:
    """A cell read back: "" -> None, True/False -> bool, numbers -> int or float, else the text."""
    if text == "":
        return None
    if text in ("True", "False"):
        return text == "True"
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            continue
    return text


def read_table(path) -> list[dict[str, Any]]:
    """Every row of a written table, values converted back (``_value``; ``TEXT_COLUMNS`` stay
    text); [] when absent."""
    path = pathlib.Path(path)
    if not path.is_file():
        return []
    with path.open(newline="") as fh:
        return [{k: v if k in TEXT_COLUMNS else _value(v) for k, v in row.items()} for row in csv.DictReader(fh)]


class Table:
    """An append-only CSV table: the header on creation, then a row per ``append``, flushed and
    synced at once. An existing table must have the same columns (the same kind of spec)."""

    def __init__(self, path, cols: Sequence[str]):
        self.path, self.columns = pathlib.Path(path), list(cols)
        if self.path.is_file() and self.path.stat().st_size > 0:
            with self.path.open(newline="") as fh:
                header = next(csv.reader(fh), [])
            if header != self.columns:
                raise ValueError(
                    f"--out: {self.path} was written by a study with other columns; give another --out to start anew"
                )
        else:
            with self.path.open("w", newline="") as fh:
                csv.writer(fh).writerow(self.columns)

    def append(self, row: Mapping[str, Any]) -> None:
        with self.path.open("a", newline="") as fh:
            csv.writer(fh).writerow([_cell(row.get(c)) for c in self.columns])
            fh.flush()
            os.fsync(fh.fileno())


def latest_rows(rows: Iterable[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """The last row of every id."""
    return {str(r["id"]): r for r in rows}


def finished_ids(rows: Iterable[Mapping[str, Any]], retry_failed: bool = False) -> set[str]:
    """The ids a re-run skips: every one with a row, or (``retry_failed``) every successful one."""
    return {i for i, r in latest_rows(rows).items() if r.get("success") or not retry_failed}


# -- summary --------------------------------------------------------------------------------------


def spread(values: Iterable[Any]) -> dict[str, float] | None:
    """Median, min, max and count of the finite values; None when there are none."""
    v = np.asarray([x for x in values if isinstance(x, (int, float)) and math.isfinite(x)], dtype=float)
    if v.size == 0:
        return None
    return {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()), "n": int(v.size)}


def group_stats(rows: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Cases, successes, errors, crashes and the spreads of iterations, solve, compile and wall
    times (every case that returned) and of the objective (the successful ones)."""
    ok = [r for r in rows if r.get("success")]
    ran = [r for r in rows if r.get("status") not in ("error", "crashed")]
    return {
        "cases": len(rows),
        "succeeded": len(ok),
        "success_rate": len(ok) / len(rows) if rows else None,
        "errors": sum(r.get("status") == "error" for r in rows),
        "crashed": sum(r.get("status") == "crashed" for r in rows),
        "iterations": spread(r.get("iterations_total") for r in ran),
        "solve_time_s": spread(r.get("solve_time_s") for r in ran),
        "compile_time_s": spread(r.get("compile_time_s") for r in ran),
        "wall_time_s": spread(r.get("wall_time_s") for r in rows),
        "objective": spread(r.get("objective") for r in ok),
    }


def _by(rows: Sequence[Mapping[str, Any]], *keys: str) -> dict[str, list[Mapping[str, Any]]]:
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(" ".join(str(r.get(k)) for k in keys), []).append(r)
    return groups


def recovery(rows: Sequence[Mapping[str, Any]], rtol: float) -> dict[str, Any]:
    """Multi-start inverse fits of one task: how many starts recover every free weight within
    ``rtol`` (relative), and the best start (the smallest final loss): keep that fit."""
    fits = [r for r in rows if r.get("success")]
    recovered = [r for r in fits if (r.get("max_rel_weight_error") or math.inf) <= rtol]
    best = min(fits, key=lambda r: r["loss_final"], default=None)
    return {
        "starts": len(rows),
        "fitted": len(fits),
        "recovered": len(recovered),
        "recovery_rate": len(recovered) / len(rows) if rows else None,
        "recovered_seeds": sorted(r["start_seed"] for r in recovered),
        "best_seed": best["start_seed"] if best else None,
        "best_loss": best["loss_final"] if best else None,
        "best_max_rel_weight_error": best["max_rel_weight_error"] if best else None,
        "best_recovers": bool(best is not None and best["max_rel_weight_error"] <= rtol),
        "rtol": rtol,
    }


def summarise(
    spec: Spec, rows: Iterable[Mapping[str, Any]], engine: str, workers: int, extra: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    """``summary.json``: the counts over the spec's cases (each with its last row), the engine,
    per-solver and per task-and-solver statistics (``group_stats``), and for an inverse study
    the recovery per task (``recovery``). ``extra`` (e.g. this run's wall time) is merged in."""
    latest = latest_rows(rows)
    done = [latest[c.id] for c in spec.cases if c.id in latest]
    summary: dict[str, Any] = {
        "name": spec.name,
        "kind": spec.kind,
        "spec": spec.path,
        "n_cases": len(spec.cases),
        "n_finished": len(done),
        "n_pending": len(spec.cases) - len(done),
        "n_succeeded": sum(bool(r.get("success")) for r in done),
        "n_failed": sum(not r.get("success") and r.get("status") not in ("error", "crashed") for r in done),
        "n_errors": sum(r.get("status") == "error" for r in done),
        "n_crashed": sum(r.get("status") == "crashed" for r in done),
        "engine": engine,
        "workers": workers,
        "per_solver": {k: group_stats(v) for k, v in _by(done, "solver").items()},
        "per_task_solver": {k: group_stats(v) for k, v in _by(done, "task", "scheme", "solver").items()},
        **(extra or {}),
    }
    if spec.kind == "inverse":
        summary["recovery"] = {k: recovery(v, spec.recovery_rtol) for k, v in _by(done, "task", "method").items()}
    return summary


def write_json(path, data: Mapping[str, Any]) -> None:
    """Write to a temporary file and rename it: the file is never half-written."""
    path = pathlib.Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, path)
