"""Task files: a body, a contact law, a task and its solve settings in one TOML file.

    name = "squat"                       # the task's name (required)
    key = "T1"                           # optional short name in reports (default: name)
    [body]                               # optional; default the paper's humanoid
    preset = "humanoid"                  #   start from a preset body, then override fields, or
    a = [0.473, 0.422, 0.532]            #   give a, c, m, inertia (n each) for a chain of n links
    c = [...]; m = [...]; inertia = [...]
    g = 9.81; names = ["knee", "hip", "shoulder"]
    q_min_deg = [...]; q_max_deg = [...] #   joint ranges (degrees; q_min/q_max in rad also work)
    u_max = [...]                        #   joint strengths (N m): torque box [-u_max, u_max]
    scale_m = 1.1                        #   multiply every mass (and inertia) by a factor
    [foot]     a0f = 0.2; a0b = 0.05; ankle_height = 0.08          # optional
    [foot_margin]  load = 0.1; friction = 0.1; cop = 0.02  # optional: keep the plan's foot inside (5)
               # by a load (M g), a fraction of the friction cone, a distance (m) from toe and heel
    [contact]  kappa = 7e4; f0 = 100.0; xhat = 0.05; mu = 0.8      # optional; default nominal
    [contact_stage1]  ...                                           # optional; default relaxed
    [task]
    start_deg = [...]; goal_deg = [...]  # postures (or start/goal in rad), n each
    active = [1, 3]                      # the joints that may carry contact forces
    goal_tolerance = 0.05                # rad, half-width of the terminal box (optional)
    contact_force_limit = 2.0            # body weights: cap on every body contact's normal force
                                         #   (optional; scheme A only)
    q_min_deg = [...]; q_max_deg = [...] # optional, replace the body's ranges
    [weights]  w_u = 1e-3; w_qd = 1.0; w_dqd = 2e-2; w_du = 1e-5  # optional
    [solve]    scheme = "A,F+C,2S"; solver = "ipopt"; N = 60; T = 4.0; N1 = 20    # optional
               guess = "static_path"       # or "auto" (default), "inverse_dynamics", "linear", "both": first guess
               handover = "direct"         # or "continuation" (default): stage 1 to stage 2
               continuation_steps = 2      #   laws of the continuation after stage 1's (default 2)
               stage1_solver = "same"      # or "ipopt" (default): the solver of the relaxed-law stages
               scaling = "physical"        # or "none" (default): the NLPs in units of O(1)
               stage1_options = {...}; stage2_options = {...}   # per-stage solver options
    [options]  tol = 1e-8                # solver options, optional

Angles follow the package's convention (relative joint angles, ``jaxhumanoid.model``). Every
field is checked on loading, and an error names the file, the table and the field. ``[solve]``'s
scheme, solver, N and T are ``solve``'s own keywords; its other keys, ``[contact_stage1]`` and
``[foot_margin]`` make the file's ``SolveSettings``.
"""

from __future__ import annotations

import dataclasses
import pathlib
import tomllib
from typing import Any

import numpy as np

from jaxhumanoid.model.foot import FootMargin, check_foot_margin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import tasks
from jaxhumanoid.ocp.tasks import Task, Weights
from jaxhumanoid.runtime import read_toml
from jaxhumanoid.strategy.settings import SolveSettings

PRESETS = {"humanoid": PlanarChain.humanoid}
# [solve]'s keys that are ``solve``'s own keywords; the others are ``SolveSettings`` fields, all but
# the two that have tables of their own
SOLVE_KEYWORDS = ("scheme", "solver", "N", "T")
_OWN_TABLES = {"contact_stage1", "foot_margin"}
SOLVE_TABLE = {*SOLVE_KEYWORDS, *(f.name for f in dataclasses.fields(SolveSettings))} - _OWN_TABLES
TABLES = {
    "name": None,
    "key": None,
    "body": {
        "preset",
        "a",
        "c",
        "m",
        "inertia",
        "g",
        "names",
        "q_min",
        "q_max",
        "q_min_deg",
        "q_max_deg",
        "u_max",
        "scale_m",
    },
    "foot": {"a0f", "a0b", "ankle_height"},
    "foot_margin": {"load", "friction", "cop"},
    "contact": {"kappa", "f0", "xhat", "mu"},
    "contact_stage1": {"kappa", "f0", "xhat", "mu"},
    "task": {
        "start",
        "goal",
        "start_deg",
        "goal_deg",
        "active",
        "q_min",
        "q_max",
        "q_min_deg",
        "q_max_deg",
        "goal_tolerance",
        "contact_force_limit",
    },
    "weights": {"w_u", "w_qd", "w_dqd", "w_du"},
    "solve": SOLVE_TABLE,
    "options": None,
}


@dataclasses.dataclass(frozen=True)
class TaskFile:
    """What a task file defines: ``solve(**as_solve_kwargs())`` solves it. ``keywords``: the
    ``[solve]`` table's scheme, solver, N and T (those it gives); ``settings``: the strategy's
    settings from the rest of ``[solve]``, ``[contact_stage1]`` and ``[foot_margin]``."""

    path: pathlib.Path
    task: Task
    model: PlanarChain
    foot: FootParams | None
    contact: ContactParams | None
    keywords: dict
    settings: SolveSettings
    options: dict

    def as_solve_kwargs(self) -> dict[str, Any]:
        return dict(
            task=self.task,
            model=self.model,
            foot=self.foot,
            contact=self.contact,
            options=self.options or None,
            settings=self.settings,
            **self.keywords,
        )


def _angles(where: str, table: dict, key: str, n: int | None):
    """The angles ``key`` (rad) or ``key_deg`` (degrees) of a table, None when absent."""
    if key in table and f"{key}_deg" in table:
        raise ValueError(f"{where}: give {key} (rad) or {key}_deg (degrees), not both")
    if key not in table and f"{key}_deg" not in table:
        return None
    raw = table.get(key, table.get(f"{key}_deg"))
    arr = np.asarray(raw, dtype=float) * (1.0 if key in table else np.pi / 180.0)
    if arr.ndim != 1 or (n is not None and arr.size != n):
        raise ValueError(f"{where}.{key}: expected {n if n else 'one'} angles per joint, got {raw!r}")
    return arr


def _body(where: str, table: dict) -> PlanarChain:
    preset = table.get("preset")
    if preset is not None and preset not in PRESETS:
        raise ValueError(f"{where}.preset: {preset!r} is not one of {sorted(PRESETS)}")
    base = PRESETS[preset]() if preset else None
    if base is None and not {"a", "c", "m", "inertia"} <= set(table):
        raise ValueError(f'{where}: give preset = "humanoid" or all of a, c, m, inertia')
    keys = ("a", "c", "m", "inertia", "u_max")
    fields: dict[str, Any] = {k: np.asarray(table[k], dtype=float) for k in keys if k in table}
    n = len(fields["a"]) if "a" in fields else (base.n if base else None)
    for key in ("q_min", "q_max"):
        value = _angles(where, table, key, n)
        if value is not None:
            fields[key] = value
    if "g" in table:
        fields["g"] = float(table["g"])
    if "names" in table:
        fields["names"] = tuple(str(s) for s in table["names"])
    chain = dataclasses.replace(base, **fields) if base is not None else PlanarChain(**fields)
    scale = float(table.get("scale_m", 1.0))
    if scale != 1.0:
        chain = dataclasses.replace(chain, m=np.asarray(chain.m) * scale, inertia=np.asarray(chain.inertia) * scale)
    return chain


def _params(table: dict | None, default):
    """``default()`` with the table's fields replaced; None when the file has no such table."""
    return None if table is None else dataclasses.replace(default(), **{k: float(v) for k, v in table.items()})


def _check_keys(path: pathlib.Path, data: dict) -> None:
    for key, value in data.items():
        if key not in TABLES:
            raise ValueError(f"{path}: unknown table or key {key!r}; allowed: {sorted(TABLES)}")
        allowed = TABLES[key]
        if allowed is not None:
            if not isinstance(value, dict):
                raise ValueError(f"{path}: [{key}] must be a table")
            unknown = sorted(set(value) - allowed)
            if unknown:
                raise ValueError(f"{path}: [{key}] has unknown keys {unknown}; allowed: {sorted(allowed)}")


def task_files(folder) -> list[pathlib.Path]:
    """The task files of a folder: its ``*.toml`` files with a ``[task]`` table, sorted (study
    specs, which list tasks instead, and unreadable files are left out)."""
    folder = pathlib.Path(folder)
    out = []
    for path in sorted(folder.glob("*.toml")) if folder.is_dir() else []:
        try:
            data = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError):
            continue
        if isinstance(data.get("task"), dict):
            out.append(path)
    return out


def solve_kwargs(task: str) -> dict[str, Any]:
    """``solve``'s keyword arguments for a built-in task key or a task file (``*.toml``)."""
    return load_task_file(task).as_solve_kwargs() if str(task).endswith(".toml") else {"task": task}


def load_task_file(path) -> TaskFile:
    """Read and check a task file (see the module docstring)."""
    path = pathlib.Path(path)
    data = read_toml(path, "--task-file")
    _check_keys(path, data)
    if "name" not in data or "task" not in data:
        raise ValueError(f'{path}: a task file needs name = "..." and a [task] table')
    try:
        model = _body(f"{path}: [body]", data["body"]) if "body" in data else PlanarChain.humanoid()
        foot = _params(data.get("foot"), FootParams.paper)
        contact = _params(data.get("contact"), ContactParams.nominal)
        stage1 = _params(data.get("contact_stage1"), ContactParams.relaxed)
        margin = _params(data.get("foot_margin"), FootMargin)
        if margin is not None:
            check_foot_margin(margin, foot or FootParams.paper())
        t = data["task"]
        where = f"{path}: [task]"
        start, goal = _angles(where, t, "start", model.n), _angles(where, t, "goal", model.n)
        if start is None or goal is None or "active" not in t:
            raise ValueError(f"{where}: needs start (or start_deg), goal (or goal_deg) and active")
        w = data.get("weights", {})
        task = Task(
            str(data["name"]),
            start,
            goal,
            tuple(t["active"]),
            weights=Weights(**w) if w else Weights(),
            q_min=_angles(where, t, "q_min", model.n),
            q_max=_angles(where, t, "q_max", model.n),
            goal_tolerance=float(t.get("goal_tolerance", tasks.GOAL_TOLERANCE)),
            key=str(data.get("key", "")),
            contact_force_limit=t.get("contact_force_limit"),
        )
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: {err}") from err
    table = data.get("solve", {})
    keywords = {k: v for k, v in table.items() if k in SOLVE_KEYWORDS}
    rest = {k: v for k, v in table.items() if k not in SOLVE_KEYWORDS}
    settings = SolveSettings.from_mapping({**rest, "contact_stage1": stage1, "foot_margin": margin}, f"{path}: [solve]")
    return TaskFile(path, task, model, foot, contact, keywords, settings, dict(data.get("options", {})))
