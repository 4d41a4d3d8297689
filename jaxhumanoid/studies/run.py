"""One case = one solve (or one inverse fit) -> one row; what goes wrong goes into the row.

``run_case(case, out_dir)`` is the job a worker runs. It builds the case's problem (the task,
its body and laws, the perturbation factors, the start posture moved and projected onto a
static equilibrium), solves it, saves the solution under ``out_dir/cases/<id>/`` and returns a
flat, JSON- and CSV-ready row. An exception becomes a row with ``status = "error"`` and its
message: a failed case is a result of the study, never a reason to stop it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import socket
import time
import warnings
from typing import Any

import numpy as np

from jaxhumanoid.diff.inverse import fit_task_weights
from jaxhumanoid.model.params import ContactParams, PlanarChain
from jaxhumanoid.ocp.tasks import Task, get_task, with_force_limit
from jaxhumanoid.runtime import enable_compilation_cache
from jaxhumanoid.strategy.posture import find_equilibrium
from jaxhumanoid.strategy.problem import Problem, problem_from_settings
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.studies.spec import Case, draw_rng

WEIGHT_INDEX = {"weights.w_qd": 0, "weights.w_dqd": 1, "weights.w_du": 2}  # after the n per-joint w_u
BODY_FIELDS = {"body.m": ("m",), "body.inertia": ("inertia",), "body.length": ("a", "c"), "body.u_max": ("u_max",)}
SOLVE_DEFAULTS = {"N": 100, "T": 5.0}


def base_problem(case: Case) -> dict[str, Any]:
    """The keyword arguments of ``solve`` for the unperturbed task: a paper key, or a task file's
    body, laws, options and settings (N, T, N1, scaling and guess of the file unless the case sets them,
    stage 1's options added to the file's),
    the task with the case's ``contact_force_limit`` where it sets one."""
    if case.task_path is None:
        kwargs: dict[str, Any] = {"task": get_task(case.task), "model": None, "contact": None, "options": None}
    else:
        kwargs = load_task_file(case.task_path).as_solve_kwargs()
    for key in ("scheme", "solver"):
        kwargs.pop(key, None)
    for key in ("N", "T"):
        value = getattr(case, key)
        kwargs[key] = value if value is not None else kwargs.get(key, SOLVE_DEFAULTS.get(key))
    kwargs["options"] = {**(kwargs.get("options") or {}), **dict(case.options)} or None
    settings = kwargs.get("settings") or SolveSettings()
    changes = {k: getattr(case, k) for k in ("N1", "scaling", "guess") if getattr(case, k) is not None}
    if case.stage1_options:
        changes["stage1_options"] = settings.merged_stage1_options(dict(case.stage1_options))
    kwargs["settings"] = settings.replace(**changes)
    if case.contact_force_limit is not None:
        kwargs["task"] = with_force_limit(kwargs["task"], case.contact_force_limit)
    return kwargs


def perturbed_weights(task: Task, factors: dict[str, float]) -> np.ndarray:
    """(n + 3,) weights of (7): the task's, ``weights.w_u`` on every joint's w_u, the others each."""
    w = task.weights.as_array(task.n)
    w[: task.n] *= factors.get("weights.w_u", 1.0)
    for name, k in WEIGHT_INDEX.items():
        w[task.n + k] *= factors.get(name, 1.0)
    return w


def perturbed_contact(contact: ContactParams | None, factors: dict[str, float]) -> ContactParams:
    """The dynamic stage's law (default nominal) with each ``contact.*`` factor applied."""
    law = ContactParams.nominal() if contact is None else contact
    return ContactParams(
        **{k: float(getattr(law, k)) * factors.get(f"contact.{k}", 1.0) for k in ("kappa", "f0", "xhat", "mu")}
    )


def perturbed_body(model: PlanarChain | None, factors: dict[str, float]) -> PlanarChain:
    """The body (default Table I) with every link's mass, inertia, length or strength scaled."""
    body = PlanarChain.humanoid() if model is None else model
    changes: dict[str, Any] = {}
    for name, fields in BODY_FIELDS.items():
        for field in fields:
            if name in factors:
                changes[field] = np.asarray(getattr(body, field)) * factors[name]
    return dataclasses.replace(body, **changes) if changes else body


def perturbed_start(case: Case, task: Task, model: PlanarChain, contact: ContactParams, foot) -> tuple[Task, dict]:
    """The task with its start moved by ``case.start_offset`` and projected onto the nearest static
    equilibrium that keeps the foot steady with margin (within the task's joint ranges). When
    none is found, or it lies more than ``max_move`` (rad) from the moved posture (another
    posture, not a perturbed start), the offset is drawn again, up to ``max_redraws`` times.
    Returns the task and the row fields ``start_moved`` and ``redraws``; raises RuntimeError."""
    q_min, q_max = task.joint_ranges(model)
    offset, last = np.asarray(case.start_offset), ""
    for redraws in range(case.max_redraws + 1):
        if redraws:
            rng = draw_rng(case.seed or 0, case.task, case.draw or 0, redraws)
            offset = np.deg2rad(rng.uniform(-case.start_deg, case.start_deg, task.n))
        try:
            eq = find_equilibrium(
                model, task.start + offset, task.active, contact=contact, foot=foot, q_min=q_min, q_max=q_max
            )
        except ValueError as err:
            last = str(err)
            continue
        if eq.moved <= case.max_move:
            start = dataclasses.replace(task, start=np.asarray(eq.q))
            return start, {"start_moved": float(eq.moved), "redraws": redraws}
        last = f"the nearest equilibrium lies {eq.moved:.3g} rad away (max_move {case.max_move:g})"
    raise RuntimeError(f"start posture: no steady-foot equilibrium in {case.max_redraws + 1} draws ({last})")


def solve_case(case: Case, out_dir: pathlib.Path) -> dict[str, Any]:
    """The solve of one case: its row fields (without the case's own parameters)."""
    kwargs = base_problem(case)
    factors = dict(case.factors)
    task: Task = kwargs.pop("task")
    if any(k.startswith("body.") for k in factors):
        kwargs["model"] = perturbed_body(kwargs["model"], factors)
    if any(k.startswith("contact.") for k in factors) or case.start_offset is not None:
        kwargs["contact"] = perturbed_contact(kwargs["contact"], factors)
    row: dict[str, Any] = {}
    if case.start_offset is not None:
        body = kwargs["model"] or PlanarChain.humanoid()
        task, fields = perturbed_start(case, task, body, kwargs["contact"], kwargs.get("foot"))
        row.update(fields)
    sol = solve(task, case.scheme, solver=case.solver, weights=perturbed_weights(task, factors), **kwargs)
    report = sol.report()
    path = sol.save(out_dir / "cases" / case.id) if case.save else None
    row.update(
        status=report["status"],
        success=report["success"],
        N=report["N"],
        T=report["T"],
        iterations="+".join(str(i) for i in report["iterations"]),
        iterations_total=sum(report["iterations"]),
        stage_status=" + ".join(report["stage_status"]),
        solve_time_s=sum(report["solve_time_s"]),
        compile_time_s=report["compile_time_s"],
        objective=report["objective"],
        max_constraint_violation=report["max_constraint_violation"],
        peak_torque_Nm=max(report["peaks"]["torque_Nm"]),
        peak_contact_force_body_weights=report["peaks"]["contact_normal_force_body_weights"],
        path=str(path) if path is not None else "",
    )
    return row


def inverse_case(case: Case, out_dir: pathlib.Path) -> dict[str, Any]:
    """One weight fit from the random start ``case.start_seed`` (``fit_task_weights``) on the case's
    task, a key or a task file; the full result goes to ``out_dir/cases/<id>/fit.json``."""
    task: str | Problem = case.task
    if case.task_path is not None:  # a task file: its body, laws, weights and guess
        task = problem_from_settings(base_problem(case), case.scheme, int(case.N or 15))
    fit = fit_task_weights(
        task,
        int(case.N or 15),
        float(case.T or 5.0),
        case.scheme,
        case.method or "gn",
        int(case.start_seed or 0),
        case.max_evals,
    )
    folder = out_dir / "cases" / case.id
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "fit.json").write_text(json.dumps(fit, indent=1) + "\n")
    return {
        "status": "fitted",
        "success": True,
        "iterations_total": fit["solves"],
        "solve_time_s": fit["solve_wall_s"] + fit["sensitivity_wall_s"],
        "objective": fit["loss_final"],
        "loss_initial": fit["loss_initial"],
        "loss_final": fit["loss_final"],
        "max_rel_weight_error": fit["max_rel_weight_error"],
        "max_abs_q_error_rad": fit["max_abs_q_error_rad"],
        "w_recovered": json.dumps(fit["w_recovered"]),
        "path": str(folder / "fit.json"),
    }


def case_fields(case: Case) -> dict[str, Any]:
    """The row fields that come from the case itself."""
    return {
        "id": case.id,
        "problem": case.problem,
        "kind": case.kind,
        "task": case.task,
        "scheme": case.scheme,
        "solver": case.solver,
        "N": case.N,
        "T": case.T,
        "N1": case.N1,
        "draw": case.draw,
        "method": case.method,
        "start_seed": case.start_seed,
        "options": json.dumps(dict(case.options)) if case.options else "",
        **dict(case.factors),
    }


def run_case(case: Case, out_dir, cache: bool = True) -> dict[str, Any]:
    """Run one case (a worker's job): its row, with ``status``, ``success`` and ``error``, the wall
    time, the worker (host:pid) and the warnings the solve raised. ``cache``: use the persistent
    compilation cache (``runtime.enable_compilation_cache``; a worker is a fresh process)."""
    if cache:
        enable_compilation_cache()
    out_dir = pathlib.Path(out_dir)
    row = {**case_fields(case), "error": "", "worker": f"{socket.gethostname()}:{os.getpid()}"}
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            row.update(solve_case(case, out_dir) if case.kind == "solve" else inverse_case(case, out_dir))
        except Exception as exc:  # a failed case is a row of the study, not the end of it
            row.update(status="error", success=False, error=f"{type(exc).__name__}: {exc}")
    row["wall_time_s"] = time.perf_counter() - t0
    row["warnings"] = " | ".join(dict.fromkeys(str(w.message) for w in caught))
    return row


def crashed_row(case: Case, message: str) -> dict[str, Any]:
    """The row of a case whose worker died (or that never came back from the engine)."""
    return {**case_fields(case), "status": "crashed", "success": False, "error": message}
