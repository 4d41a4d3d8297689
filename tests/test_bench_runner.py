"""``jaxhumanoid bench``: the runner's record and table on a fake suite (no solves), its argument
checks (bad input exits 2 before any work), the reference README's figures, and one real solve."""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np
import pytest

from jaxhumanoid.outputs.cli import main
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.studies import runner, suites
from jaxhumanoid.studies.runner import BenchSettings, Case, Measurement, Suite

REPO = pathlib.Path(__file__).resolve().parents[1]

# two rows of the reference posing's README, as it writes them
REFERENCE_README = """
| task | stage 1 iterations | stage 2 iterations | solve time (s): stage 1 + stage 2 | objective (7) | stage 2 ... |
|---|---|---|---|---|---|
| T1 | 106 | 224 | 0.3 + 3.2 = 3.5 | 1018.81 | 14.5 ms (function evaluations 36 %) |
| T2 | 36 | 263 | 0.1 + 3.9 = 4.0 | 579.97 | 14.8 ms (37 %) |
"""


def fake_suite(calls: list[str]) -> Suite:
    """Two cases: ``steady`` gives the same values each run, ``drifting`` does not."""

    def make(name: str, times: list[float], drift: bool) -> Case:
        def run() -> Measurement:
            calls.append(name)
            k = sum(c == name for c in calls)
            return Measurement({"status": "ok", "iterations": [3, 4 + (k if drift else 0)]}, {"solve_s": times[k - 1]})

        return Case(name, run)

    def cases(settings: BenchSettings) -> list[Case]:
        return [make("steady", [3.0, 1.0, 2.0], False), make("drifting", [5.0, 5.0, 5.0], True)]

    def summary(records, settings):
        return {"cases": [r["case"] for r in records]}

    def table(rec) -> str:
        return "\n".join(f"| {c['case']} | {runner.fmt_time(c['times']['solve_s'])} |" for c in rec["cases"])

    return Suite(cases, table, summary, about="A fake suite.")


def test_record_and_markdown_of_a_fake_suite(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXHUMANOID_IPOPT_LIBRARY", "/opt/ipopt/libipopt.so")
    calls: list[str] = []
    suites_ = {"fake": fake_suite(calls)}
    settings = BenchSettings(repeats=3, quiet=True)
    record = runner.run_record(runner.plan_run(["fake"], suites_, settings), suites_, settings, argv=["bench"])
    # every case once per round, in alternation
    assert calls == ["steady", "drifting"] * 3
    assert {"commit", "describe", "dirty", "environment", "started", "settings"} <= set(record)
    env = record["environment"]
    assert env["python"] and env["packages"]["jax"] and env["packages"]["numpy"] and "cpu" in env
    assert env["ipopt_library"] == "/opt/ipopt/libipopt.so"  # what the solves load, loaded here or not
    rec = record["suites"]["fake"]
    assert rec["summary"] == {"cases": ["steady", "drifting"]} and rec["rounds"] == 3
    steady, drifting = rec["cases"]
    assert steady["repeats_agree"] and steady["iterations"] == [3, 4] and steady["runs"] == 3
    assert steady["times"]["solve_s"] == {"median": 2.0, "min": 1.0, "max": 3.0, "runs": [3.0, 1.0, 2.0]}
    assert not drifting["repeats_agree"] and drifting["iterations"] == [3, 5]
    assert [d["iterations"] for d in drifting["differing"]] == [[3, 6], [3, 7]]
    text = runner.markdown(record, suites_)
    assert "## fake\n\nA fake suite." in text
    assert "| steady | 2.00 (1.00-3.00) |" in text and "| drifting | 5.00 |" in text
    assert (record["describe"] or "unknown") in text
    json_path, md_path = runner.write_run(record, text, tmp_path)
    assert json.loads(json_path.read_text())["suites"]["fake"]["cases"][0]["case"] == "steady"
    assert md_path.read_text() == text and json_path.parent == tmp_path


def test_a_suite_that_does_not_repeat_runs_once():
    calls: list[str] = []
    suite = fake_suite(calls)._replace(repeat=False)
    rec = runner.run_suite("fake", suite, suite.cases(BenchSettings()), BenchSettings(repeats=5, quiet=True))
    assert calls == ["steady", "drifting"] and rec["rounds"] == 1


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"repeats": 0}, "--repeats"),
        ({"repeats": 1.5}, "--repeats"),
        ({"N": 2}, "--N"),
        ({"tasks": ("T7",)}, "--tasks"),
        ({"tasks": ()}, "--tasks"),
        ({"backends": ("snopt",)}, "--backends"),
        ({"draws": 0}, "--draws"),
        ({"workers": 0}, "--workers"),
        ({"guess": "zero"}, "--guess"),
    ],
)
def test_settings_are_checked(kwargs, field):
    with pytest.raises(ValueError, match=field):
        BenchSettings(**kwargs)


def test_bad_input_exits_2_before_any_work(capsys, tmp_path, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("no solve before the input is checked")

    monkeypatch.setattr(suites, "solve", never)
    out = tmp_path / "bench"
    for argv, field in [
        (["--repeats", "0"], "--repeats"),
        (["--tasks", "T7"], "--tasks"),
        (["--suite", "reference", "--reference-dir", str(tmp_path / "none")], "--reference-dir"),
        (["--suite", "robustness", "--spec", str(tmp_path / "none.toml")], "none.toml"),
        (["--suite", "robustness", "--draws", "0"], "--draws"),
        (["--stage1-option", "mu_init=abc"], "--stage1-option"),
        (["--stage1-option", "mu_init"], "--stage1-option"),
    ]:
        assert main(["--no-cache", "bench", *argv, "--out", str(out)]) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("jaxhumanoid: error:") and field in err[0], (argv, err)
    for argv in (["--suite", "speed"], ["--backends", "snopt"], ["--repeats", "many"]):
        with pytest.raises(SystemExit) as exc:  # argparse's choices and types
            main(["--no-cache", "bench", *argv, "--out", str(out)])
        assert exc.value.code == 2
    assert not out.exists()


def test_reference_figures_parse_the_readme():
    figures = suites.reference_figures(REFERENCE_README)
    assert figures["T1"] == {
        "iterations": [106, 224],
        "solve_s": [0.3, 3.2],
        "solve_total_s": 3.5,
        "objective": 1018.81,
        "stage2_ms_per_iteration": 14.5,
    }
    assert set(figures) == {"T1", "T2"}


def test_reference_suite_one_real_solve(tmp_path, capsys):
    """The reference suite on one task file and IPOPT at N = 15: the record holds the solve's
    stages, the README's figures side by side and the ratios, and the table shows both."""
    ref = tmp_path / "reference"
    ref.mkdir()
    shutil.copy(REPO / "examples" / "paper" / "T1.toml", ref / "T1.toml")
    (ref / "README.md").write_text(REFERENCE_README)
    out = tmp_path / "bench"
    argv = ["bench", "--suite", "reference", "--tasks", "T1", "--backends", "ipopt", "--N", "15", "--repeats", "1"]
    assert main([*argv, "--reference-dir", str(ref), "--out", str(out), "--quiet"]) == 0
    (json_path,) = out.glob("*.json")
    record = json.loads(json_path.read_text())
    rec = record["suites"]["reference"]
    (case,) = rec["cases"]
    assert case["case"] == "T1 ipopt" and case["runs"] == 1 and case["repeats_agree"]
    assert len(case["iterations"]) >= 2 and all(isinstance(i, int) and i > 0 for i in case["iterations"])
    assert np.isfinite(case["objective"]) and case["times"]["solve_s"]["median"] > 0
    assert rec["summary"]["reference"]["T1"]["objective"] == 1018.81
    ratio = rec["summary"]["ratios"]["T1 ipopt"]["objective_rel_diff"]
    assert ratio == pytest.approx(abs(case["objective"] - 1018.81) / 1018.81)
    table = json_path.with_suffix(".md").read_text()
    assert "| T1 | ipopt |" in table and "| 106+224 | 3.5 | 1018.81 | 14.5 |" in table


def test_reference_draws_weights_are_seeded_and_small():
    """Draw 0 is the file as posed; draw d >= 1 moves each weight by about 1 % with seed d, the
    same draw for every backend and every run."""
    from jaxhumanoid.strategy.taskfile import solve_kwargs

    kw = solve_kwargs(str(REPO / "examples" / "paper" / "T1.toml"))
    assert suites.reference_draw_weights(kw, 0) is None
    w0 = kw["task"].weights.as_array(kw["model"].n)
    w1, w1_again, w2 = (suites.reference_draw_weights(kw, d) for d in (1, 1, 2))
    np.testing.assert_array_equal(w1, w1_again)
    assert not np.allclose(w1, w2)
    rel = np.abs(w1 / w0 - 1)
    assert 0 < rel.max() < 5 * suites.REFERENCE_DRAW_SIGMA


def test_reference_draws_summary_counts_the_best_optimum():
    """A draw's best optimum is the lowest any backend reached; a failed run is neither solved nor
    at it, and an optimum 1 % above it is not at it (rtol 0.5 %)."""

    def draw(obj, ok=True, its=(10, 20)):
        return {"status": "ok" if ok else "failed", "success": ok, "iterations": list(its), "objective": obj}

    cases = [
        {"case": "T1 ipopt", "draws": [draw(100.0), draw(200.0), draw(50.0, ok=False)]},
        {"case": "T1 ipm", "draws": [draw(101.0, its=(5, 5)), draw(200.5), draw(60.0)]},
    ]
    settings = BenchSettings(reference_dir="/nonexistent")
    s = suites.reference_draws_summary(cases, settings)["per_case"]
    assert s["T1 ipopt"]["solved"] == 2 and s["T1 ipopt"]["at_best"] == 2
    assert s["T1 ipm"]["solved"] == 3 and s["T1 ipm"]["at_best"] == 2  # draw 0 is 1 % above ipopt's
    assert s["T1 ipm"]["median_iterations"] == 30 and s["T1 ipm"]["draw0_iterations"] == 10
    assert s["T1 ipopt"]["reference_objective"] is None
    table = suites.reference_draws_table({"summary": suites.reference_draws_summary(cases, settings)})
    assert "| T1 | ipm | 3 of 3 | 2 of 3 | 30 (30) | 10, 101 | - |" in table


def test_the_runs_guess_reaches_the_robustness_cases_and_the_builtin_solves():
    from jaxhumanoid.studies import suites

    plain = suites.robustness_spec(BenchSettings(backends=("ipopt",), draws=1))
    both = suites.robustness_spec(BenchSettings(backends=("ipopt",), draws=1, guess="both"))
    assert [c.guess for c in plain.cases] == [None] * 4 and [c.guess for c in both.cases] == ["both"] * 4
    assert [c.draw for c in both.cases] == [c.draw for c in plain.cases]
    assert suites._builtin(BenchSettings(N=20)) == {"N": 20}
    assert suites._builtin(BenchSettings(guess="static_path"))["settings"].guess == "static_path"
    barrier = suites.robustness_spec(BenchSettings(backends=("ipopt",), draws=1, stage1_options={"mu_init": 0.1}))
    assert [dict(c.stage1_options) for c in barrier.cases] == [{"mu_init": 0.1}] * 4
    assert [c.guess for c in barrier.cases] == [None] * 4
    s = suites._builtin(BenchSettings(stage1_options={"mu_init": 1e-3}))["settings"]
    assert dict(s.stage1_options) == {"mu_init": 1e-3} and s.guess == SolveSettings().guess


def test_the_runs_guess_and_stage1_options_replace_a_task_files():
    """The reference suites solve each file as posed unless the run sets a guess or stage-1
    options; then the file's other settings stay and only those change."""
    from jaxhumanoid.strategy.taskfile import solve_kwargs

    ref = REPO / "examples" / "paper" / "T1.toml"
    posed = suites._reference_kwargs(ref, "ipm", BenchSettings())
    assert posed["solver"] == "ipm" and posed["settings"].guess == "linear"
    assert posed["settings"] == solve_kwargs(str(ref))["settings"] and posed["settings"].handover == "direct"
    auto = suites._reference_kwargs(ref, "ipopt", BenchSettings(guess="auto", stage1_options={"mu_init": 0.1}, N=20))
    assert auto["settings"] == posed["settings"].replace(guess="auto", stage1_options={"mu_init": 0.1})
    assert auto["N"] == 20 and auto["task"].name == posed["task"].name


def test_bench_settings_pin_the_workloads_options_where_none_are_set():
    from jaxhumanoid.studies.bench import BENCH_GUESS, BENCH_STAGE1_OPTIONS, BENCH_STAGE2_OPTIONS, bench_settings

    pinned = bench_settings(None)
    assert dict(pinned.stage1_options) == BENCH_STAGE1_OPTIONS
    assert dict(pinned.stage2_options) == BENCH_STAGE2_OPTIONS
    assert pinned.guess == BENCH_GUESS != SolveSettings().guess
    own = bench_settings(SolveSettings(stage1_options={"mu_init": 0.1}, stage2_options={"tol": 1e-6}, guess="both"))
    assert dict(own.stage1_options) == {"mu_init": 0.1} and dict(own.stage2_options) == {"tol": 1e-6}
    assert own.guess == "both"


def test_compile_table_shows_each_variants_spread_from_the_embedded_record():
    def row(variant, wall, cpu):
        return {
            "variant": variant,
            "compile_wall_s": wall,
            "compile_cpu_s": cpu,
            "process_wall_s (wall run)": wall + 8.0,
            "process_cpu_s (wall run)": cpu + 8.0,
        }

    rows = [row("a", 13.0, 19.0), row("b", 10.0, 15.0), row("a", 12.0, 20.0), row("a", 14.0, 18.0)]
    case = {"case": "cold compile", "script": "bench_iteration.py", "args": ["--parts", "compile"], "returncode": 0}
    minute = {"wall_s": {"median": 60.0, "min": 60.0, "max": 60.0}}
    rec = {"cases": [{**case, "times": minute, "record": {"compile": rows}}]}
    lines = suites.compile_table(rec).splitlines()
    assert lines[0].startswith("- cold compile: `scripts/bench_iteration.py --parts compile` exited 0")
    assert "| a | 3 | 13.0 (12.0-14.0) | 19.0 (18.0-20.0) | 21.0 (20.0-22.0) | 27.0 (26.0-28.0) |" in lines
    assert "| b | 1 | 10.0 | 15.0 | 18.0 | 23.0 |" in lines
    no_record = {"cases": [{**case, "times": {"wall_s": {"median": 1.0, "min": 1.0, "max": 1.0}}, "record": None}]}
    assert suites.compile_table(no_record).endswith("no record")


def test_iteration_table_shows_each_stages_time_per_iteration_from_the_embedded_record():
    def ms(m, lo, hi):
        return {"median": m, "min": lo, "max": hi}

    entry = {
        "task": "T1",
        "variant": "base",
        "runs": 2,
        "stage 2 iterations": [456, 456],
        "stage 2 OverallAlgorithm cpu ms/it": ms(15.9, 15.1, 16.0),
        "stage 2 Function Evaluations cpu ms/it": ms(4.65, 4.5, 4.7),
        "stage 2 PDSystemSolverTotal cpu ms/it": ms(10.39, 9.8, 10.45),
        "stage 1 OverallAlgorithm cpu ms/it": ms(3.47, 3.47, 3.47),
        "stage 2 OverallAlgorithm wall ms/it": ms(99.0, 99.0, 99.0),  # not a column
    }
    case = {"case": "bench_iteration", "script": "bench_iteration.py", "args": ["--tasks", "T1"], "returncode": 0}
    minute = {"wall_s": {"median": 60.0, "min": 60.0, "max": 60.0}}
    rec = {"cases": [{**case, "times": minute, "record": {"solve": [entry]}}]}
    lines = suites.iteration_table(rec).splitlines()
    row = "| T1 | base | 2 | 456/456 | 15.90 (15.10-16.00) | 4.65 (4.50-4.70) | 10.39 (9.80-10.45) | 3.47 | - |"
    assert f"{row} - | - |" in lines and not any("99.00" in line for line in lines)
    # on the reference posing: the independent implementation's stage-2 time per iteration and the ratio
    rec["summary"] = {"reference": {"T1": {"stage2_ms_per_iteration": 14.5}}}
    assert f"{row} 14.5 | 1.10 |" in suites.iteration_table(rec).splitlines()


def test_iteration_suite_runs_on_the_reference_posing_where_the_folder_has_it(tmp_path, monkeypatch):
    monkeypatch.setattr(suites, "external_case", lambda name, script, args: (script, args))
    (tmp_path / "T1.toml").write_text("")
    row = "| T1 | 106 | 224 | 0.3 + 3.2 = 3.5 | 1018.81 | 14.5 ms (function evaluations 36 %) |"
    (tmp_path / "README.md").write_text(row + "\n")
    on_ref = BenchSettings(tasks=("T1",), reference_dir=str(tmp_path), repeats=2)
    built_in = BenchSettings(tasks=("T4",), reference_dir=str(tmp_path))
    ((script, ref_args),) = suites.iteration_cases(on_ref)
    ((_, own_args),) = suites.iteration_cases(built_in)
    assert script == "bench_iteration.py" and ref_args == ["--tasks", "T1", "--runs", "2", "--task-dir", str(tmp_path)]
    assert own_args == ["--tasks", "T4", "--runs", "3"]
    summary = suites.iteration_summary([{"case": "bench_iteration", "args": ref_args}], on_ref)
    assert summary["reference"]["T1"]["stage2_ms_per_iteration"] == 14.5
    assert suites.iteration_summary([{"case": "bench_iteration", "args": own_args}], built_in)["reference"] == {}


def test_recorded_solve_gives_every_nlp_solve_of_the_strategy():
    # stage 2 solved again from what was recorded reproduces the strategy's own last solve
    from jaxhumanoid.solvers.ipopt import solve_ipopt
    from jaxhumanoid.studies.bench import recorded_solve

    settings = SolveSettings(N1=5, guess="linear", handover="direct")
    sol, runs = recorded_solve(task="T1", scheme="A,F+C,2S", N=10, settings=settings)
    # each stage's runs (its fallbacks and reruns included) add up to the stage's statistics
    for st in sol.stages:
        mine = [r for r in runs if r.stage.split(" (")[0] == st.name.split(" (")[0]]
        assert mine and sum(r.result.iterations for r in mine) == st.iterations
    assert len(runs) >= len(sol.stages) and runs[-1].stage.startswith("stage 2")
    last = runs[-1]
    again = solve_ipopt(last.problem.nlp, last.problem.p, last.problem.bounds, x0=last.x0, options=last.options)
    assert again.iterations == last.result.iterations
    np.testing.assert_array_equal(again.x, last.result.x)
