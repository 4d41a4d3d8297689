"""A task's contact-force limit: its bounds and checks, a solve that meets it, and the sensitivities
of an optimum where it is active."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import jaxhumanoid as jh
from jaxhumanoid.diff import active_set, fd
from jaxhumanoid.diff import kkt as kkt_mod
from jaxhumanoid.model.contact import contact_forces
from jaxhumanoid.ocp.tasks import CONTACT_FORCE_LIMIT, get_task
from jaxhumanoid.outputs.cli import build_parser, solve_arguments
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.studies import parse_spec
from jaxhumanoid.studies.run import base_problem
from jaxhumanoid.validation.checks import cross_validate

CAP = 0.8  # body weights: below the 1.33 M g of T1's A,F+C,1S optimum at N = 15


def capped(key="T1", cap=CAP):
    return dataclasses.replace(get_task(key), contact_force_limit=cap)


def force_bounds(problem):
    lo, hi = (problem.full(b) for b in (problem.bounds.xl, problem.bounds.xu))
    f = problem.layout.stage_slices()["f"]
    return lo[:-1, f].reshape(-1, 2), hi[:-1, f].reshape(-1, 2)  # (f_t, f_n) per contact and node


def test_the_limit_bounds_every_contact_force_in_body_weights_of_the_body():
    body = jh.PlanarChain.humanoid()
    heavy = dataclasses.replace(body, m=np.asarray(body.m) * 1.2, inertia=np.asarray(body.inertia) * 1.2)
    weight = float(np.sum(body.m)) * body.g
    lo, hi = force_bounds(build_problem(capped(), "A,F+C,1S", N=8))
    assert np.allclose(hi, CAP * weight) and np.allclose(lo[:, 0], -CAP * weight)
    assert np.all(lo[:, 1] == -np.inf)  # f_n's lower bound is implied by the law (3)
    _, hi_heavy = force_bounds(build_problem(capped(), "A,F+C,1S", N=8, model=heavy))
    assert np.allclose(hi_heavy, 1.2 * CAP * weight)
    _, hi_free = force_bounds(build_problem(get_task("T1"), "A,F+C,1S", N=8))
    assert np.all(hi_free == CONTACT_FORCE_LIMIT)


@pytest.mark.parametrize("cap", [0.0, -1.0, float("inf"), True, "2"])
def test_a_bad_limit_is_refused_with_its_field(cap):
    with pytest.raises(ValueError, match="Task.contact_force_limit"):
        capped(cap=cap)


def test_scheme_e_bounds_the_law_normal_force_of_each_contact_by_a_row():
    weight = float(np.sum(jh.PlanarChain.humanoid().m)) * jh.PlanarChain.humanoid().g
    plain, limited = (build_problem(t, "E,F,1S", N=8) for t in (get_task("T1"), capped()))
    k = len(limited.layout.active)
    assert limited.nlp.m == plain.nlp.m + 8 * k and plain.layout.n_force_rows == 0
    rows = limited.layout.constraint_kinds() == 2
    assert rows.sum() == k and np.all(rows[-k:])
    gl, gu = (b.reshape(8, -1)[:, rows] for b in (limited.bounds.gl, limited.bounds.gu))
    assert np.all(gl == -np.inf) and np.allclose(gu, CAP * weight)
    # the rows are the law's normal forces at the midpoints, and the other rows are unchanged
    x = limited.bounds.x0
    g_lim = np.asarray(limited.nlp.g(x, limited.p)).reshape(8, -1)
    g_plain = np.asarray(plain.nlp.g(x, plain.p)).reshape(8, -1)
    assert np.array_equal(g_lim[:, ~rows], g_plain)
    Z = np.asarray(limited.full(x))
    qbar = 0.5 * (Z[:-1, :5] + Z[1:, :5])
    qdbar = 0.5 * (Z[:-1, 5:10] + Z[1:, 5:10])
    p, active = limited.p, limited.layout.active
    f_n = [contact_forces(p.model, p.foot, p.contact, a, b, active)[:, 1] for a, b in zip(qbar, qdbar)]
    assert np.allclose(g_lim[:, rows], np.asarray(f_n), rtol=1e-12, atol=1e-9)


def test_scheme_e_limit_rows_agree_with_the_casadi_backend():
    rows = cross_validate(build_problem(capped(), "E,F,1S", N=6), points=2)
    assert all(r.ok for r in rows), [r for r in rows if not r.ok]


def test_a_scheme_e_solve_meets_the_limit_where_the_free_optimum_exceeds_it():
    # T3's E,F,1S optimum at N = 15 pushes off at 0.60 M g; limited to 0.55 it converges with
    # the limit active
    sol = jh.solve(capped("T3", 0.55), "E,F,1S", N=15)
    assert sol.success
    peak = sol.peaks()["contact_normal_force_body_weights"]
    assert 0.55 * (1 - 1e-3) <= peak <= 0.55 * (1 + 1e-6)


def test_the_limit_reaches_the_problem_from_a_task_file_the_command_line_and_a_study(tmp_path):
    path = tmp_path / "t.toml"
    path.write_text(
        'name = "capped"\n[task]\nstart = [1.6, 0.0, 0.0, -3.1, -0.2]\ngoal = [3.2, -0.2, -0.3, -4.5, -1.3]\n'
        "active = [1, 4, 5]\ncontact_force_limit = 1.5\n"
    )
    assert load_task_file(path).task.contact_force_limit == 1.5
    path.write_text(path.read_text().replace("1.5", "-2"))
    with pytest.raises(ValueError, match=r"t.toml.*contact_force_limit"):
        load_task_file(path)
    args = build_parser().parse_args(["solve", "--task", "T1", "--contact-force-limit", "2"])
    assert solve_arguments(args)["task"] == dataclasses.replace(get_task("T1"), contact_force_limit=2.0)
    spec = {"tasks": ["T1"], "schemes": ["A,F+C,1S"], "N": [10]}
    (plain,), (case,) = parse_spec(spec).cases, parse_spec({**spec, "contact_force_limit": 2.0}).cases
    assert "contact_force_limit" not in plain.params() and case.id != plain.id
    assert base_problem(case)["task"].contact_force_limit == 2.0 and base_problem(plain)["task"] == get_task("T1")
    with pytest.raises(ValueError, match="contact_force_limit"):
        parse_spec({**spec, "contact_force_limit": 0})


def test_t3_carries_its_own_limit_which_the_command_line_can_lift():
    weight = float(np.sum(jh.PlanarChain.humanoid().m)) * jh.PlanarChain.humanoid().g
    _, hi = force_bounds(build_problem("T3", "A,F+C,1S", N=8))
    assert np.allclose(hi, 2.0 * weight)
    for value, cap in (("none", None), ("NONE", None), ("1.5", 1.5)):
        args = build_parser().parse_args(["solve", "--task", "T3", "--contact-force-limit", value])
        assert solve_arguments(args)["task"] == dataclasses.replace(get_task("T3"), contact_force_limit=cap)
    _, hi_free = force_bounds(
        build_problem(dataclasses.replace(get_task("T3"), contact_force_limit=None), "A,F+C,1S", N=8)
    )
    assert np.all(hi_free == CONTACT_FORCE_LIMIT)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["solve", "--task", "T3", "--contact-force-limit", "off"])
    spec = {"tasks": ["T3"], "schemes": ["A,F+C,1S"], "N": [10]}
    (plain,), (lifted,) = parse_spec(spec).cases, parse_spec({**spec, "contact_force_limit": "none"}).cases
    assert base_problem(plain)["task"] == get_task("T3") and lifted.id != plain.id
    assert base_problem(lifted)["task"] == dataclasses.replace(get_task("T3"), contact_force_limit=None)
    with pytest.raises(ValueError, match="contact_force_limit.*'none'"):
        parse_spec({**spec, "contact_force_limit": "off"})


# T3's A,F+C,1S optimum at N = 15 pushes off at 0.60 M g: limited to 0.55 it converges with the limit
# active (limited further, or on T1, the 1S solve from the guess ends infeasible at this coarse grid)
ACTIVE_CAP = 0.55


@pytest.fixture(scope="module")
def capped_optimum():
    task = capped("T3", ACTIVE_CAP)
    return build_problem(task, "A,F+C,1S", N=15), jh.solve(task, "A,F+C,1S", N=15)


def test_a_solve_meets_the_limit_where_the_free_optimum_exceeds_it(capped_optimum):
    _, sol = capped_optimum
    assert sol.success
    peak = sol.peaks()["contact_normal_force_body_weights"]
    assert ACTIVE_CAP * (1 - 1e-3) <= peak <= ACTIVE_CAP * (1 + 1e-6)  # active


def test_sensitivities_with_the_limit_active_match_finite_differences(capped_optimum, monkeypatch):
    problem, _ = capped_optimum
    lower, upper = active_set.implied_bounds(problem)
    assert lower.sum() == 2 * upper.sum()  # f_n's limit is a real bound, its lower one stays implied
    out = fd.check_against_fd(problem=problem, groups=("weights",), verbose=False)
    assert all(r["ok"] for r in fd.table_rows(out))
    # mutation: the limit taken as implied (never active) like the wide box
    monkeypatch.setattr(kkt_mod, "implied_bounds", lambda p: np.stack([lower, lower]))
    bad = fd.check_against_fd(problem=problem, groups=("weights",), verbose=False)
    assert not all(r["ok"] for r in fd.table_rows(bad))
