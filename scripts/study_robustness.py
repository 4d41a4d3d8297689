"""Study: robustness of A,F+C,2S over perturbed problems around each task family, for every backend.

    OMP_NUM_THREADS=1 python scripts/study_robustness.py [--per-family 40] [--tasks T1,T2,T3,T4]
        [--solvers ipopt,ipm,casadi] [--n-set 50,75,100,125,150] [--seed 0] [--workers 1]
        [--n1 N1] [--max-move 0.1] [--obj-rtol 1e-6] [--q-atol 1e-4]
        [--out results/robustness.json] [--md docs/robustness.md] [--quiet]
    python scripts/study_robustness.py --summarise results/robustness.json [--md docs/robustness.md]

Problem i of family Tk is drawn from a numpy Generator seeded by (seed, Tk, i), so a problem does
not depend on how many others are drawn or in which order they run. Per problem:

* the four cost-term weights of (7) (w_u as one common factor on the per-joint vector, w_qd, w_dqd,
  w_du) each scaled by a factor log-uniform in [0.5, 2];
* the nominal contact law's kappa, f0, xhat and mu each scaled by a factor uniform in [0.5, 1.5]
  (the law of the dynamic stage; stage 1 keeps the relaxed law);
* N drawn from a small set (each distinct N costs one compilation per worker), T uniform in [4, 6] s;
* the task's start posture moved by a uniform +-2 deg per joint, then projected onto the nearest
  static equilibrium that keeps the foot steady (5) with margin under the drawn law
  (``find_equilibrium`` within the task's joint ranges). When none is found, or the nearest one
  lies more than ``--max-move`` (default 0.1 rad) from the moved posture (then it is another
  posture, not a perturbed start of the family: e.g. a lying start with the hip lifted off the
  ground), every value except N is drawn again; the redraws are counted by reason.

Each problem is solved by every backend; a record per solve keeps the perturbation, the per-stage
statistics, the objective and its terms, peak torques and contact normal force, and the wall time.
Solvers are compared per problem (relative objective difference and max |q_a - q_b| per pair); the
trajectories themselves are not stored. The JSON is rewritten after every finished problem, so an
interrupted run keeps what it has done; ``--summarise`` re-reads it and prints the tables.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import dataclasses
import itertools
import json
import multiprocessing
import os
import pathlib
import platform
import sys
import time
import warnings
import zlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, NamedTuple, TextIO

import numpy as np

import jaxhumanoid
from jaxhumanoid import ContactParams, PlanarChain, Task, Weights, find_equilibrium, get_task, solve

SCHEME = "A,F+C,2S"
BACKENDS = ("ipopt", "ipm", "casadi")
N_SET = (50, 75, 100, 125, 150)
WEIGHT_RANGE = (0.5, 2.0)  # log-uniform factor on each cost-term weight
CONTACT_SPREAD = 0.5  # each contact parameter scaled by a factor uniform in [1 - spread, 1 + spread]
T_RANGE = (4.0, 6.0)  # s
START_SPREAD_DEG = 2.0  # per-joint uniform offset of the start posture before the projection
MAX_REDRAWS = 50
MAX_MOVE = 0.1  # rad: the farthest the projection may move the perturbed start posture (max norm)
WEIGHT_NAMES = ("w_u", "w_qd", "w_dqd", "w_du")
CONTACT_NAMES = ("kappa", "f0", "xhat", "mu")
OBJ_RTOL = 1e-6
Q_ATOL = 1e-4  # rad


# -- sampling ------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Perturbation:
    """One perturbed problem of a task family.

    weight_factors / contact_factors: the drawn factors by name; weights: the (n + 3,) weights of
    (7) they give (w_u1..w_un, w_qd, w_dqd, w_du); contact: the drawn law by name; start_offset:
    the drawn joint offsets (rad, before the projection); start: the projected start posture (rad);
    start_moved: max |start - (task start + offset)| (rad); redraws: rejected draws before this
    one, ``rejected`` the same by reason (no equilibrium found, equilibrium too far).
    """

    family: str
    index: int
    seed: int
    weight_factors: dict[str, float]
    weights: tuple[float, ...]
    contact_factors: dict[str, float]
    contact: dict[str, float]
    N: int
    T: float
    start_offset: tuple[float, ...]
    start: tuple[float, ...]
    start_moved: float
    redraws: int
    rejected: dict[str, int]

    def task(self, base: Task) -> Task:
        """The family's task with the projected start posture."""
        return dataclasses.replace(base, start=np.asarray(self.start))

    def law(self) -> ContactParams:
        """The contact law of the dynamic stage."""
        return ContactParams(**self.contact)

    def cost_weights(self) -> Weights:
        """The weights of (7) as a ``Weights`` (per-joint w_u)."""
        w = self.weights
        return Weights(w_u=tuple(w[:-3]), w_qd=w[-3], w_dqd=w[-2], w_du=w[-1])


def family_id(key: str) -> int:
    """A stable integer for a family key (part of every problem's seed)."""
    return zlib.crc32(key.encode())


def sample_N(family: str, seed: int, index: int, n_set: Sequence[int] = N_SET) -> int:
    """The grid size of a problem, from its own generator stream: known without the projection,
    so that jobs can be grouped by N before they run."""
    rng = np.random.default_rng([seed, family_id(family), index, 0])
    return int(rng.choice(np.asarray(sorted(n_set))))


def sample_problem(
    task: Task,
    seed: int,
    index: int,
    n_set: Sequence[int] = N_SET,
    body: PlanarChain | None = None,
    max_redraws: int = MAX_REDRAWS,
    max_move: float = MAX_MOVE,
) -> Perturbation:
    """Problem ``index`` of the family ``task`` (see the module docstring). Raises RuntimeError
    when no draw in 1 + ``max_redraws`` admits a steady-foot equilibrium within ``max_move`` (rad)
    of the moved start."""
    body = PlanarChain.humanoid() if body is None else body
    rng = np.random.default_rng([seed, family_id(task.key), index, 1])
    base_w = task.weights.as_array(task.n)
    nominal = ContactParams.nominal()
    q_min, q_max = task.joint_ranges(body)
    N = sample_N(task.key, seed, index, n_set)
    last_error = ""
    rejected = {"no_equilibrium": 0, "moved_too_far": 0}
    for redraws in range(max_redraws + 1):
        wf = np.exp(rng.uniform(np.log(WEIGHT_RANGE[0]), np.log(WEIGHT_RANGE[1]), len(WEIGHT_NAMES)))
        cfac = rng.uniform(1.0 - CONTACT_SPREAD, 1.0 + CONTACT_SPREAD, len(CONTACT_NAMES))
        T = float(rng.uniform(*T_RANGE))
        offset = np.deg2rad(rng.uniform(-START_SPREAD_DEG, START_SPREAD_DEG, task.n))
        contact = {k: float(getattr(nominal, k)) * float(f) for k, f in zip(CONTACT_NAMES, cfac)}
        guess = task.start + offset
        try:
            eq = find_equilibrium(body, guess, task.active, contact=ContactParams(**contact), q_min=q_min, q_max=q_max)
        except ValueError as exc:
            last_error = str(exc)
            rejected["no_equilibrium"] += 1
            continue
        if eq.moved > max_move:
            last_error = f"the nearest equilibrium lies {eq.moved:.3f} rad away"
            rejected["moved_too_far"] += 1
            continue
        factor_per_weight = np.concatenate([np.full(task.n, wf[0]), wf[1:]])
        return Perturbation(
            family=task.key,
            index=int(index),
            seed=int(seed),
            weight_factors={k: float(f) for k, f in zip(WEIGHT_NAMES, wf)},
            weights=tuple(float(w) for w in base_w * factor_per_weight),
            contact_factors={k: float(f) for k, f in zip(CONTACT_NAMES, cfac)},
            contact=contact,
            N=N,
            T=T,
            start_offset=tuple(float(x) for x in offset),
            start=tuple(float(x) for x in eq.q),
            start_moved=float(eq.moved),
            redraws=redraws,
            rejected=rejected,
        )
    raise RuntimeError(
        f"{task.key} problem {index}: no steady-foot equilibrium in {max_redraws + 1} draws ({last_error})"
    )


# -- solving -------------------------------------------------------------------------------------


class Outcome(NamedTuple):
    """What the comparison of solvers needs from one solve: success, objective, q (N+1, n) or None."""

    success: bool
    objective: float
    q: np.ndarray | None


def _stage_record(stage) -> dict[str, Any]:
    return {
        "name": stage.name,
        "status": stage.status,
        "success": bool(stage.success),
        "iterations": int(stage.iterations),
        "solve_time_s": float(stage.solve_time_s),
        "compile_time_s": float(stage.compile_time_s),
        "objective": float(stage.objective),
        "attempts": int(stage.attempts),
    }


def solve_one(base: Task, pert: Perturbation, solver: str, N1: int | None = None) -> tuple[dict[str, Any], Outcome]:
    """One solve of a perturbed problem by one backend: its record and its outcome. Any exception
    is recorded as a failure with its message; warnings raised by the solve are recorded too."""
    record: dict[str, Any] = {"family": pert.family, "index": pert.index, "solver": solver}
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            sol = solve(
                pert.task(base),
                SCHEME,
                solver=solver,
                N=pert.N,
                T=pert.T,
                N1=N1,
                weights=pert.cost_weights(),
                contact=pert.law(),
            )
        except Exception as exc:  # a failed solve is a result of the study, not a reason to stop it
            record.update(
                success=False,
                error=f"{type(exc).__name__}: {exc}",
                stages=[],
                objective=None,
                objective_terms=None,
                peak_torque=None,
                peak_normal_force=None,
                wall_time_s=time.perf_counter() - t0,
                warnings=[str(w.message) for w in caught],
            )
            return record, Outcome(False, float("nan"), None)
    record.update(
        success=bool(sol.success),
        error=None,
        stages=[_stage_record(s) for s in sol.stages],
        objective=float(sol.objective),
        objective_terms={k: float(v) for k, v in sol.objective_terms.items()},
        peak_torque=[float(x) for x in np.max(np.abs(sol.u), axis=0)],
        peak_normal_force=float(np.max(sol.f_contact[..., 1])),
        wall_time_s=time.perf_counter() - t0,
        warnings=[str(w.message) for w in caught],
    )
    return record, Outcome(bool(sol.success), float(sol.objective), np.asarray(sol.q))


def agreement(outcomes: Mapping[str, Outcome], obj_rtol: float = OBJ_RTOL, q_atol: float = Q_ATOL) -> dict[str, Any]:
    """Pairwise comparison of the solvers on one problem: relative objective difference
    |J_a - J_b| / max(|J_a|, |J_b|) and max |q_a - q_b| (rad) per pair. ``agrees``: every solver
    succeeded and every pair is within both thresholds (with one solver: it succeeded)."""
    pairs = []
    agrees = all(o.success for o in outcomes.values())
    for (a, oa), (b, ob) in itertools.combinations(outcomes.items(), 2):
        if oa.q is None or ob.q is None or np.shape(oa.q) != np.shape(ob.q):
            rel, dq = None, None
        else:
            scale = max(abs(oa.objective), abs(ob.objective), 1e-300)
            rel = float(abs(oa.objective - ob.objective) / scale)
            dq = float(np.max(np.abs(oa.q - ob.q)))
        within = rel is not None and dq is not None and bool(rel <= obj_rtol and dq <= q_atol)
        agrees = agrees and within
        pairs.append({"a": a, "b": b, "rel_objective": rel, "max_dq": dq, "within": within})
    return {"pairs": pairs, "agrees": bool(agrees), "obj_rtol": obj_rtol, "q_atol": q_atol}


def solve_problem(
    family: str,
    index: int,
    seed: int,
    solvers: Sequence[str] = BACKENDS,
    n_set: Sequence[int] = N_SET,
    N1: int | None = None,
    obj_rtol: float = OBJ_RTOL,
    q_atol: float = Q_ATOL,
    max_move: float = MAX_MOVE,
) -> dict[str, Any]:
    """Problem ``index`` of ``family``: drawn, solved by every solver, compared. The job a worker
    runs; returns a JSON-ready dict (no trajectories)."""
    t0 = time.perf_counter()
    base = get_task(family)
    try:
        pert = sample_problem(base, seed, index, n_set, max_move=max_move)
    except Exception as exc:  # recorded like a failed solve: the study goes on
        return {
            "family": family,
            "index": index,
            "error": f"{type(exc).__name__}: {exc}",
            "perturbation": None,
            "records": [],
            "agreement": {"pairs": [], "agrees": False, "obj_rtol": obj_rtol, "q_atol": q_atol},
            "wall_time_s": time.perf_counter() - t0,
        }
    records, outcomes = [], {}
    for solver in solvers:
        record, outcome = solve_one(base, pert, solver, N1)
        record["perturbation"] = dataclasses.asdict(pert)
        records.append(record)
        outcomes[solver] = outcome
    return {
        "family": family,
        "index": index,
        "error": None,
        "perturbation": dataclasses.asdict(pert),
        "records": records,
        "agreement": agreement(outcomes, obj_rtol, q_atol),
        "wall_time_s": time.perf_counter() - t0,
    }


# -- scheduling ----------------------------------------------------------------------------------


def plan_workers(jobs: Sequence[tuple[str, int, int]], workers: int) -> list[list[tuple[str, int, int]]]:
    """Split jobs (family, index, N) over ``workers`` queues so that a queue holds few distinct N
    (each costs a compilation): one group per N, the largest groups halved while there are fewer
    groups than workers, then the groups dealt out largest first (cost: the sum of N) to the
    least loaded queue. Jobs keep their order within a group."""
    groups = [[j for j in jobs if j[2] == n] for n in sorted({j[2] for j in jobs})]
    while len(groups) < workers and max(len(g) for g in groups) > 1:
        big = max(groups, key=len)
        groups.remove(big)
        groups += [big[: len(big) // 2], big[len(big) // 2 :]]
    queues: list[list[tuple[str, int, int]]] = [[] for _ in range(max(1, min(workers, len(groups))))]
    load = [0] * len(queues)
    for group in sorted(groups, key=lambda g: -sum(j[2] for j in g)):
        k = int(np.argmin(load))
        queues[k] += group
        load[k] += sum(j[2] for j in group)
    return queues


# -- summary -------------------------------------------------------------------------------------


def _spread(values: Iterable[float]) -> dict[str, float] | None:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return None
    return {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max()), "n": int(v.size)}


def summarise(problems: Sequence[Mapping[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """Per family and solver: solves, successes, success rate, and median/min/max of the stage-1
    and stage-2 iterations and the solve time (both stages; over the solves that returned) and of
    the objective (over the successful solves). Per family: problems, problems on which all
    solvers agree and their fraction, redraws of the sampling, problems whose sampling failed."""
    families = list(dict.fromkeys(p["family"] for p in problems))
    solvers = list(dict.fromkeys(r["solver"] for p in problems for r in p["records"]))
    rows, agree_rows = [], []
    for fam in families:
        probs = [p for p in problems if p["family"] == fam]
        for solver in solvers:
            recs = [r for p in probs for r in p["records"] if r["solver"] == solver]
            if not recs:
                continue
            ran = [r for r in recs if len(r["stages"]) == 2]
            ok = [r for r in recs if r["success"]]
            rows.append(
                {
                    "family": fam,
                    "solver": solver,
                    "solves": len(recs),
                    "succeeded": len(ok),
                    "success_rate": len(ok) / len(recs),
                    "stage1_iterations": _spread(r["stages"][0]["iterations"] for r in ran),
                    "stage2_iterations": _spread(r["stages"][1]["iterations"] for r in ran),
                    "solve_time_s": _spread(sum(s["solve_time_s"] for s in r["stages"]) for r in ran),
                    "objective": _spread(r["objective"] for r in ok),
                }
            )
        agree = sum(bool(p["agreement"]["agrees"]) for p in probs)
        agree_rows.append(
            {
                "family": fam,
                "problems": len(probs),
                "agree": agree,
                "agree_fraction": agree / len(probs),
                "redraws": sum(p["perturbation"]["redraws"] for p in probs if p["perturbation"] is not None),
                "sampling_failed": sum(p["perturbation"] is None for p in probs),
            }
        )
    return {"solvers": rows, "agreement": agree_rows}


def _cell(s: Mapping[str, float] | None, fmt: str) -> str:
    if s is None:
        return "-"
    return f"{s['median']:{fmt}} ({s['min']:{fmt}}-{s['max']:{fmt}})"


def markdown(summary: Mapping[str, Sequence[Mapping[str, Any]]]) -> str:
    """The two summary tables as markdown: medians with (min-max) ranges."""
    lines = [
        "| family | solver | success | stage-1 iterations | stage-2 iterations | solve time (s) | objective |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in summary["solvers"]:
        lines.append(
            f"| {r['family']} | {r['solver']} | {r['succeeded']}/{r['solves']} ({100 * r['success_rate']:.0f}%) "
            f"| {_cell(r['stage1_iterations'], '.0f')} | {_cell(r['stage2_iterations'], '.0f')} "
            f"| {_cell(r['solve_time_s'], '.2f')} | {_cell(r['objective'], '.4g')} |"
        )
    lines += ["", "| family | problems | all solvers agree | redraws | sampling failed |", "|---|---|---|---|---|"]
    for r in summary["agreement"]:
        lines.append(
            f"| {r['family']} | {r['problems']} | {r['agree']}/{r['problems']} ({100 * r['agree_fraction']:.0f}%) "
            f"| {r['redraws']} | {r['sampling_failed']} |"
        )
    return "\n".join(lines) + "\n"


# -- output --------------------------------------------------------------------------------------


def _duration(seconds: float) -> str:
    if not np.isfinite(seconds) or seconds < 0:
        return "?"
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m" if hours else f"{minutes}m{secs:02d}s"


class ProgressLine:
    """One line rewritten in place (carriage return): problems done/total, successes per solver,
    problems on which the solvers agree, elapsed time and ETA (elapsed / done x left)."""

    def __init__(self, total: int, solvers: Sequence[str], quiet: bool = False, stream: TextIO | None = None):
        self.total, self.solvers, self.quiet = total, list(solvers), quiet
        self.stream = sys.stderr if stream is None else stream
        self.t0 = time.perf_counter()
        self.done, self.agree = 0, 0
        self.ok = dict.fromkeys(self.solvers, 0)
        self._width = 0

    def update(self, problem: Mapping[str, Any]) -> None:
        self.done += 1
        self.agree += bool(problem["agreement"]["agrees"])
        for r in problem["records"]:
            self.ok[r["solver"]] = self.ok.get(r["solver"], 0) + bool(r["success"])
        self.show()

    def show(self) -> None:
        if self.quiet:
            return
        elapsed = time.perf_counter() - self.t0
        eta = elapsed / self.done * (self.total - self.done) if self.done else float("nan")
        ok = " ".join(f"{s} {self.ok[s]}/{self.done}" for s in self.solvers)
        line = (
            f"[{self.done}/{self.total}] ok: {ok}  agree {self.agree}/{self.done}  "
            f"elapsed {_duration(elapsed)}  ETA {_duration(eta)}"
        )
        self.stream.write("\r" + line.ljust(self._width))
        self.stream.flush()
        self._width = len(line)

    def close(self) -> None:
        if not self.quiet:
            self.stream.write("\n")
            self.stream.flush()


def write_json(path: pathlib.Path, config: Mapping[str, Any], problems: Mapping[tuple[str, int], Any]) -> None:
    """The study so far, written to a temporary file and renamed, so the file is never half-written."""
    ordered = [problems[k] for k in sorted(problems)]
    data = {"config": dict(config), "problems": ordered, "summary": summarise(ordered)}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(tmp, path)


def _report(summary: Mapping[str, Any], md: str | None) -> None:
    text = markdown(summary)
    print(text, end="")
    if md:
        out = pathlib.Path(md)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("# Robustness of A,F+C,2S over perturbed problems\n\n" + text)
        print(f"wrote {out}")


def _csv(text: str) -> list[str]:
    return [s.strip() for s in text.split(",") if s.strip()]


def run_study(args: argparse.Namespace) -> dict[str, Any]:
    """Draw, solve and compare every problem; rewrite ``args.out`` after each one."""
    kw = {
        "solvers": args.solvers,
        "n_set": args.n_set,
        "N1": args.n1,
        "obj_rtol": args.obj_rtol,
        "q_atol": args.q_atol,
        "max_move": args.max_move,
    }
    if args.workers > 1:
        # Spawned workers inherit the environment at start, before they import JAX (through this
        # module's imports): one OpenMP thread per worker.
        os.environ["OMP_NUM_THREADS"] = "1"
    jobs = [(fam, i, sample_N(fam, args.seed, i, args.n_set)) for fam in args.tasks for i in range(args.per_family)]
    config = {
        "scheme": SCHEME,
        "seed": args.seed,
        "per_family": args.per_family,
        "tasks": args.tasks,
        **kw,
        "weight_range": WEIGHT_RANGE,
        "contact_spread": CONTACT_SPREAD,
        "T_range": T_RANGE,
        "start_spread_deg": START_SPREAD_DEG,
        "workers": args.workers,
        "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
        "jaxhumanoid": jaxhumanoid.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
    }
    out = pathlib.Path(args.out)
    progress = ProgressLine(len(jobs), args.solvers, quiet=args.quiet)
    progress.show()
    problems: dict[tuple[str, int], Any] = {}

    def finished(problem: dict[str, Any]) -> None:
        problems[(problem["family"], problem["index"])] = problem
        write_json(out, config, problems)
        progress.update(problem)

    if args.workers <= 1:
        for fam, i, _ in sorted(jobs, key=lambda j: j[2]):  # one N after another: compiled code is reused
            finished(solve_problem(fam, i, args.seed, **kw))
    else:
        ctx = multiprocessing.get_context("spawn")
        # One single-process pool per queue: a queue's jobs (grouped by N) stay in one process,
        # which keeps its compiled NLPs, while results still come back one problem at a time.
        queues = plan_workers(jobs, args.workers)
        pools = [cf.ProcessPoolExecutor(max_workers=1, mp_context=ctx) for _ in queues]
        futures = {}
        try:
            for pool, queue in zip(pools, queues):
                for fam, i, _ in queue:
                    futures[pool.submit(solve_problem, fam, i, args.seed, **kw)] = (fam, i)
            for fut in cf.as_completed(futures):
                fam, i = futures[fut]
                try:
                    problem = fut.result()
                except Exception as exc:  # a worker that died: its problem is recorded as failed
                    problem = {
                        "family": fam,
                        "index": i,
                        "error": f"{type(exc).__name__}: {exc}",
                        "perturbation": None,
                        "records": [],
                        "agreement": {"pairs": [], "agrees": False, "obj_rtol": args.obj_rtol, "q_atol": args.q_atol},
                        "wall_time_s": None,
                    }
                finished(problem)
        finally:
            for pool in pools:
                pool.shutdown(wait=False, cancel_futures=True)
    progress.close()
    print(f"wrote {out} ({len(problems)} problems)")
    return summarise([problems[k] for k in sorted(problems)])


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-family", type=int, default=40, help="problems per task family")
    ap.add_argument("--tasks", default="T1,T2,T3,T4", help="task families, comma-separated")
    ap.add_argument("--solvers", default=",".join(BACKENDS), help="backends, comma-separated")
    ap.add_argument("--n-set", default=",".join(map(str, N_SET)), help="grid sizes N to draw from, comma-separated")
    ap.add_argument("--n1", type=int, default=None, help="stage-1 intervals (default: solve's, min(30, N))")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1, help="worker processes (spawned)")
    ap.add_argument("--obj-rtol", type=float, default=OBJ_RTOL, help="agreement: max relative objective difference")
    ap.add_argument("--q-atol", type=float, default=Q_ATOL, help="agreement: max |q_a - q_b| (rad)")
    ap.add_argument(
        "--max-move", type=float, default=MAX_MOVE, help="max move (rad) of the start by the equilibrium projection"
    )
    ap.add_argument("--out", default="results/robustness.json")
    ap.add_argument("--md", default=None, help="also write the tables to this markdown file")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    ap.add_argument("--summarise", metavar="JSON", default=None, help="only print the tables of a written study")
    args = ap.parse_args(argv)
    if args.summarise:
        data = json.loads(pathlib.Path(args.summarise).read_text())
        _report(summarise(data["problems"]), args.md)
        return
    args.tasks = _csv(args.tasks)
    args.solvers = _csv(args.solvers)
    try:
        args.tasks = [get_task(t).key for t in args.tasks]
    except ValueError as exc:
        ap.error(f"--tasks: {exc}")
    if not args.solvers or any(s not in BACKENDS for s in args.solvers):
        ap.error(f"--solvers: expected a comma-separated subset of {','.join(BACKENDS)}, got {args.solvers}")
    try:
        args.n_set = sorted({int(n) for n in _csv(args.n_set)})
    except ValueError:
        ap.error(f"--n-set: expected comma-separated integers, got {args.n_set!r}")
    if not args.n_set or min(args.n_set) < 3:
        ap.error("--n-set: expected grid sizes >= 3")
    if not args.max_move > 0:
        ap.error(f"--max-move: expected a positive angle (rad), got {args.max_move}")
    if args.per_family < 1 or args.workers < 1:
        ap.error("--per-family and --workers: expected at least 1")
    _report(run_study(args), args.md)


if __name__ == "__main__":
    main()
