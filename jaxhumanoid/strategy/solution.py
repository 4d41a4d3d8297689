"""A solved trajectory: arrays on the time grid, per-stage solver statistics, save and load.

Shapes (N intervals, N + 1 nodes; a chain of n links with joints O_1..O_n, named in
``geometry["names"]``; the humanoid: knee, hip, shoulder, elbow, hand):

    t            (N+1,)      node times (s)
    q, qd        (N+1, n)    joint angles (rad) and rates (rad/s) at the nodes
    u            (N, n)      joint torques (N m), constant on each interval
    f_contact    (N, n, 2)   contact forces (f_t, f_n) at O_1..O_n at the interval midpoints (N);
                             zero at joints without a modelled contact force
    gaps         (N+1, n)    heights y of O_1..O_n above the ground at the nodes (m)
    foot_reaction (N, 2)     ground reaction on the foot (f_t0, f_n0) at the midpoints (N)
    foot_margins (N, 5)      the five products of (5), >= 0 when the foot stays steady
    warm_start   optional dict {t, q}: the stage-1 solution interpolated onto t (2S only)
    geometry     link lengths "a" (n,), joint "names" (n strings), foot "ankle_height", "a0f",
                 "a0b", friction "mu", link masses "m" (n,) and gravity "g": what the figures and
                 the peak loads need without the model; and what rebuilds the body, the law and the
                 goal box for a simulation (``jaxhumanoid.tracking``): "c", "inertia", "u_max" (n,),
                 "kappa", "f0", "xhat", "goal" (n,), "goal_tolerance" (files saved before these
                 keys existed lack them)
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from typing import Any

import numpy as np

from jaxhumanoid.runtime import environment

ARRAY_FIELDS = ("t", "q", "qd", "u", "f_contact", "gaps", "foot_reaction", "foot_margins")


@dataclasses.dataclass
class StageStats:
    """One NLP solve of a strategy (stage 1 = pseudo-static, stage 2 = dynamic, or the only one)."""

    name: str
    status: str
    success: bool
    iterations: int
    solve_time_s: float
    compile_time_s: float
    objective: float
    max_constraint_violation: float
    n_variables: int
    n_constraints: int
    attempts: int = 1  # solver runs (a stage-1 fallback or a continuation step adds one)
    start_violation: float = float("nan")  # max constraint violation at the stage's start point
    runs: tuple[int, ...] = ()  # iterations of each solver run, in order
    force_limit_lifted: bool = False  # stage 1 solved only without the task's contact-force limit
    strength_factor: float = 1.0  # stage 1 solved only with its torque box (STAGE1_STRENGTH u_max) scaled by this
    law_step: int = 0  # stage 1's law: step j of the path from the relaxed to the nominal law
    guess: str = ""  # stage 1: the initial guess of the run handed over ("" for the other stages)


@dataclasses.dataclass
class Solution:
    task: str
    scheme: str
    solver: str
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    u: np.ndarray
    f_contact: np.ndarray
    gaps: np.ndarray
    foot_reaction: np.ndarray
    foot_margins: np.ndarray
    objective: float
    objective_terms: dict[str, float]
    stages: list[StageStats]
    active: tuple[int, ...]
    geometry: dict[str, Any]
    warm_start: dict[str, np.ndarray] | None = None

    @property
    def success(self) -> bool:
        return all(s.success for s in self.stages)

    @property
    def status(self) -> str:
        return self.stages[-1].status

    @property
    def n_links(self) -> int:
        return int(np.shape(self.q)[1])

    def peaks(self) -> dict[str, Any]:
        """Peak loads of the motion: |u_i| per joint (N m), the largest normal force at each joint
        O_1..O_n and on the foot (N), and the largest contact normal force over the body in units
        of body weight M g (the foot excluded)."""
        body_weight = float(np.sum(self.geometry["m"]) * self.geometry["g"]) if "m" in self.geometry else np.nan
        f_n = np.asarray(self.f_contact)[..., 1]
        return {
            "torque_Nm": np.abs(np.asarray(self.u)).max(axis=0).tolist(),
            "contact_normal_force_N": f_n.max(axis=0).tolist(),
            "foot_normal_force_N": float(np.asarray(self.foot_reaction)[:, 1].max()),
            "contact_normal_force_body_weights": float(f_n.max()) / body_weight,
        }

    def report(self) -> dict[str, Any]:
        """The report.json record (the fields the CLI and table2 promise)."""
        last = self.stages[-1]
        return {
            "task": self.task,
            "scheme": self.scheme,
            "solver": self.solver,
            "success": bool(self.success),
            "status": last.status,
            "stage_status": [s.status for s in self.stages],
            "iterations": [int(s.iterations) for s in self.stages],
            "solve_time_s": [float(s.solve_time_s) for s in self.stages],
            "compile_time_s": float(sum(s.compile_time_s for s in self.stages)),
            "objective": float(self.objective),
            "objective_terms": {k: float(v) for k, v in self.objective_terms.items()},
            "n_variables": int(last.n_variables),
            "n_constraints": int(last.n_constraints),
            "max_constraint_violation": float(last.max_constraint_violation),
            "N": int(self.t.size - 1),
            "T": float(self.t[-1] - self.t[0]),
            "active_contacts": list(self.active),
            "n_links": self.n_links,
            "peaks": self.peaks(),
            "stages": [dataclasses.asdict(s) for s in self.stages],
        }

    def save(self, out_dir) -> pathlib.Path:
        """Write ``solution.npz`` and ``report.json`` into ``out_dir`` (created if missing)."""
        out = pathlib.Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        arrays = {k: np.asarray(getattr(self, k)) for k in ARRAY_FIELDS}
        if self.warm_start is not None:
            arrays.update({f"warm_start_{k}": np.asarray(v) for k, v in self.warm_start.items()})
        np.savez(out / "solution.npz", **arrays)  # type: ignore[arg-type]  # numpy stubs type **kwds as bool
        meta = self.report()
        meta["geometry"] = {k: np.asarray(v).tolist() for k, v in self.geometry.items()}
        meta["environment"] = environment()  # these NLPs are chaotic: what the bits depend on
        (out / "report.json").write_text(json.dumps(meta, indent=2) + "\n")
        return out

    @classmethod
    def load(cls, out_dir) -> Solution:
        out = pathlib.Path(out_dir)
        report_path, npz_path = out / "report.json", out / "solution.npz"
        for path in (report_path, npz_path):
            if not path.is_file():
                raise FileNotFoundError(f"{path} not found: expected a directory written by Solution.save")
        meta = json.loads(report_path.read_text())
        with np.load(npz_path) as data:
            arrays = {k: data[k] for k in ARRAY_FIELDS}
            warm = {k[len("warm_start_") :]: data[k] for k in data.files if k.startswith("warm_start_")} or None
        return cls(
            task=meta["task"],
            scheme=meta["scheme"],
            solver=meta["solver"],
            objective=meta["objective"],
            objective_terms=meta["objective_terms"],
            stages=[StageStats(**{**s, "runs": tuple(s.get("runs", ()))}) for s in meta["stages"]],
            active=tuple(meta["active_contacts"]),
            geometry={k: tuple(v) if k == "names" else np.asarray(v) for k, v in meta["geometry"].items()},
            warm_start=warm,
            **arrays,
        )
