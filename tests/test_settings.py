"""The strategy's settings (``SolveSettings``): checked when made, each error naming its field;
really frozen; built from a mapping (a task file's ``[solve]`` table, the command line) with
unknown keys named; and the same solve whichever way they arrive."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import jaxhumanoid as jh
from jaxhumanoid.model.foot import FootMargin
from jaxhumanoid.strategy.settings import CONTINUATION_STEPS, DEFAULT_HANDOVER, DEFAULT_STAGE1_SOLVER, SolveSettings
from jaxhumanoid.strategy.solve import check_arguments


def test_the_defaults_are_the_package_defaults():
    s = SolveSettings()
    assert s.N1 is None and s.stage1_options is None and s.stage2_options is None and s.contact_stage1 is None
    assert s.guess == "auto" and s.handover == DEFAULT_HANDOVER == "continuation"
    assert s.continuation_steps == CONTINUATION_STEPS and s.stage1_solver == DEFAULT_STAGE1_SOLVER == "ipopt"
    assert s.foot_margin is None and s.scaling == "none"
    assert s.stage1_grid(100) == 30 and s.stage1_grid(12) == 12 and s.replace(N1=50).stage1_grid(100) == 50
    assert s.relaxed_solver("ipm") == "ipopt" and s.replace(stage1_solver="same").relaxed_solver("ipm") == "ipm"
    assert s.replace(stage1_solver=None).relaxed_solver("casadi") == "casadi"


@pytest.mark.parametrize(
    "field, value, allowed",
    [
        ("N1", 2, ">= 3"),
        ("N1", 8.0, ">= 3"),
        ("N1", True, ">= 3"),
        ("stage1_options", 3, "dict of solver options"),
        ("stage1_options", {1: 2}, "dict of solver options"),
        ("stage2_options", "tol=1e-8", "dict of solver options"),
        ("contact_stage1", {"kappa": 1.0}, "ContactParams"),
        ("guess", "zero", "'linear', 'inverse_dynamics', 'static_path', 'both'"),
        ("handover", "homotopy", "'direct', 'continuation'"),
        ("continuation_steps", 0, ">= 1"),
        ("continuation_steps", 1.5, ">= 1"),
        ("stage1_solver", "snopt", "'ipopt', 'ipm', 'casadi', 'same', None"),
        ("foot_margin", 0.1, "FootMargin"),
        ("scaling", "unit", "'none', 'physical'"),
    ],
)
def test_a_bad_value_names_its_field_and_what_it_allows(field, value, allowed):
    with pytest.raises(ValueError, match=f"^{field}: ") as err:
        SolveSettings(**{field: value})
    assert allowed in str(err.value)
    with pytest.raises(ValueError, match=f"^{field}: "):  # replace checks as a new object does
        SolveSettings().replace(**{field: value})
    with pytest.raises(ValueError, match=f"^somewhere: {field}: "):
        SolveSettings.from_mapping({field: value}, "somewhere")


def test_the_settings_are_frozen_and_keep_a_copy_of_their_options():
    options = {"tol": 1e-8}
    s = SolveSettings(stage1_options=options, stage2_options={"mu_init": 1e-4})
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.N1 = 20  # type: ignore[misc]
    with pytest.raises(TypeError):
        s.stage1_options["tol"] = 1.0  # type: ignore[index]
    with pytest.raises(TypeError):
        del s.stage2_options["mu_init"]  # type: ignore[attr-defined]
    options["tol"] = 1.0  # the caller's dict is not the settings' own
    assert s.stage1_options == {"tol": 1e-8}
    assert s == SolveSettings(stage1_options={"tol": 1e-8}, stage2_options={"mu_init": 1e-4})
    assert s.replace(N1=12).stage1_options == {"tol": 1e-8} and s.replace(N1=12) != s


def test_from_mapping_names_an_unknown_key_and_lists_the_allowed_ones():
    with pytest.raises(ValueError, match=r"^file.toml: \[solve\]: unknown settings \['homotopy', 'n1'\]") as err:
        SolveSettings.from_mapping({"n1": 20, "homotopy": True, "guess": "linear"}, "file.toml: [solve]")
    for name in ("N1", "guess", "handover", "scaling", "foot_margin"):
        assert repr(name) in str(err.value)
    s = SolveSettings.from_mapping({"N1": 20, "guess": "linear", "foot_margin": FootMargin(load=0.1)}, "here")
    assert s == SolveSettings(N1=20, guess="linear", foot_margin=FootMargin(load=0.1))


def test_solve_takes_settings_only_as_a_solve_settings():
    with pytest.raises(ValueError, match=r"^settings: expected a SolveSettings or None, got dict"):
        jh.solve("T1", settings={"N1": 20})  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="N1"):
        jh.solve("T1", N1=20)  # type: ignore[call-arg]
    with pytest.raises(ValueError, match="^solver: "):
        check_arguments(task="T1", solver="snopt", settings=SolveSettings())


def test_a_task_file_splits_its_solve_table_into_keywords_and_settings(tmp_path):
    path = tmp_path / "task.toml"
    path.write_text(THREE_LINK + SOLVE_TABLE + "\n[contact_stage1]\nkappa = 3e4\n")
    tf = jh.load_task_file(path)
    assert tf.keywords == {"scheme": "A,F+C,2S", "N": 15, "T": 3.0}
    assert tf.settings == SETTINGS.replace(contact_stage1=dataclasses.replace(jh.ContactParams.relaxed(), kappa=3e4))
    kwargs = tf.as_solve_kwargs()
    assert kwargs["settings"] is tf.settings and "N1" not in kwargs and kwargs["N"] == 15
    for extra, match in (
        ("N1 = 2", r"task.toml: \[solve\]: N1: expected an integer number of intervals >= 3, got 2"),
        ('handover = "homotopy"', r"task.toml: \[solve\]: handover: 'homotopy' not in \('direct', 'continuation'\)"),
        ("n1 = 20", r"task.toml: \[solve\] has unknown keys \['n1'\]; allowed: \[.*'N1'"),
        ("contact_stage1 = 3", r"task.toml: \[solve\] has unknown keys \['contact_stage1'\]"),
    ):
        bad = tmp_path / "task.toml"
        bad.write_text(THREE_LINK + "\n[solve]\n" + extra + "\n")
        with pytest.raises(ValueError, match=match):
            jh.load_task_file(bad)


# the 3-link squat-to-stand chain of test_nlinks, as a task file
THREE_LINK = """
name = "3-link squat-to-stand"
[body]
a = [0.47, 0.42, 0.75]
c = [0.21, 0.17, 0.40]
m = [6.3, 20.7, 44.0]
inertia = [0.086, 0.40, 2.2]
names = ["knee", "hip", "head"]
[task]
start = [2.007129, -1.308997, 1.541336]
goal = [1.658063, -0.174533, 0.366099]
active = []
"""
SOLVE_TABLE = """
[solve]
scheme = "A,F+C,2S"
N = 15
T = 3.0
N1 = 8
guess = "linear"
handover = "direct"
stage1_solver = "same"
stage2_options = { mu_init = 1e-2 }
"""
SETTINGS = SolveSettings(
    N1=8, guess="linear", handover="direct", stage1_solver="same", stage2_options={"mu_init": 1e-2}
)


def test_the_task_file_and_the_settings_object_give_the_same_solve(tmp_path):
    path = tmp_path / "task.toml"
    path.write_text(THREE_LINK + SOLVE_TABLE)
    tf = jh.load_task_file(path)
    from_file = jh.solve(**tf.as_solve_kwargs())
    direct = jh.solve(tf.task, "A,F+C,2S", N=15, T=3.0, model=tf.model, settings=SETTINGS)
    assert from_file.success and [s.name for s in direct.stages] == ["stage 1 (pseudo-static)", "stage 2 (dynamic)"]
    assert direct.stages[0].n_variables < direct.stages[1].n_variables / 1.5  # stage 1 on N1 = 8 intervals
    assert [s.runs for s in from_file.stages] == [s.runs for s in direct.stages]
    assert from_file.objective == direct.objective
    np.testing.assert_array_equal(from_file.q, direct.q)
    np.testing.assert_array_equal(from_file.u, direct.u)
