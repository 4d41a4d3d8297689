"""CasADi twin of the NLP (7): values and derivatives agree with ours; CasADi's IPOPT solves a small
problem to the same point as our IPOPT path."""

import dataclasses

import casadi as ca
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.solvers.ipopt import solve_ipopt
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.validation import casadi_backend as cb
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
    # stage 1 of T3 on 10 intervals from the linear guess: both paths run the same IPOPT library
    # (``ipopt_capi.default_library``) on the same NLP and reach one point in the same iterations.
    # Longer paths (T1; or from the inverse-dynamics guess, 156 against 140 iterations) part after
    # the rounding-level differences between JAX's and CasADi's arithmetic and end at other optima.
    problem = _stage1_problem(10, "T3", "linear")
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


def _energy_dynamics(nb, active):
    """(q, qd, qdd, u, f) -> (B qdd + C qd + G - Q, foot reaction) of the Euler-Lagrange equations of the
    energy written from the chain geometry, by CasADi's AD: B = d2T/dqd2, C qd = (d/dq (B qd)) qd -
    dT/dq, G = dV/dq, Q = u + sum_i J_vi^T f_i with J_vi = dO_i/dq; the reaction from the COM
    accelerations J_l qdd + (d/dq (J_l qd)) qd."""
    n = nb.n
    q, qd, qdd, u = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd", "u"))
    f = ca.SX.sym("f", 2, len(active))
    theta = ca.cumsum(q)
    joint, joints, coms = ca.vertcat(0.0, nb.ankle_height), [], []
    for k in range(n):
        e = ca.vertcat(ca.cos(theta[k]), ca.sin(theta[k]))
        joint = joint + nb.a[k] * e
        joints.append(joint)
        coms.append(joint - nb.c[k] * e)
    com_jac = [ca.jacobian(p, q) for p in coms]
    kinetic = 0.5 * sum(nb.m[k] * ca.sumsqr(com_jac[k] @ qd) + nb.inertia[k] * ca.cumsum(qd)[k] ** 2 for k in range(n))
    potential = nb.g * sum(nb.m[k] * coms[k][1] for k in range(n))
    B = ca.hessian(kinetic, qd)[0]
    cqd = ca.jacobian(ca.gradient(kinetic, qd), q) @ qd - ca.gradient(kinetic, q)
    Q = u + sum(ca.jacobian(joints[i - 1], q).T @ f[:, j] for j, i in enumerate(active))
    accel = sum(nb.m[k] * (com_jac[k] @ qdd + ca.jacobian(com_jac[k] @ qd, q) @ qd) for k in range(n))
    reaction = accel + ca.vertcat(0.0, float(np.sum(nb.m)) * nb.g) - ca.sum2(f)
    return ca.Function("energy", [q, qd, qdd, u, f], [B @ qdd + cqd + ca.gradient(potential, q) - Q, reaction])


def _backend_dynamics(nb, active):
    n = nb.n
    q, qd, qdd, u = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd", "u"))
    f = ca.SX.sym("f", 2, len(active))
    scalars = lambda v: [v[k] for k in range(v.shape[0])]  # noqa: E731
    forces = [(f[0, j], f[1, j]) for j in range(len(active))]
    motion = (cb._cumsum(scalars(qd)), cb._cumsum(scalars(qdd)))  # absolute angle rates
    residual, reaction = cb._dynamics(nb, cb._Pose.of(scalars(q)), scalars(u), forces, active, motion)
    return ca.Function("backend", [q, qd, qdd, u, f], [ca.vertcat(*residual), ca.vertcat(*reaction)])


@pytest.mark.parametrize("n_links,active", [(5, (1, 4, 5)), (3, (2,))])
def test_dynamics_match_the_euler_lagrange_equations_of_the_energy(n_links, active):
    # the backend's O(n) form of (1)-(2) and of the foot reaction against the equations of motion
    # derived by AD from the kinetic and potential energy, at random states, torques and forces
    rng = np.random.default_rng(n_links)
    m = rng.uniform(2.0, 30.0, n_links)
    nb = dataclasses.replace(
        cb._numbers(build_problem("T1", "A,F+C,1S", N=3).p),
        a=rng.uniform(0.2, 0.6, n_links),
        c=rng.uniform(0.05, 0.2, n_links),
        m=m,
        inertia=rng.uniform(0.02, 2.0, n_links),
    )
    ours, energy = _backend_dynamics(nb, active), _energy_dynamics(nb, active)
    for _ in range(5):
        args = [rng.uniform(-3, 3, n_links), *rng.normal(0, 2, (3, n_links)), rng.normal(0, 300, (2, len(active)))]
        for mine, theirs in zip(ours(*args), energy(*args)):
            np.testing.assert_allclose(np.asarray(mine), np.asarray(theirs), rtol=1e-12, atol=1e-9)
    # the comparison sees a change of one inertia by 1e-6 relative
    changed = dataclasses.replace(nb, inertia=nb.inertia * (1 + 1e-6 * (np.arange(n_links) == 1)))
    res_changed, res = (np.asarray(fn(*args)[0]) for fn in (_backend_dynamics(changed, active), energy))
    assert not np.allclose(res_changed, res, rtol=1e-12, atol=1e-9)
