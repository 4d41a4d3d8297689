"""scripts/study_robustness.py: sampling, solver agreement, summary, and one real solve."""

import importlib.util
import json
import pathlib
import sys

import numpy as np
import pytest

from jaxhumanoid import ContactParams, PlanarChain, get_task
from jaxhumanoid.strategy.posture import margins

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "scripts" / "study_robustness.py"


@pytest.fixture(scope="module")
def study():
    spec = importlib.util.spec_from_file_location("study_robustness", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["study_robustness"] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("study_robustness", None)


def test_grid_sizes_are_reproducible_and_drawn_from_the_set(study):
    n_set = (50, 100)
    drawn = [study.sample_N("T1", 3, i, n_set) for i in range(40)]
    assert drawn == [study.sample_N("T1", 3, i, n_set) for i in range(40)]
    assert set(drawn) == set(n_set)
    assert drawn != [study.sample_N("T2", 3, i, n_set) for i in range(40)]


N_SET = (50, 75)


@pytest.fixture(scope="module")
def samples(study):
    """Problem 1 of a standing-start and a lying-start family (each draw runs an equilibrium search)."""
    return {family: study.sample_problem(get_task(family), seed=7, index=1, n_set=N_SET) for family in ("T2", "T3")}


def test_sampling_is_reproducible(study, samples):
    assert samples["T3"] == study.sample_problem(get_task("T3"), seed=7, index=1, n_set=N_SET)
    assert samples["T2"] != samples["T3"]


@pytest.mark.parametrize("family", ["T2", "T3"])
def test_samples_are_in_range_and_at_equilibrium(study, samples, family):
    task, body, pert = get_task(family), PlanarChain.humanoid(), samples[family]
    n_set = N_SET

    lo, hi = study.WEIGHT_RANGE
    assert all(lo <= f <= hi for f in pert.weight_factors.values())
    base = task.weights.as_array(task.n)
    factors = np.array(
        [pert.weight_factors["w_u"]] * task.n + [pert.weight_factors[k] for k in ("w_qd", "w_dqd", "w_du")]
    )
    np.testing.assert_allclose(pert.weights, base * factors, rtol=1e-12)
    np.testing.assert_allclose(pert.cost_weights().as_array(task.n), pert.weights, rtol=0)
    nominal = ContactParams.nominal()
    for name, f in pert.contact_factors.items():
        assert 0.5 <= f <= 1.5
        assert pert.contact[name] == pytest.approx(f * getattr(nominal, name), rel=1e-12)
    assert pert.N in n_set
    assert 4.0 <= pert.T <= 6.0
    assert np.max(np.abs(pert.start_offset)) <= np.deg2rad(2.0)
    assert pert.start_moved <= study.MAX_MOVE
    assert pert.redraws == sum(pert.rejected.values()) >= 0

    q = np.asarray(pert.start)
    q_min, q_max = task.joint_ranges(body)
    assert np.all(q >= q_min - 1e-9) and np.all(q <= q_max + 1e-9)
    assert margins(body, q, task.active, contact=pert.law()).ok
    assert pert.start_moved == pytest.approx(np.max(np.abs(q - (task.start + np.asarray(pert.start_offset)))))


def test_a_projection_that_moves_the_start_too_far_is_redrawn(study):
    with pytest.raises(RuntimeError, match="2 draws"):
        study.sample_problem(get_task("T3"), seed=7, index=1, n_set=N_SET, max_redraws=1, max_move=1e-9)


def test_agreement_flags_a_moved_trajectory(study):
    rng = np.random.default_rng(0)
    q = rng.standard_normal((21, 5))
    same = {"ipopt": study.Outcome(True, 2.5, q), "ipm": study.Outcome(True, 2.5 * (1 + 1e-9), q + 1e-7)}
    result = study.agreement(same)
    assert result["agrees"]
    assert result["pairs"][0]["max_dq"] == pytest.approx(1e-7)

    moved = q.copy()
    moved[7, 2] += 1e-3
    result = study.agreement({**same, "casadi": study.Outcome(True, 2.5, moved)})
    assert not result["agrees"]
    assert [p["within"] for p in result["pairs"]] == [True, False, False]
    assert result["pairs"][1]["max_dq"] == pytest.approx(1e-3)

    assert not study.agreement({**same, "casadi": study.Outcome(True, 2.5 * (1 + 1e-5), q)})["agrees"]
    assert not study.agreement({**same, "casadi": study.Outcome(False, 2.5, q)})["agrees"]
    assert not study.agreement({**same, "casadi": study.Outcome(False, float("nan"), None)})["agrees"]
    assert study.agreement({"ipopt": study.Outcome(True, 1.0, q)})["agrees"]


def _record(solver, its1, its2, times, objective, success=True):
    stages = [
        {"iterations": its1, "solve_time_s": times[0], "status": "s", "success": success},
        {"iterations": its2, "solve_time_s": times[1], "status": "s", "success": success},
    ]
    return {"solver": solver, "success": success, "stages": stages, "objective": objective}


def _problems():
    def problem(index, records, agrees, redraws):
        return {
            "family": "T1",
            "index": index,
            "perturbation": {"redraws": redraws},
            "records": records,
            "agreement": {"agrees": agrees},
        }

    crashed = {"solver": "ipopt", "success": False, "stages": [], "objective": None}
    return [
        problem(0, [_record("ipopt", 10, 100, (1.0, 2.0), 5.0), _record("ipm", 12, 90, (1.0, 1.0), 5.0)], True, 0),
        problem(1, [_record("ipopt", 30, 300, (2.0, 4.0), 7.0), _record("ipm", 8, 80, (1.0, 1.0), 7.0)], True, 2),
        problem(
            2, [_record("ipopt", 20, 200, (1.0, 1.0), 9.0, False), _record("ipm", 9, 85, (1.0, 2.0), 6.0)], False, 1
        ),
        problem(3, [crashed, _record("ipm", 11, 70, (0.5, 0.5), 8.0)], False, 0),
    ]


def test_summary_medians_and_ranges(study):
    summary = study.summarise(_problems())
    ipopt, ipm = summary["solvers"]
    assert (ipopt["solver"], ipopt["solves"], ipopt["succeeded"], ipopt["success_rate"]) == ("ipopt", 4, 2, 0.5)
    assert ipopt["stage1_iterations"] == {"median": 20.0, "min": 10.0, "max": 30.0, "n": 3}
    assert ipopt["stage2_iterations"] == {"median": 200.0, "min": 100.0, "max": 300.0, "n": 3}
    assert ipopt["solve_time_s"] == {"median": 3.0, "min": 2.0, "max": 6.0, "n": 3}
    assert ipopt["objective"] == {"median": 6.0, "min": 5.0, "max": 7.0, "n": 2}
    assert ipm["success_rate"] == 1.0
    assert ipm["stage1_iterations"] == {"median": 10.0, "min": 8.0, "max": 12.0, "n": 4}
    assert ipm["stage2_iterations"] == {"median": 82.5, "min": 70.0, "max": 90.0, "n": 4}
    assert ipm["objective"] == {"median": 6.5, "min": 5.0, "max": 8.0, "n": 4}
    assert summary["agreement"] == [
        {"family": "T1", "problems": 4, "agree": 2, "agree_fraction": 0.5, "redraws": 3, "sampling_failed": 0}
    ]
    table = study.markdown(summary)
    assert "| T1 | ipopt | 2/4 (50%) | 20 (10-30) | 200 (100-300) | 3.00 (2.00-6.00) | 6 (5-7) |" in table
    assert "| T1 | 4 | 2/4 (50%) | 3 | 0 |" in table


def test_summarise_mode_rereads_a_study(study, tmp_path, capsys):
    path, md = tmp_path / "robustness.json", tmp_path / "robustness.md"
    path.write_text(json.dumps({"config": {}, "problems": _problems()}))
    study.main(["--summarise", str(path), "--md", str(md)])
    assert "| T1 | ipm | 4/4 (100%) |" in capsys.readouterr().out
    assert "| T1 | ipm | 4/4 (100%) |" in md.read_text()


def test_one_tiny_problem_end_to_end(study):
    problem = study.solve_problem("T3", 0, seed=0, solvers=("ipopt",), n_set=(20,), N1=20)
    assert problem["error"] is None
    (record,) = problem["records"]
    assert record["error"] is None, record["error"]
    assert record["success"], [s["status"] for s in record["stages"]]
    assert [s["iterations"] > 0 for s in record["stages"]] == [True, True]
    assert record["perturbation"]["N"] == 20
    assert set(record["objective_terms"]) == {"torque", "velocity", "acceleration", "torque_rate"}
    assert record["objective"] == pytest.approx(sum(record["objective_terms"].values()))
    assert len(record["peak_torque"]) == 5 and record["peak_normal_force"] > 0
    assert not record["warnings"]  # the projected start keeps the foot steady: solve does not move it
    assert problem["agreement"]["agrees"]
    json.dumps(problem)


def test_workers_get_one_grid_size_each_where_possible(study):
    jobs = [("T1", 0, 50), ("T1", 1, 100), ("T2", 0, 50), ("T2", 1, 50)]
    assert study.plan_workers(jobs, 1) == [[("T1", 0, 50), ("T2", 0, 50), ("T2", 1, 50), ("T1", 1, 100)]]
    assert sorted([j[2] for j in q] for q in study.plan_workers(jobs, 2)) == [[50, 50, 50], [100]]
    for workers in (2, 3, 4, 8):
        queues = study.plan_workers(jobs, workers)
        assert len(queues) == min(workers, len(jobs))
        assert sorted(j for q in queues for j in q) == sorted(jobs)
        assert all(len({j[2] for j in q}) == 1 for q in queues)
