"""The parts of the interior-point method on their own, on tiny hand-made inputs with known answers:
the filter, the barrier update and its floor, the fraction to the boundary, the kappa_sigma
safeguard, the inertia correction's delta_w rules and degeneracy test, the restoration phase's
entry and return test, the optimality errors and the status priority."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaxhumanoid.solvers.ipm import barrier, inertia, linesearch, restoration, step, termination
from jaxhumanoid.solvers.ipm.algorithm import start_at
from jaxhumanoid.solvers.ipm.filter import filter_add, filter_ok, filter_reset
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import make_context, make_prob
from jaxhumanoid.solvers.ipm.state import Evals, Iterate, Prob, Resto, fresh_globalization, inactive_resto
from jaxhumanoid.solvers.status import Status
from jaxhumanoid.validation import testproblems as tp

O = IPMOptions()
INF = np.inf


def box_prob(xl, xu, gl=(), gu=(), sf=1.0):
    """A Prob with the given (unrelaxed, unscaled) bounds; no fixed variables."""
    xl, xu, gl, gu = (jnp.asarray(v, float) for v in (xl, xu, gl, gu))
    eq = gl == gu
    return Prob(
        p=None,
        xl=xl,
        xu=xu,
        gl=gl,
        gu=gu,
        hxl=jnp.isfinite(xl),
        hxu=jnp.isfinite(xu),
        fixed=jnp.zeros(xl.shape, bool),
        eq=eq,
        hsl=jnp.isfinite(gl) & ~eq,
        hsu=jnp.isfinite(gu) & ~eq,
        free=~eq & ~jnp.isfinite(gl) & ~jnp.isfinite(gu),
        sf=jnp.asarray(sf),
        sg=jnp.ones(gl.shape),
    )


# ---------------------------------------------------------------- filter (Sec. 2.3)
def test_filter_acceptance_and_augmentation():
    G = fresh_globalization(3, 1e-4, 10.0)
    assert bool(filter_ok(G, 5.0, 1e9))
    assert not bool(filter_ok(G, 11.0, -1e9)), "theta above theta_max"
    G = filter_add(O, G, 2.0, 1.0)
    # the entry carries the margins of (18): ((1 - gamma_theta) theta, phi - gamma_phi theta)
    assert float(G.filt_theta[0]) == (1 - O.gamma_theta) * 2.0
    assert float(G.filt_phi[0]) == 1.0 - O.gamma_phi * 2.0
    assert int(G.filt_n) == 1
    assert not bool(filter_ok(G, 2.0, 1.0)), "dominated in both theta and phi"
    assert bool(filter_ok(G, 1.0, 5.0)) and bool(filter_ok(G, 5.0, 0.5))
    # ring buffer of filter_size entries: the fourth entry overwrites the first
    o3 = O.replace(filter_size=3)
    for theta in (3.0, 4.0, 0.1):
        G = filter_add(o3, G, theta, 10.0)
    assert int(G.filt_n) == 4 and float(G.filt_theta[0]) == (1 - O.gamma_theta) * 0.1
    G = filter_reset(o3, G)
    assert int(G.filt_n) == 0 and np.all(np.isinf(G.filt_theta)) and float(G.theta_max) == 10.0


def test_switching_armijo_and_sufficient_decrease():
    G = fresh_globalization(4, 1e-4, 1e4)
    # small theta and a descent direction: the switching condition (19) holds, Armijo (20) decides
    ref = linesearch.Reference(jnp.asarray(1e-6), jnp.asarray(1.0), jnp.asarray(-1.0))
    acc, ftype = linesearch.acceptable(O, G, ref, 1.0, 1e-6, 0.5)
    assert bool(acc) and bool(ftype)
    acc, _ = linesearch.acceptable(O, G, ref, 1.0, 1e-7, 1.0)
    assert not bool(acc), "no Armijo decrease of phi"
    # large theta: sufficient decrease (18) of theta alone is enough (an h-type step)
    ref = linesearch.Reference(jnp.asarray(1.0), jnp.asarray(1.0), jnp.asarray(-1.0))
    acc, ftype = linesearch.acceptable(O, G, ref, 1.0, 0.5, 2.0)
    assert bool(acc) and not bool(ftype)
    acc, _ = linesearch.acceptable(O, G, ref, 1.0, 1.0, 1.0)
    assert not bool(acc)
    # alpha_min (23): gamma_theta when the direction is not a descent direction
    assert float(linesearch.alpha_min(O, 1.0, 1e-4, 1.0)) == O.alpha_min_frac * O.gamma_theta


# ---------------------------------------------------------------- barrier update (7) and its floor
def test_mu_update_rule_and_floor():
    assert float(barrier.next_mu(O, 0.1, 0.0)) == pytest.approx(0.02)  # kappa_mu mu
    assert float(barrier.next_mu(O, 1e-3, 0.0)) == pytest.approx(1e-3**1.5)  # mu^theta_mu
    assert float(barrier.next_mu(O, 1e-9, 1e-8)) == 1e-8  # the floor
    P = box_prob([0.0], [INF], sf=0.5)
    assert float(barrier.mu_floor(O, P)) == pytest.approx(min(1e-8, 1e-4 * 0.5) / 11.0)


def test_mu_decreases_while_the_barrier_error_is_small():
    def err(mu):
        return jnp.asarray(1e-3)

    mu, n = barrier.update_mu(O, jnp.asarray(0.1), 1e-9, err, jnp.zeros((), bool), jnp.zeros((), bool))
    # 0.1 -> 0.02 -> 0.004 -> 0.004^1.5 = 2.53e-4 -> 4.0e-6: E_mu = 1e-3 > kappa_eps mu stops it
    expected, k = 0.1, 0
    while 10.0 * expected >= 1e-3:
        expected, k = min(0.2 * expected, expected**1.5), k + 1
    assert int(n) == k == 4 and float(mu) == pytest.approx(expected)
    mu, n = barrier.update_mu(
        O, jnp.asarray(0.1), 1e-9, lambda mu: jnp.asarray(10.0), jnp.ones((), bool), jnp.zeros((), bool)
    )
    assert int(n) == 1 and float(mu) == pytest.approx(0.02), "a forced update happens once"
    _, n = barrier.update_mu(O, jnp.asarray(0.1), 1e-9, err, jnp.zeros((), bool), jnp.ones((), bool))
    assert int(n) == 0, "no update in the restoration phase's first iteration"
    mu, n = barrier.update_mu(
        O, jnp.asarray(0.1), 1e-3, lambda mu: jnp.asarray(0.0), jnp.zeros((), bool), jnp.zeros((), bool)
    )
    assert float(mu) == 1e-3 and int(n) == 3


# ---------------------------------------------------------------- fraction to the boundary (15), safeguard (16)
def test_fraction_to_the_boundary():
    P = box_prob([0.0, -INF], [1.0, 2.0], [0.0], [INF])
    x, s = jnp.array([0.5, 1.0]), jnp.array([0.2])
    tau = 0.99
    a = step.frac_to_boundary(P, x, s, jnp.array([-1.0, 0.0]), jnp.array([0.0]), tau)
    assert float(a) == pytest.approx(tau * 0.5)
    a = step.frac_to_boundary(P, x, s, jnp.array([0.0, 4.0]), jnp.array([-0.1]), tau)
    assert float(a) == pytest.approx(tau * 1.0 / 4.0)
    assert float(step.frac_to_boundary(P, x, s, jnp.array([0.1, -5.0]), jnp.array([1.0]), tau)) == 1.0
    assert float(
        step.smallest(step.dual_ratios(jnp.array([2.0, 1.0]), jnp.array([-4.0, -0.5]), jnp.array([True, True]), tau))
    ) == pytest.approx(tau * 0.5)


def test_one_reduction_equals_the_reductions_of_each_vector():
    """``step.smallest`` and ``step.max_abs`` (one reduction of the concatenation, fewer kernels in
    the compiled loop) give the bits of a reduction per vector, NaN and infinities included."""
    rng = np.random.default_rng(3)
    vs = [jnp.asarray(rng.standard_normal(k) * 10.0 ** rng.integers(-8, 8, k)) for k in (7, 0, 40, 3)]
    vs[2] = vs[2].at[5].set(jnp.inf)
    ratios = [jnp.where(v < 0, -0.99 / jnp.where(v < 0, v, -1.0), 1.0) for v in vs]
    old_min = jnp.min(jnp.stack([jnp.min(r, initial=1.0) for r in ratios]))
    assert float(step.smallest(*ratios)) == float(old_min)
    old_max = jnp.max(jnp.stack([jnp.max(jnp.abs(v), initial=0.0) for v in vs]))
    assert float(step.max_abs(*vs)) == float(old_max)
    with_nan = [vs[0], vs[1].at[:].set(0.0), vs[2].at[1].set(jnp.nan)]
    assert math.isnan(float(step.max_abs(*with_nan)))
    assert math.isnan(float(jnp.max(jnp.stack([jnp.max(jnp.abs(v), initial=0.0) for v in with_nan]))))


def test_kappa_sigma_safeguard():
    mu, ks = 0.1, O.kappa_sigma
    mask = jnp.array([True, True, True, False])
    d = jnp.array([1.0, 2.0, 1.0, 1.0])
    z = step.clip_mult(O, jnp.array([1e12, 1e-14, 0.3, 5.0]), d, mask, mu)
    np.testing.assert_allclose(z, [ks * mu / 1.0, mu / (ks * 2.0), 0.3, 0.0])


# ---------------------------------------------------------------- inertia correction (Algorithm IC)
def test_delta_w_first_increase_decrease():
    assert float(inertia.wrong_inertia_dw(O, 0.0, 0.0)) == O.first_hessian_perturbation
    assert float(inertia.wrong_inertia_dw(O, 0.0, 3e-4)) == pytest.approx(O.perturb_dec_fact * 3e-4)
    assert float(inertia.wrong_inertia_dw(O, 0.0, 1e-30)) == O.min_hessian_perturbation
    # growth: perturb_inc_fact_first without history or far above it, else perturb_inc_fact
    assert float(inertia.wrong_inertia_dw(O, 1e-4, 0.0)) == pytest.approx(100.0 * 1e-4)
    assert float(inertia.wrong_inertia_dw(O, 1e-4, 1e-10)) == pytest.approx(100.0 * 1e-4)
    assert float(inertia.wrong_inertia_dw(O, 1e-4, 1e-6)) == pytest.approx(8.0 * 1e-4)


def test_degeneracy_test_bookkeeping():
    U, N, D = inertia.UNDETERMINED, inertia.NOT_DEGENERATE, inertia.DEGENERATE
    pert0 = jnp.array([U, U, 0], jnp.int32)
    np.testing.assert_array_equal(inertia.finalize_test(O, inertia.T_00, pert0), [N, N, 0])
    np.testing.assert_array_equal(inertia.finalize_test(O, inertia.T_C0, pert0), [N, U, 1])
    np.testing.assert_array_equal(inertia.finalize_test(O, inertia.T_C0, jnp.array([N, U, 2])), [N, D, 3])
    np.testing.assert_array_equal(inertia.finalize_test(O, inertia.T_0X, jnp.array([U, N, 2])), [D, N, 3])
    np.testing.assert_array_equal(inertia.finalize_test(O, inertia.T_NONE, jnp.array([N, D, 3])), [N, D, 3])
    # singular K while undetermined: (0,0) -> (c,0) -> (0,x) -> (c,x)
    dcd = 1e-9
    dc, grow, test = inertia.singular_rule(inertia.T_00, pert0, 0.0, dcd)
    assert (float(dc), bool(grow), int(test)) == (dcd, False, inertia.T_C0)
    dc, grow, test = inertia.singular_rule(inertia.T_C0, pert0, dcd, dcd)
    assert (float(dc), bool(grow), int(test)) == (0.0, True, inertia.T_0X)
    dc, grow, test = inertia.singular_rule(inertia.T_0X, pert0, 0.0, dcd)
    assert (float(dc), bool(grow), int(test)) == (dcd, True, inertia.T_CX)
    # decided: delta_c first, then delta_w
    decided = jnp.array([N, N, 0], jnp.int32)
    assert (
        float(inertia.singular_rule(inertia.T_NONE, decided, 0.0, dcd)[0]),
        bool(inertia.singular_rule(inertia.T_NONE, decided, 0.0, dcd)[1]),
    ) == (dcd, False)
    assert bool(inertia.singular_rule(inertia.T_NONE, decided, dcd, dcd)[1])


def _ic(nlp, Wvals, jac, dw_last, pert, mu=0.1, o=O):
    ctx = make_context(nlp, o)
    P = box_prob([-INF] * nlp.n, [INF] * nlp.n, [0.0] * nlp.m, [0.0] * nlp.m)
    zn, zm = jnp.zeros(nlp.n), jnp.zeros(nlp.m)
    return inertia.inertia_corrected_factor(
        ctx,
        P,
        jnp.zeros(nlp.m, bool),
        jnp.asarray(Wvals),
        jnp.asarray(jac),
        zn,
        zm,
        zm,
        zm,
        jnp.asarray(dw_last),
        mu,
        jnp.asarray(pert, jnp.int32),
    )


def test_inertia_correction_of_a_nonconvex_hessian():
    """min -x0^2/2 s.t. x0 + x1 = 0: the reduced Hessian 2 delta_w - 1 needs delta_w > 1/2, reached
    by 0, 1e-4, 1e-2, 1 (perturb_inc_fact_first), then from the memory 1/3, 8/3 (perturb_inc_fact)."""
    nlp = tp.dense_nlp("ic_nonconvex", 2, 1, lambda x, p: -0.5 * x[0] ** 2, lambda x, p: jnp.array([x[0] + x[1]]))
    r = _ic(nlp, [-1.0, 0.0, 0.0], [1.0, 1.0], 0.0, [0, 0, 0])
    assert bool(r.ok) and int(r.n_fact) == 4
    assert float(r.dw) == pytest.approx(1.0) and float(r.dw_last) == pytest.approx(1.0) and float(r.dc) == 0.0
    np.testing.assert_array_equal(r.pert, [1, 1, 0])
    r = _ic(nlp, [-1.0, 0.0, 0.0], [1.0, 1.0], 1.0, r.pert)
    assert bool(r.ok) and int(r.n_fact) == 3 and float(r.dw) == pytest.approx(8.0 / 3.0)


def test_the_last_delta_w_as_first_trial_saves_the_plain_factorisation():
    """inertia_first_trial="last": 1/3, 8/3 without the delta_w = 0 trial once the Hessian is
    decided; while the degeneracy test is undetermined the plain trial still comes first."""
    nlp = tp.dense_nlp("ic_nonconvex", 2, 1, lambda x, p: -0.5 * x[0] ** 2, lambda x, p: jnp.array([x[0] + x[1]]))
    last = O.replace(inertia_first_trial="last")
    r = _ic(nlp, [-1.0, 0.0, 0.0], [1.0, 1.0], 1.0, [1, 1, 0], o=last)
    assert bool(r.ok) and int(r.n_fact) == 2 and float(r.dw) == pytest.approx(8.0 / 3.0)
    r = _ic(nlp, [-1.0, 0.0, 0.0], [1.0, 1.0], 1.0, [0, 0, 0], o=last)
    assert bool(r.ok) and int(r.n_fact) == 3 and float(r.dw) == pytest.approx(8.0 / 3.0)
    convex = _ic(nlp, [1.0, 0.0, 1.0], [1.0, 1.0], 1.0, [1, 1, 0], o=last)  # the plain trial would do
    assert bool(convex.ok) and int(convex.n_fact) == 1 and float(convex.dw) == pytest.approx(1.0 / 3.0)
    with pytest.raises(ValueError, match="inertia_first_trial must be one of"):
        O.replace(inertia_first_trial="always")


def test_degenerate_jacobian_is_detected_after_degen_iters_max():
    """A constraint with a vanishing gradient makes K singular; (delta_c, 0) cures it. After
    degen_iters_max such iterations the Jacobian is declared degenerate and delta_c is applied
    from the first trial on."""
    nlp = tp.dense_nlp(
        "ic_degenerate", 2, 2, lambda x, p: 0.5 * jnp.sum(x**2), lambda x, p: jnp.array([x[0] + x[1], 0.0 * x[0]])
    )
    hess, jac = [1.0, 0.0, 1.0], [1.0, 1.0, 0.0, 0.0]
    pert, mu = jnp.zeros(3, jnp.int32), 0.1
    dcd = O.jacobian_regularization_value * mu**O.jacobian_regularization_exponent
    for k in range(O.degen_iters_max):
        r = _ic(nlp, hess, jac, 0.0, pert, mu)
        assert bool(r.ok) and int(r.n_fact) == 2 and float(r.dw) == 0.0
        assert float(r.dc) == pytest.approx(dcd)
        pert = r.pert
        assert int(pert[2]) == k + 1
    np.testing.assert_array_equal(pert, [1, 2, O.degen_iters_max])
    r = _ic(nlp, hess, jac, 0.0, pert, mu)
    assert bool(r.ok) and int(r.n_fact) == 1 and float(r.dc) == pytest.approx(dcd)


# ---------------------------------------------------------------- restoration phase (Sec. 3.3)
@pytest.fixture(scope="module")
def shifted():
    """min |x|^2/2 s.t. x0 + 1 = 0, x1 - 2 = 0, started at x = 0 where c = (1, -2)."""
    nlp = tp.dense_nlp(
        "resto_shift", 2, 2, lambda x, p: 0.5 * jnp.sum(x**2), lambda x, p: jnp.array([x[0] + 1.0, x[1] - 2.0])
    )
    ctx = make_context(nlp, O)
    P, x, raw = make_prob(ctx, jnp.zeros(2), [-INF] * 2, [INF] * 2, [0.0, 0.0], [0.0, 0.0], None)
    return ctx, P, start_at(ctx, P, x, raw)[0]


def test_restoration_entry_initialises_p_n_by_ipopts_formula(shifted):
    ctx, P, S = shifted
    c = np.array([1.0, -2.0])
    np.testing.assert_allclose(S.ev.g, c)
    Sr = restoration.enter_restoration(ctx, P, S, 0.1, 3.0, 0.5)
    R, rho = Sr.rs, O.resto_penalty_parameter
    mu_r = max(0.1, 2.0)  # max(mu, ||c||_inf)
    a = mu_r / (2 * rho) - c / 2
    n = a + np.sqrt(a * a + c * mu_r / (2 * rho))
    np.testing.assert_allclose(R.n, n, rtol=1e-14)
    np.testing.assert_allclose(R.p, c + n, rtol=1e-14)
    np.testing.assert_allclose(np.asarray(R.p) - np.asarray(R.n), c, atol=1e-14)  # c - p + n = 0
    np.testing.assert_allclose(R.zp, mu_r / np.asarray(R.p))
    np.testing.assert_allclose(R.zn, mu_r / np.asarray(R.n))
    assert bool(R.on) and bool(R.fresh) and float(Sr.mu) == mu_r and float(R.mu_orig) == 0.1
    np.testing.assert_array_equal(Sr.it.y, 0.0)
    np.testing.assert_allclose(R.dr, 1.0)  # 1/max(1, |x_R|)^2 at x_R = 0
    assert int(Sr.gl.filt_n) == 0 and float(Sr.gl.theta_max) == O.resto_theta_max_fact
    assert float(R.theta_ref) == 3.0 and float(R.inf_ref) == 2.0
    assert float(R.outer.theta_max) == float(S.gl.theta_max)


def test_restoration_return_test(shifted):
    ctx, P, S = shifted
    R = restoration.enter_restoration(ctx, P, S, 0.1, 3.0, 0.5).rs
    f = jnp.asarray(0.0)
    # feasible: infeasibility reduced, outer filter empty, theta below the starting theta
    assert bool(restoration.restoration_done(O, P, R, f, jnp.zeros(2), jnp.array([-1.0, 2.0]), jnp.zeros(2)))
    # ||c||_inf = 1.85 > kappa_resto * 2: not reduced enough
    assert not bool(restoration.restoration_done(O, P, R, f, jnp.array([0.5, -1.85]), jnp.zeros(2), jnp.zeros(2)))
    assert bool(restoration.restoration_done(O, P, R, f, jnp.array([0.5, -1.75]), jnp.zeros(2), jnp.zeros(2)))
    # a point the outer filter blocks is not a return point
    blocked = R._replace(outer=filter_add(O, R.outer, 0.0, -1e300))
    assert not bool(restoration.restoration_done(O, P, blocked, f, jnp.zeros(2), jnp.array([-1.0, 2.0]), jnp.zeros(2)))


def test_leaving_restoration_steps_the_bound_multipliers(shifted):
    """Back in the original problem, z takes one complementarity step as if the restoration had
    been one primal step from x_R to x: dz = ((a - b) z + mu)/a - z with a = x_R - xl, b = x - xl,
    cut by the fraction to the boundary; above bound_mult_reset_threshold all reset to 1."""
    ctx, _, S = shifted
    P = box_prob([0.0, -INF], [INF, INF], [0.0, 0.0], [0.0, 0.0])

    def leave(x_r, x, z):
        start = S._replace(it=S.it._replace(x=jnp.array([x_r, 0.0]), zl=jnp.array([z, 0.0])))
        R = restoration.enter_restoration(ctx, P, start, 0.1, 3.0, 0.5).rs
        return restoration.leave_restoration(ctx, P, S._replace(rs=R, it=S.it._replace(x=jnp.array([x, 0.0]))))

    out = leave(1.0, 2.0, 2.0)
    dz = ((1.0 - 2.0) * 2.0 + 0.1) / 1.0 - 2.0
    a_du = 0.99 * 2.0 / -dz
    assert float(out.it.zl[0]) == pytest.approx(2.0 + a_du * dz) and float(out.it.zl[0]) == pytest.approx(0.02)
    assert not bool(out.rs.on) and float(out.mu) == 0.1 and float(jnp.max(jnp.abs(out.it.y))) == 0.0
    out = leave(1e-5, 1e-5, 0.0)  # dz = mu / a = 1e4
    np.testing.assert_array_equal(out.it.zl, [1.0, 0.0])


# ---------------------------------------------------------------- termination
def test_optimality_errors_known_values():
    """min x0 s.t. x0 - x1 = 0, x0 >= 0 at x = (1, 1), y = 0.5, z_l = (1.5, 0), mu = 0.5:
    grad L = (0, -0.5), c = 0, complementarity x0 z_l0 = 1.5, s_d = s_c = 1."""
    nlp = tp.dense_nlp("errors", 2, 1, lambda x, p: x[0], lambda x, p: jnp.array([x[0] - x[1]]))
    ctx = make_context(nlp, O)
    P = box_prob([0.0, -INF], [INF, INF], [0.0], [0.0])
    it = Iterate(
        jnp.array([1.0, 1.0]),
        jnp.zeros(1),
        jnp.array([0.5]),
        jnp.array([1.5, 0.0]),
        jnp.zeros(2),
        jnp.zeros(1),
        jnp.zeros(1),
    )
    ev = Evals(jnp.asarray(1.0), jnp.zeros(1), jnp.array([1.0, 0.0]), jnp.array([1.0, -1.0]))
    e = termination.errors(ctx, P, it, ev, 0.5, inactive_resto(2, 1, 4))
    assert float(e.dual) == 0.5 and float(e.primal) == 0.0 and float(e.compl) == 1.5
    assert float(e.E0) == 1.5 and float(e.Emu) == 1.0


def _status(**kw):
    args = dict(
        prior=int(Status.Running),
        finite=True,
        converged=False,
        resto_converged=False,
        resto_code=int(Status.Infeasible_Problem_Detected),
        acceptable_stop=False,
        tiny_stop=False,
        acceptable_point=False,
        out_of_iterations=False,
    )
    args.update(kw)
    args = {k: jnp.asarray(v) for k, v in args.items()}
    return Status(int(termination.decide_status(**args)))


def test_status_priority():
    assert _status() is Status.Running
    assert _status(out_of_iterations=True) is Status.Maximum_Iterations_Exceeded
    assert _status(tiny_stop=True, out_of_iterations=True) is Status.Search_Direction_Becomes_Too_Small
    assert _status(tiny_stop=True, acceptable_point=True) is Status.Solved_To_Acceptable_Level
    assert _status(acceptable_stop=True, tiny_stop=True) is Status.Solved_To_Acceptable_Level
    assert _status(resto_converged=True, acceptable_stop=True) is Status.Infeasible_Problem_Detected
    assert _status(converged=True, resto_converged=True) is Status.Solve_Succeeded
    assert _status(finite=False, converged=True) is Status.Invalid_Number_Detected
    assert _status(prior=int(Status.Restoration_Failed), finite=False) is Status.Restoration_Failed
    code = termination.step_status(jnp.asarray(False), jnp.asarray(True), jnp.asarray(False))
    assert Status(int(code)) is Status.Error_In_Step_Computation
    code = termination.step_status(jnp.asarray(False), jnp.asarray(True), jnp.asarray(True))
    assert Status(int(code)) is Status.Restoration_Failed
    code = termination.step_status(jnp.asarray(True), jnp.asarray(False), jnp.asarray(True))
    assert Status(int(code)) is Status.Solved_To_Acceptable_Level


def test_inactive_restoration_keeps_the_logarithms_finite():
    R = inactive_resto(3, 2, 4)
    assert isinstance(R, Resto) and not bool(R.on)
    np.testing.assert_array_equal(R.p, 1.0)
    np.testing.assert_array_equal(R.dr, 0.0)
    assert math.isinf(float(R.outer.filt_theta[0]))
