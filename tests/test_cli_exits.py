"""Exit statuses of the command line: 2 only for input rejected before any work, 1 for a run that
failed while working (its message printed, the files written so far kept), and the default grid
of ``check --sensitivities``."""

from __future__ import annotations

import json

import pytest

from jaxhumanoid.outputs import cli
from jaxhumanoid.outputs.cli import SENSITIVITY_N, main


def _err(capsys) -> list[str]:
    return capsys.readouterr().err.strip().splitlines()


def test_an_error_while_solving_is_a_failed_run_not_bad_input(capsys, tmp_path, monkeypatch):
    """A ValueError raised by the solve (no equilibrium near the start, say) exits 1 with its message."""

    def no_equilibrium(**kwargs):
        raise ValueError("find_equilibrium: no equilibrium found near the start posture")

    monkeypatch.setattr(cli, "solve", no_equilibrium)
    assert main(["--no-cache", "solve", "--task", "T2", "--out", str(tmp_path / "T2"), "--quiet"]) == 1
    err = _err(capsys)
    assert err == ["jaxhumanoid: failed: find_equilibrium: no equilibrium found near the start posture"], err


def test_bad_settings_are_rejected_before_the_solve(capsys, tmp_path, monkeypatch):
    """Settings the solve would reject (from the command line or a task file) exit 2 before it
    starts, naming the field and what it allows."""

    def never(**kwargs):
        raise AssertionError("the solve must not start")

    monkeypatch.setattr(cli, "solve", never)
    task_file = tmp_path / "bad.toml"
    text = (cli.pathlib.Path("examples/paper/T1.toml")).read_text().replace('guess = "linear"', 'guess = "lucky"')
    task_file.write_text(text)
    out = tmp_path / "out"
    cases = [
        (["solve", "--N", "2"], "N"),
        (["solve", "--T", "-1"], "T"),
        (["solve", "--scheme", "B,F,1S"], "scheme"),
        (["solve", "--task-file", str(task_file)], f"{task_file}: [solve]: guess"),
        (["solve", "--N1", "2"], "command line: N1"),
    ]
    for argv, field in cases:
        assert main(["--no-cache", *argv, "--out", str(out), "--quiet"]) == 2, argv
        err = _err(capsys)
        assert len(err) == 1 and err[0].startswith(f"jaxhumanoid: error: {field}"), (argv, err)
        if "--task-file" in argv:
            assert "'lucky' not in" in err[0] and "linear" in err[0], err
    assert not out.exists() or not list(out.iterdir())


def test_check_rejects_an_unknown_task_before_work(capsys, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("the check must not start")

    monkeypatch.setattr(cli, "sensitivity_table", never)
    assert main(["--no-cache", "check", "--sensitivities", "--task", "T7"]) == 2
    assert "T7" in _err(capsys)[0]
    assert main(["--no-cache", "check", "--sensitivities", "--scheme", "Q,F"]) == 2
    assert "scheme" in _err(capsys)[0]


def test_table2_keeps_the_cells_before_a_failure(capsys, tmp_path, monkeypatch):
    """A failure while working exits 1 and keeps table2.json with the cells solved before it."""
    calls = []

    def solve(**kwargs):
        calls.append(kwargs["task"])
        if len(calls) > 1:
            raise ValueError("find_equilibrium: no equilibrium found")
        return "a solution"

    def save(sol, folder):
        folder.mkdir(parents=True)
        return {"task": calls[-1], "stage_status": ["Solve_Succeeded"], "iterations": [1], "solve_time_s": [0.1]}

    monkeypatch.setattr(cli, "solve", solve)
    monkeypatch.setattr(cli, "_save", save)
    argv = ["--no-cache", "table2", "--tasks", "T1", "T2", "--schemes", "A,F+C,2S", "--out", str(tmp_path), "--quiet"]
    assert main(argv) == 1
    assert _err(capsys)[-1] == "jaxhumanoid: failed: find_equilibrium: no equilibrium found"
    records = json.loads((tmp_path / "table2.json").read_text())
    assert len(records) == 1 and records[0]["task"] == "T1"


def test_sensitivity_check_default_grid(monkeypatch, capsys):
    """``check --sensitivities`` solves on SENSITIVITY_N intervals unless told otherwise."""
    seen = {}

    def table(tasks, scheme, N, eps):
        seen.update(tasks=list(tasks), scheme=scheme, N=N)
        return [], []

    monkeypatch.setattr(cli, "sensitivity_table", table)
    assert main(["--no-cache", "check", "--sensitivities", "--task", "T2"]) == 0
    assert seen == {"tasks": ["T2"], "scheme": "A,F+C,1S", "N": SENSITIVITY_N}


@pytest.mark.slow
@pytest.mark.parametrize("task", ["T2", "T4"])
def test_sensitivity_check_passes_by_default(task, capsys):
    """The documented ``jaxhumanoid check --sensitivities --task T`` passes on the tasks whose
    reference solve failed on the coarser grid."""
    assert main(["--no-cache", "check", "--sensitivities", "--task", task]) == 0
    assert " 0 failed" in capsys.readouterr().out
