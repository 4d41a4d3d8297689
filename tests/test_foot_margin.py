"""The foot margin on (5): a solved plan keeps it (and a plan solved without it sits on the edge the
margin moves away from), zero margin is (5) bit for bit, the CasADi twin agrees with a margin, and
bad margins are refused before any work, in Python, in task files and on the command line."""

from __future__ import annotations

import pathlib
import sys

import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model.foot import FootMargin, check_foot_margin
from jaxhumanoid.model.params import ContactParams, FootParams
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.outputs.cli import main
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.strategy.settings import SolveSettings
from jaxhumanoid.strategy.solve import solve
from jaxhumanoid.strategy.taskfile import load_task_file
from jaxhumanoid.validation.checks import cross_validate

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from test_nlinks import CHAINS, TASKS  # noqa: E402  (the small chains and their tasks)

# The 2-link lean in 0.6 s on a slippery floor: without margin the optimum uses the whole friction cone.
SLIPPERY = ContactParams(kappa=1e5, f0=200.0, xhat=0.02, mu=0.2)
MARGIN = FootMargin(load=0.6, friction=0.3, cop=0.03)


def _lean(margin):
    settings = SolveSettings(foot_margin=margin)
    return solve(TASKS[2], "A,F+C,1S", N=15, T=0.6, model=CHAINS[2], contact=SLIPPERY, settings=settings)


def physical_margins(sol):
    """(least foot load in M g, largest friction use |f_t0| / (mu f_n0), centre of pressure range (m))."""
    geo = sol.geometry
    f_t0, f_n0 = sol.foot_reaction[:, 0], sol.foot_reaction[:, 1]
    weight = float(np.sum(geo["m"]) * geo["g"])
    cop = sol.u[:, 0] / f_n0
    return float(f_n0.min() / weight), float(np.max(np.abs(f_t0) / (geo["mu"] * f_n0))), (cop.min(), cop.max())


def keeps(sol, margin: FootMargin, foot: FootParams, tol: float = 1e-6) -> bool:
    load, friction, (cop_lo, cop_hi) = physical_margins(sol)
    return bool(
        load >= margin.load - tol
        and friction <= 1.0 - margin.friction + tol
        and cop_lo >= -foot.a0f + margin.cop - tol
        and cop_hi <= foot.a0b - margin.cop + tol
    )


def test_a_solved_plan_keeps_its_margin_and_one_without_sits_on_the_edge():
    foot = FootParams.paper()
    bare, kept = _lean(None), _lean(MARGIN)
    assert bare.success and kept.success
    assert keeps(kept, MARGIN, foot)
    assert not keeps(bare, MARGIN, foot)  # the mutation: the same check fails on the plan without margin
    _, friction, _ = physical_margins(bare)
    assert friction == pytest.approx(1.0, abs=1e-6)  # on the friction cone's edge
    load, friction, _ = physical_margins(kept)
    assert load == pytest.approx(MARGIN.load, abs=1e-6) and friction == pytest.approx(0.7, abs=1e-6)  # active
    assert kept.objective > bare.objective  # what the margin costs
    assert kept.geometry["margin_load"] == MARGIN.load and bare.geometry["margin_cop"] == 0.0


def test_zero_margin_is_the_steady_foot_rows_bit_for_bit():
    problem = build_problem("T1", "A,F+C,1S", N=6)
    layout, p = problem.layout, problem.p
    Z = jnp.asarray(problem.full(problem.bounds.x0 + 0.01 * np.random.default_rng(0).standard_normal(problem.nlp.n)))
    g = np.asarray(tr.all_constraints(layout, Z, p)).reshape(layout.N, -1)
    f_c0, u1, mu = jnp.array([30.0, 400.0]), jnp.asarray(12.0), p.contact.mu
    plain = np.asarray(ft.foot_constraints(p.foot, mu, f_c0, u1))
    np.testing.assert_array_equal(np.asarray(ft.foot_constraints(p.foot, mu, f_c0, u1, FootMargin(), 700.0)), plain)
    tight = tr.OCPParams(**{**p.__dict__, "foot_margin": MARGIN})
    g_tight = np.asarray(tr.all_constraints(layout, Z, tight)).reshape(layout.N, -1)
    rows = slice(2 * layout.n_links + layout.n_f, 2 * layout.n_links + layout.n_f + tr.N_FOOT)
    weight = float(p.model.total_mass * p.model.g)
    f_n0 = g[:, rows][:, 0]
    np.testing.assert_allclose(g[:, rows][:, 0] - g_tight[:, rows][:, 0], MARGIN.load * weight, rtol=1e-9)
    np.testing.assert_allclose(g[:, rows][:, 3] - g_tight[:, rows][:, 3], MARGIN.cop * f_n0, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(np.delete(g, np.r_[rows], axis=1), np.delete(g_tight, np.r_[rows], axis=1))


def test_the_casadi_twin_agrees_with_a_margin():
    problem = build_problem("T3", "A,F+C,1S", N=4, foot_margin=FootMargin(0.1, 0.2, 0.02))
    bad = [r for r in cross_validate(problem, points=1, x=problem.bounds.x0, seed=3) if not r.ok]
    assert not bad, bad


@pytest.mark.parametrize(
    "margin,match",
    [
        (dict(load=-0.1), "FootMargin.load"),
        (dict(friction=1.0), "FootMargin.friction"),
        (dict(cop=True), "FootMargin.cop"),
        (dict(cop="0.1"), "FootMargin.cop"),
    ],
)
def test_bad_margins_name_their_field(margin, match):
    with pytest.raises(ValueError, match=match):
        FootMargin(**margin)


def test_margins_are_checked_against_the_foot_and_the_start_before_any_work():
    with pytest.raises(ValueError, match=r"FootMargin.cop: expected a distance in \[0, 0.129\)"):
        check_foot_margin(FootMargin(cop=0.13), FootParams.paper())
    with pytest.raises(ValueError, match="foot_margin: expected a FootMargin"):
        SolveSettings(foot_margin=0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"FootMargin.cop: expected a distance in \[0, 0.129\)"):
        solve("T1", settings=SolveSettings(foot_margin=FootMargin(cop=0.13)))
    with pytest.raises(ValueError, match="foot_margin: the start posture of task T1 keeps a foot load of 0"):
        # the prone start carries about a quarter of the body
        solve("T1", settings=SolveSettings(foot_margin=FootMargin(load=0.9)))


def test_task_files_and_the_command_line_take_a_margin(tmp_path):
    src = pathlib.Path(__file__).parents[1] / "examples" / "bow_3link.toml"
    good = tmp_path / "good.toml"
    good.write_text(src.read_text() + "\n[foot_margin]\nload = 0.2\nfriction = 0.25\ncop = 0.02\n")
    assert load_task_file(good).as_solve_kwargs()["settings"].foot_margin == FootMargin(0.2, 0.25, 0.02)
    assert load_task_file(src).as_solve_kwargs()["settings"].foot_margin is None
    for extra, match in (("tilt = 0.1", "unknown keys"), ("cop = 0.5", "FootMargin.cop")):
        bad = tmp_path / "bad.toml"
        bad.write_text(src.read_text() + f"\n[foot_margin]\n{extra}\n")
        with pytest.raises(ValueError, match=match):
            load_task_file(bad)
    assert main(["--no-cache", "solve", "--task", "T4", "--foot-margin", "1.5", "0", "0", "--out", str(tmp_path)]) == 2
