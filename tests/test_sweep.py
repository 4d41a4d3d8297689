"""Studies: the spec (ids, draws, checks), the table and resume, the engines (a local pool and a
real local Dask cluster, two workers each), failed and crashed cases, the summaries."""

from __future__ import annotations

import csv
import dataclasses
import json
import pathlib
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from jaxhumanoid import get_task
from jaxhumanoid.model.params import PlanarChain
from jaxhumanoid.outputs.cli import main as cli_main
from jaxhumanoid.strategy.posture import margins
from jaxhumanoid.strategy.problem import problem_from_settings
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.studies import Crash, Outcome, Spec, agreement, load_spec, parse_spec, read_table, run_jobs, sweep
from jaxhumanoid.studies.compare import problem_agreement
from jaxhumanoid.studies.engines import plan_queues
from jaxhumanoid.studies.run import base_problem, perturbed_contact, perturbed_start, perturbed_weights
from jaxhumanoid.studies.sweep import select_cases
from jaxhumanoid.studies.table import Table, finished_ids, recovery

ROOT = pathlib.Path(__file__).resolve().parents[1]
SPECS = [ROOT / "examples" / "sweep_small.toml", *sorted((ROOT / "examples" / "studies").glob("*.toml"))]

TINY = {"tasks": ["T3"], "schemes": ["A,F+C,1S"], "solvers": ["ipopt"], "N": [10], "grid": {"weights.w_u": [0.5, 1.0]}}


# -- specs ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", SPECS, ids=lambda p: p.name)
def test_shipped_specs_parse_into_distinct_cases(path):
    spec = load_spec(path)
    ids = [c.id for c in spec.cases]
    assert len(ids) == len(set(ids)) > 0
    assert [c.id for c in load_spec(path).cases] == ids  # stable from run to run


def test_ids_are_hashes_of_the_parameters():
    (a, b) = parse_spec(TINY).cases
    assert a.id != b.id and len(a.id) == 12
    assert a.id == parse_spec(dict(TINY)).cases[0].id
    assert dataclasses.replace(a, task_path="/elsewhere", save=False).id == a.id  # not parameters
    assert dataclasses.replace(a, N=11).id != a.id
    two = parse_spec({**TINY, "solvers": ["ipopt", "ipm"]}).cases
    assert [c.problem for c in two] == [a.problem, a.problem, b.problem, b.problem]
    assert len({c.id for c in two}) == 4


@pytest.mark.parametrize(
    "record, spec",
    [
        ("robustness_ipopt_ipm", "robustness"),
        ("robustness_casadi_draws16", "robustness"),
        ("robustness_N1_50", "robustness_N1_50"),
        ("robustness_force_limit_draws20", "robustness_force_limit"),
        ("robustness_scaling_draws3", "robustness_scaling"),
        ("robustness_static_path_draws10", "robustness_static_path"),
        ("robustness_default_draws10", "robustness"),
        ("robustness_default_draws40", "robustness"),
        ("robustness_inverse_dynamics_draws10", "robustness"),
        ("robustness_inverse_dynamics_draws40", "robustness"),
        ("inverse_multistart", "inverse_multistart"),
    ],
)
def test_every_recorded_case_is_a_case_its_spec_draws_here(record, spec):
    # a case's id hashes its drawn values: a draw that rounds its last bit differently on this CPU
    # than on the one that made the record would give another id (and, the NLPs being chaotic,
    # possibly another result), so the records would not be reproducible here
    rows = read_table(ROOT / "docs" / "studies" / f"{record}_cases.csv")
    ids = {c.id: c for c in load_spec(ROOT / "examples" / "studies" / f"{spec}.toml").cases}
    assert rows and all(r["id"] in ids for r in rows)
    assert all((ids[r["id"]].task, ids[r["id"]].draw) == (r["task"], r["draw"]) for r in rows)


@pytest.mark.parametrize("key, value", [("scaling", "physical"), ("guess", "static_path"), ("guess", "both")])
def test_a_spec_setting_reaches_the_solve_and_an_unset_one_keeps_the_ids(key, value):
    (a, _) = parse_spec(TINY).cases
    (scaled, _) = parse_spec({**TINY, key: value}).cases
    # an unset setting is not a parameter: the shipped robustness spec keeps its recorded ids, drawn
    # bit for bit on this CPU as on the one that made the record (``spec.sample``)
    rows = read_table(ROOT / "docs" / "studies" / "robustness_ipopt_ipm_cases.csv")
    spec = select_cases(load_spec(ROOT / "examples" / "studies" / "robustness.toml"), solvers=("ipopt", "ipm"))
    assert sorted(c.id for c in spec.cases) == sorted(r["id"] for r in rows)
    assert scaled.id != a.id and scaled.problem != a.problem
    assert key not in a.params() and scaled.params()[key] == value
    assert getattr(base_problem(scaled)["settings"], key) == value
    assert base_problem(a)["settings"] == SolveSettings()  # the package's defaults


def test_stage1_options_reach_the_solve_on_top_of_a_task_files_and_unset_keep_the_ids(tmp_path):
    (a, _) = parse_spec(TINY).cases
    (b, _) = parse_spec({**TINY, "stage1_options": {"mu_init": 1e-2}}).cases
    assert "stage1_options" not in a.params() and b.params()["stage1_options"] == {"mu_init": 1e-2}
    assert b.id != a.id and b.problem != a.problem
    assert base_problem(a)["settings"].stage1_options is None
    assert dict(base_problem(b)["settings"].stage1_options) == {"mu_init": 1e-2}
    file = tmp_path / "T1.toml"
    text = (ROOT / "examples" / "paper" / "T1.toml").read_text()
    file.write_text(text.replace("\n[solve]\n", "\n[solve]\nstage1_options = { tol = 1e-6, mu_init = 0.1 }\n"))
    on_file = dataclasses.replace(b, task_path=str(file))
    assert dict(base_problem(on_file)["settings"].stage1_options) == {"tol": 1e-6, "mu_init": 1e-2}


def test_bad_stage1_options_are_rejected_before_any_work(tmp_path):
    spec = parse_spec({**TINY, "stage1_options": {"mu_init": "abc"}})
    with pytest.raises(ValueError, match="^stage1_options: "):
        sweep(spec, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_random_draws_are_reproducible_and_independent_of_their_number():
    random = {"seed": 3, "start_deg": 2.0, "contact.mu": {"uniform": [0.5, 1.5]}, "N": {"choice": [10, 20]}}
    spec = {k: v for k, v in TINY.items() if k not in ("N", "grid")}
    few = parse_spec({**spec, "random": {**random, "draws": 3}}).cases
    many = parse_spec({**spec, "random": {**random, "draws": 8}}).cases
    assert few == many[:3]
    assert len({c.factors for c in many}) == 8
    assert {c.N for c in many} == {10, 20}
    for c in many:
        ((name, f),) = c.factors
        assert name == "contact.mu" and 0.5 <= f <= 1.5
        assert np.max(np.abs(c.start_offset)) <= np.deg2rad(2.0)
    other_seed = parse_spec({**spec, "random": {**random, "seed": 4, "draws": 3}}).cases
    assert other_seed[0].factors != few[0].factors


@pytest.mark.parametrize(
    "change, field",
    [
        ({"tasks": ["T9"]}, "tasks[0]"),
        ({"solvers": ["snopt"]}, "solvers"),
        ({"schemes": ["A,X,1S"]}, "schemes"),
        ({"N": [2]}, "N"),
        ({"T": [-1.0]}, "T"),
        ({"colour": "red"}, "colour"),
        ({"grid": {"weights.w_x": [1.0]}}, "grid.weights.w_x"),
        ({"grid": {"contact.mu": [0.0]}}, "grid.contact.mu"),
        ({"random": {"draws": 0}}, "random.draws"),
        ({"random": {"contact.mu": {"normal": [1, 2]}}}, "random.contact.mu"),
        ({"random": {"contact.mu": {"uniform": [2.0, 1.0]}}}, "random.contact.mu.uniform"),
        ({"random": {"N": {"choice": [10]}}}, "N"),
        ({"random": {"weights.w_u": {"uniform": [0.5, 2.0]}}}, "random.weights.w_u"),
        ({"random": {"start_deg": "2"}}, "random.start_deg"),
        ({"kind": "table"}, "kind"),
        ({"scaling": "si"}, "scaling"),
        ({"guess": "zero"}, "guess"),
        ({"stage1_options": 1e-2}, "stage1_options"),
        ({"kind": "inverse", "methods": ["newton"], "grid": None}, "methods"),
    ],
)
def test_bad_fields_are_rejected_naming_the_field(change, field):
    data = {k: v for k, v in {**TINY, **change}.items() if v is not None}
    if data.get("kind") == "inverse":
        data = {k: v for k, v in data.items() if k not in ("grid", "solvers")}
    with pytest.raises(ValueError, match="^" + re.escape(field)):
        parse_spec(data)


def test_an_inverse_study_fits_on_task_files_with_their_posing():
    spec = load_spec(ROOT / "examples" / "studies" / "inverse_multistart.toml")
    case = spec.cases[0]
    assert case.kind == "inverse" and case.task_path is not None and case.task_path.endswith("T1.toml")
    problem = problem_from_settings(base_problem(case), case.scheme, int(case.N))
    assert problem.layout.N == 15 and np.all(problem.model.u_max == 1000.0)  # the paper's box, not a strength


def test_a_spec_file_error_names_the_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('tasks = ["T3"]\nsolvers = ["nope"]\n')
    with pytest.raises(ValueError, match="bad.toml: solvers"):
        load_spec(path)
    assert cli_main(["sweep", str(path), "--out", str(tmp_path / "out")]) == 2


# -- perturbations --------------------------------------------------------------------------------


def test_a_part_of_a_study_keeps_the_ids_of_the_whole():
    spec = load_spec(ROOT / "examples" / "studies" / "robustness.toml")
    part = select_cases(spec, solvers=["ipopt", "ipm"], draws=8)
    assert len(part.cases) == 4 * 8 * 2 == len(spec.cases) * 2 // (3 * 5)
    assert {c.solver for c in part.cases} == {"ipopt", "ipm"} and max(c.draw for c in part.cases) == 7
    assert {c.id for c in part.cases} < {c.id for c in spec.cases}
    assert select_cases(spec).cases == spec.cases
    with pytest.raises(ValueError, match=r"--solvers: \['snopt'\] not among the spec's solvers"):
        select_cases(spec, solvers=["ipopt", "snopt"])
    with pytest.raises(ValueError, match="--draws: expected an integer >= 1"):
        select_cases(spec, draws=0)
    with pytest.raises(ValueError, match="--draws: the spec has no"):
        select_cases(parse_spec(TINY), draws=2)


def test_perturbations_scale_the_task_values():
    task = get_task("T3")
    w = perturbed_weights(task, {"weights.w_u": 2.0, "weights.w_du": 0.5})
    np.testing.assert_allclose(w, task.weights.as_array(5) * [2, 2, 2, 2, 2, 1, 1, 0.5], rtol=1e-15)
    law = perturbed_contact(None, {"contact.mu": 0.8})
    assert (law.mu, law.kappa) == (pytest.approx(0.8), 1e5)


def test_a_perturbed_start_is_a_nearby_static_equilibrium():
    (case,) = parse_spec({**TINY, "grid": {}, "random": {"draws": 1, "start_deg": 2.0}}).cases
    task, body = get_task("T3"), PlanarChain.humanoid()
    law = perturbed_contact(None, {})
    moved, fields = perturbed_start(case, task, body, law, None)
    assert margins(body, moved.start, task.active, contact=law).ok
    assert fields["start_moved"] == pytest.approx(np.max(np.abs(moved.start - task.start - case.start_offset)))
    assert fields["start_moved"] <= case.max_move and fields["redraws"] == 0
    with pytest.raises(RuntimeError, match="2 draws"):
        perturbed_start(dataclasses.replace(case, max_move=1e-12, max_redraws=1), task, body, law, None)


# -- tables and summaries -------------------------------------------------------------------------


def test_resume_skips_finished_cases_and_retries_failed_ones_on_request():
    rows = [{"id": "a", "success": False}, {"id": "b", "success": True}, {"id": "a", "success": True}]
    assert finished_ids(rows) == {"a", "b"}
    assert finished_ids(rows[:2], retry_failed=True) == {"b"}


def test_ids_that_look_like_numbers_read_back_as_text(tmp_path):
    """A hex id such as 67257e895274 parses as a float (inf) and 123456789012 as an int: read
    back as numbers, those cases would never count as finished and a resume would re-run them."""
    ids = ["67257e895274", "123456789012", "0a1b2c3d4e5f"]
    table = Table(tmp_path / "cases.csv", ["id", "problem", "success", "objective"])
    for i in ids:
        table.append({"id": i, "problem": i, "success": True, "objective": 1.5})
    rows = read_table(tmp_path / "cases.csv")
    assert [r["id"] for r in rows] == ids and [r["problem"] for r in rows] == ids
    assert finished_ids(rows) == set(ids) and rows[0]["objective"] == 1.5 and rows[0]["success"] is True


def test_recovery_rate_and_best_start():
    rows = [
        {"start_seed": 0, "success": True, "loss_final": 1e-20, "max_rel_weight_error": 1e-9},
        {"start_seed": 1, "success": True, "loss_final": 8.2, "max_rel_weight_error": 0.9},
        {"start_seed": 2, "success": False, "loss_final": None, "max_rel_weight_error": None},
    ]
    r = recovery(rows, 1e-3)
    assert (r["recovered"], r["recovery_rate"], r["recovered_seeds"]) == (1, 1 / 3, [0])
    assert (r["best_seed"], r["best_recovers"]) == (0, True)
    assert not recovery(rows[1:], 1e-3)["best_recovers"]


def test_agreement_flags_a_moved_trajectory():
    rng = np.random.default_rng(0)
    q = rng.standard_normal((21, 5))
    same = {"ipopt": Outcome(True, 2.5, q), "ipm": Outcome(True, 2.5 * (1 + 1e-9), q + 1e-7)}
    result = agreement(same)
    assert result["agrees"]
    assert result["pairs"][0]["max_dq"] == pytest.approx(1e-7)
    moved = q.copy()
    moved[7, 2] += 1e-3
    result = agreement({**same, "casadi": Outcome(True, 2.5, moved)})
    assert not result["agrees"]
    assert [p["within"] for p in result["pairs"]] == [True, False, False]
    assert not agreement({**same, "casadi": Outcome(True, 2.5 * (1 + 1e-5), q)})["agrees"]
    assert not agreement({**same, "casadi": Outcome(False, float("nan"), None)})["agrees"]
    assert agreement({"ipopt": Outcome(True, 1.0, q)})["agrees"]


# -- engines and whole studies --------------------------------------------------------------------


def tiny_study() -> Spec:
    """Two solves of T3 at N = 10 and a case that raises in its worker (its start cannot be
    projected within max_move)."""
    good = parse_spec(TINY)
    (raising,) = parse_spec({**TINY, "grid": {}, "random": {"draws": 1, "start_deg": 2.0}}).cases
    raising = dataclasses.replace(raising, max_move=1e-12, max_redraws=0)
    return dataclasses.replace(good, cases=(*good.cases, raising), name="tiny")


def _rows(path: pathlib.Path) -> list[dict]:
    return read_table(path / "cases.csv")


def test_local_pool_records_a_raising_case_and_resumes(tmp_path):
    spec = tiny_study()
    out = tmp_path / "study"
    summary = sweep(spec, out, workers=2, quiet=True)
    assert (summary["n_cases"], summary["n_finished"], summary["n_errors"], summary["run_cases"]) == (3, 3, 1, 3)
    assert (summary["engine"], summary["workers"]) == ("local", 2)
    rows = {r["id"]: r for r in _rows(out)}
    bad = rows[spec.cases[2].id]
    assert (bad["status"], bad["success"]) == ("error", False) and "start posture" in bad["error"]
    for case in spec.cases[:2]:
        row = rows[case.id]
        assert row["error"] is None and row["iterations_total"] > 0 and row["N"] == 10
        assert row["status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Infeasible_Problem_Detected")
        assert (pathlib.Path(row["path"]) / "solution.npz").is_file()
    assert summary["per_solver"]["ipopt"]["cases"] == 3
    assert json.loads((out / "summary.json").read_text())["n_cases"] == 3

    again = sweep(spec, out, workers=2, quiet=True)  # nothing left: no solve, no new row
    assert (again["run_cases"], again["skipped_finished"], len(_rows(out))) == (0, 3, 3)

    with (out / "cases.csv").open() as fh:  # as if interrupted before the last good case finished
        lines = [ln for ln in fh if spec.cases[1].id not in ln]
    (out / "cases.csv").write_text("".join(lines))
    resumed = sweep(spec, out, workers=2, quiet=True)
    assert (resumed["run_cases"], resumed["n_finished"]) == (1, 3)
    assert sorted(r["id"] for r in _rows(out)) == sorted(c.id for c in spec.cases)


def test_a_worker_that_dies_is_a_crash_and_the_rest_finish():
    # eval pickles by reference: one job kills its worker process, the other computes
    jobs = [("dies", ("__import__('os')._exit(3)",)), ("lives", ("6 * 7",))]
    results = dict(run_jobs(eval, jobs, engine="local", workers=2))
    assert isinstance(results["dies"], Crash) and "died" in results["dies"].message
    assert results["lives"] == 42


def test_dask_local_cluster_runs_a_study(tmp_path):
    pytest.importorskip("distributed")
    spec = tiny_study()
    spec = dataclasses.replace(spec, cases=spec.cases[1:])  # one solve and the raising case
    summary = sweep(spec, tmp_path / "dask", engine="dask", workers=2, quiet=True)
    assert (summary["engine"], summary["n_finished"], summary["n_errors"]) == ("dask", 2, 1)
    (solved,) = [r for r in _rows(tmp_path / "dask") if r["error"] is None]
    assert solved["id"] == spec.cases[0].id and solved["iterations_total"] > 0


def test_dask_reports_a_killed_worker_as_a_crash():
    pytest.importorskip("distributed")
    jobs = [("dies", ("__import__('os')._exit(3)",)), ("lives", ("6 * 7",))]
    results = dict(run_jobs(eval, jobs, engine="dask", workers=2))
    assert isinstance(results["dies"], Crash) and "KilledWorker" in results["dies"].message
    assert results["lives"] == 42


def test_the_cli_checks_its_arguments(tmp_path, capsys):
    spec = ROOT / "examples" / "sweep_small.toml"
    assert cli_main(["sweep", str(spec), "--out", str(tmp_path), "--workers", "0"]) == 2
    assert "--workers" in capsys.readouterr().err
    assert cli_main(["sweep", str(spec), "--out", str(tmp_path), "--address", "tcp://x:1"]) == 2
    assert "--address" in capsys.readouterr().err
    assert cli_main(["sweep", str(spec), "--out", str(tmp_path), "--solvers", "snopt"]) == 2
    assert "--solvers" in capsys.readouterr().err
    (tmp_path / "cases.csv").write_text("id,other\n")
    assert cli_main(["sweep", str(spec), "--out", str(tmp_path)]) == 2
    assert "other columns" in capsys.readouterr().err
    with (tmp_path / "cases.csv").open() as fh:
        assert next(csv.reader(fh)) == ["id", "other"]  # an existing table is never overwritten


def _children(pid: int) -> list[int]:
    out = subprocess.run(["pgrep", "-P", str(pid)], capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


def _alive(pid: int) -> bool:
    try:
        return pathlib.Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not pathlib.Path("/proc").is_dir(), reason="reads /proc")
def test_sigterm_stops_the_sweep_and_its_workers(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text('tasks = ["T3"]\nschemes = ["A,F+C,1S"]\nsolvers = ["ipopt"]\nN = [10, 11, 12, 13]\n')
    cmd = [sys.executable, "-m", "jaxhumanoid", "--no-cache", "sweep", str(spec), "--out", str(tmp_path / "o")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline, workers = time.monotonic() + 60, []
    while not workers and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        workers = _children(proc.pid)
    assert workers, "the sweep started no worker process"
    time.sleep(2.0)  # the worker is importing or solving
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "resumes the study" in err
    deadline = time.monotonic() + 20
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(_alive(w) for w in workers)


def test_problem_agreement_reads_the_saved_trajectories(tmp_path):
    q = np.linspace(0.0, 1.0, 22).reshape(11, 2)
    rows = []
    for solver, dq in (("ipopt", 0.0), ("ipm", 1e-7), ("casadi", 1e-2)):
        (tmp_path / solver).mkdir()
        np.savez(tmp_path / solver / "solution.npz", q=q + dq)
        rows.append({"problem": "p", "task": "T1", "solver": solver, "success": True, "objective": 3.0})
        rows[-1]["path"] = str(tmp_path / solver)
    two = rows[:2] + [{**r, "problem": "lone"} for r in rows[2:]]
    pair = {"problems": 1, "agree": 1}
    assert problem_agreement(two) == {
        "T1": {"problems": 1, "agree": 1, "agree_fraction": 1.0, "pairs": {"ipopt-ipm": pair}}
    }
    three = problem_agreement(rows)["T1"]
    assert three["agree"] == 0  # casadi's trajectory lies 1e-2 rad away: it is the one that parts
    parted = {**pair, "agree": 0}
    assert three["pairs"] == {"ipopt-ipm": pair, "ipopt-casadi": parted, "ipm-casadi": parted}
    failed = [{**r, "success": r["solver"] != "ipm"} for r in rows[:2]]
    assert problem_agreement(failed)["T1"]["pairs"]["ipopt-ipm"]["agree"] == 0  # same point, one failed


def test_workers_get_one_grid_each_where_possible():
    jobs = [("a", 50, 50.0), ("b", 100, 100.0), ("c", 50, 50.0), ("d", 50, 50.0)]
    assert plan_queues(jobs, 1) == [["a", "c", "d", "b"]]
    assert sorted(plan_queues(jobs, 2)) == [["a", "c", "d"], ["b"]]
    group = {k: g for k, g, _ in jobs}
    for workers in (2, 3, 4, 8):
        queues = plan_queues(jobs, workers)
        assert len(queues) == min(workers, len(jobs))
        assert sorted(k for q in queues for k in q) == ["a", "b", "c", "d"]
        assert all(len({group[k] for k in q}) == 1 for q in queues)
