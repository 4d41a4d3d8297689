"""CasADi twin of the NLP (7): values and derivatives agree with ours; CasADi's IPOPT solves a small
problem to the same point as our IPOPT path."""

import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.validation.casadi_backend import build_casadi_nlp, solve_casadi
from jaxhumanoid.validation.checks import DEFAULT_CASES, cross_validate

CASES = list(DEFAULT_CASES)


@pytest.mark.parametrize("task,scheme,pseudo", CASES)
def test_values_and_derivatives_agree(task, scheme, pseudo):
    contact = ContactParams.relaxed() if pseudo else None
    problem = build_problem(task, scheme, N=6, pseudo_static=pseudo, contact=contact)
    rows = cross_validate(problem, points=2, x=problem.bounds.x0, seed=3)
    bad = [r for r in rows if not r.ok]
    assert not bad, bad
    assert {r.quantity for r in rows} >= {
        "f",
        "grad f",
        "g",
        "jacobian",
        "hessian (tril)",
        "jacobian pattern",
        "hessian pattern",
    }
    assert all(r.tol == 1e-10 for r in rows if "pattern" not in r.quantity)


def _stage1_problem(N, key="T1", guess="linear"):
    relaxed = ContactParams.relaxed()
    nominal = build_problem(key, "A,F+C,1S", N=N)
    q1, _ = reseat_for_contact(nominal.p, nominal.p.q_start, nominal.layout.active, relaxed)
    return build_problem(key, "A,F+C,1S", N=N, pseudo_static=True, contact=relaxed, q_start=q1, guess=guess)


def test_casadi_solve_matches_ipopt():
    # stage 1 of T3 on 10 intervals: both IPOPT builds (cyipopt's and CasADi's differ in IPOPT/MUMPS
    # versions) reach one point in about 140 iterations. Longer paths (T1; or from the linear guess)
    # part after rounding-level differences, which compares the two IPOPT builds rather than the NLPs;
    # coarser grids are infeasible under the body's strengths.
    problem = _stage1_problem(10, "T3", "inverse_dynamics")
    opts = {"tol": 1e-10}
    ours = solve_ipopt(problem.nlp, problem.p, problem.bounds, x0=problem.bounds.x0, options=opts)
    seen = []
    ref = solve_casadi(problem, x0=problem.bounds.x0, options=opts, progress=lambda *a: seen.append(a))
    assert ref.success and ours.success, (ref.status, ours.status)
    # the progress callback, once per iterate; IPOPT calls it once more when it enters restoration
    ks = [k for k, _, _ in seen]
    assert ks == list(range(len(ks))) and ref.iterations <= ks[-1] <= ref.iterations + 1
    assert abs(seen[-1][1] - ref.objective) <= 1e-9 * abs(ref.objective) and seen[-1][2] < 1e-6
    assert ref.status == "Solve_Succeeded"
    assert ref.iterations > 0 and ref.solve_time_s > 0 and ref.compile_time_s > 0
    assert ref.max_constraint_violation < 1e-6  # IPOPT relaxes bounds by 1e-8 relative (forces ~1e3 N)
    assert np.max(np.abs(ref.x - ours.x)) <= 1e-6
    assert abs(ref.objective - ours.objective) <= 1e-8 * max(1.0, abs(ours.objective))
    assert np.max(np.abs(ref.lam_g - ours.lam_g)) <= 1e-4 * max(1.0, np.max(np.abs(ours.lam_g)))
    assert ref.history["objective"].size == len(ks)


def test_equilibrium_torques_match_fixed_entries():
    problem = build_problem("T3", "A,F+C,1S", N=4)
    np.testing.assert_allclose(
        build_casadi_nlp(problem).u0, problem.full(problem.bounds.x0)[0, 10:15], rtol=1e-12, atol=1e-9
    )


def test_rejects_bad_arguments():
    problem = _stage1_problem(4)
    with pytest.raises(ValueError, match="x0"):
        solve_casadi(problem, x0=np.zeros(3))
    with pytest.raises(ValueError, match="options"):
        solve_casadi(problem, options={"no_such_option": 1})
