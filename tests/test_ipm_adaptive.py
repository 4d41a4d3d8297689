"""The adaptive barrier update of the IPM (``mu_strategy="adaptive"``, solvers/ipm/mu_oracle.py):
the section search, the quality-function oracle on a hand-made iterate, the switch between free
and fixed mode, the option's validation, and convergence to the monotone update's optima."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxhumanoid.ocp.nlp import Bounds
from jaxhumanoid.solvers.ipm import batch_solve_ipm, mu_oracle, solve_ipm
from jaxhumanoid.solvers.ipm.algorithm import start_at
from jaxhumanoid.solvers.ipm.direction import kkt_factor
from jaxhumanoid.solvers.ipm.options import make_options
from jaxhumanoid.solvers.ipm.problem import make_context, make_prob
from jaxhumanoid.validation import testproblems as tp

SHRINK = (1.0 - mu_oracle.GOLDEN) ** 8  # the bracket left after IPOPT's 8 sections


@pytest.mark.parametrize("steps", [8, 100])
def test_golden_section_finds_the_minimiser(steps):
    def q(s):
        return (s - 0.3) ** 2 + 1.0

    run = jax.jit(lambda lo, up: mu_oracle.golden_section(q, lo, up, mu_oracle.UNKNOWN, q(up), 1e-12, 0.0, steps))
    sigma = float(run(0.0, 1.0))
    assert abs(sigma - 0.3) <= (SHRINK if steps == 8 else 1e-6)
    # a minimiser at an end of the interval is found by the final comparison with that end
    edge = float(jax.jit(lambda: mu_oracle.golden_section(q, 0.5, 2.0, mu_oracle.UNKNOWN, q(2.0), 1e-2, 0.0, 8))())
    assert edge == 0.5


def one_dim():
    """min (x - 2)^2 s.t. x >= 0 from x = 1: hand-made numbers (no scaling, no bound relaxation)."""
    nlp = tp.dense_nlp("adaptive_1d", 1, 0, lambda x, p: (x[0] - 2.0) ** 2, lambda x, p: jnp.zeros(0))
    bounds = Bounds(np.ones(1), np.zeros(1), np.full(1, np.inf), np.zeros(0), np.zeros(0))
    o = make_options({"mu_strategy": "adaptive", "nlp_scaling_method": "none", "bound_relax_factor": 0.0})
    ctx = make_context(nlp, o)
    P, x, raw = make_prob(ctx, bounds.x0, bounds.xl, bounds.xu, bounds.gl, bounds.gu, None)
    return ctx, P, start_at(ctx, P, x, raw)[0]  # checked, as the loop starts from it


def quality_1d(sigma, tau=0.99):
    """q(sigma) at x = 1, z = 1 by hand: W + Sigma = 3, d_aff: dx = 2/3, dz = -1 - dx; d_cen:
    dx = (1 - kappa_d)/3, dz = 1 - dx; grad L = -3; a_pr = 1 (dx > 0)."""
    dx_c = (1.0 - make_options(None).kappa_d) / 3.0
    dx = 2.0 / 3.0 + sigma * dx_c
    dz = -5.0 / 3.0 + sigma * (1.0 - dx_c)
    a_du = min(1.0, tau / -dz) if dz < 0 else 1.0
    return (1.0 - a_du) ** 2 * 9.0 + ((1.0 + dx) * (1.0 + a_du * dz)) ** 2, dx


def test_oracle_sigma_on_a_hand_made_iterate():
    ctx, P, S = one_dim()
    assert float(mu_oracle.avrg_compl(P, S.it)[0]) == 1.0
    mu, nw = jax.jit(lambda S_: mu_oracle.oracle_direction(ctx, P, S_, kkt_factor(ctx, P, S_, S_.mu), 0.99))(S)
    sigma = float(mu)  # avrg = 1
    grid = np.linspace(1.0, 100.0, 200001)
    q = np.array([quality_1d(s)[0] for s in grid])
    assert quality_1d(1.0 - 1e-2)[0] > quality_1d(1.0)[0]  # the search runs on [1, sigma_max]
    s_star = grid[np.argmin(q)]
    assert 1.0 < s_star < 100.0
    assert abs(sigma - s_star) <= SHRINK * 99.0
    assert quality_1d(sigma)[0] <= quality_1d(1.0)[0]
    # the step is d_aff + sigma d_cen
    assert abs(float(nw.d.dx[0]) - quality_1d(sigma)[1]) < 1e-12


def test_free_mode_switches_to_fixed_when_progress_stalls_and_back():
    ctx, P, S = one_dim()
    mode = jax.jit(lambda S_: mu_oracle.adaptive_mode(ctx, P, S_))
    S1, _, _, nupd, free = mode(S)
    assert bool(free) and int(nupd) == 1 and int(S1.am.filt_n) == 1  # the start point is remembered
    # the same point again: no progress over its own filter entry, so fixed mode starts with
    # mu = adaptive_mu_monotone_init_factor * avrg
    S2, mu2, tau2, _, free2 = mode(S1)
    assert not bool(free2) and not bool(S2.am.free)
    assert float(mu2) == pytest.approx(0.8 * 1.0) and float(tau2) == pytest.approx(0.99)
    # still no progress: fixed mode stays, mu only decreases by the monotone rule
    S3, mu3, _, _, free3 = mode(S2._replace(mu=mu2))
    assert not bool(free3) and float(mu3) <= float(mu2)
    # a filter the point improves on: back to free mode
    far = S2.am._replace(filt_f=S2.am.filt_f + 1.0, filt_theta=S2.am.filt_theta + 1.0)
    assert bool(mode(S2._replace(am=far))[4])
    # a tiny step forces fixed mode even with progress
    assert not bool(mode(S._replace(tiny_count=jnp.ones((), jnp.int32)))[4])


def test_bad_mu_strategy_is_refused():
    with pytest.raises(ValueError, match="mu_strategy.*'monotone', 'adaptive'"):
        make_options({"mu_strategy": "probing"})
    with pytest.raises(ValueError, match="sigma_min"):
        make_options({"mu_strategy": "adaptive", "sigma_min": 1e3})


ALL_CASES = {**tp.HS_PROBLEMS, "wachter_biegler": tp.wachter_biegler, "infeasible_disk": tp.infeasible_disk}
# one through the restoration phase (HS071 in the vmap test below); every test problem with -m slow
QUICK = ("infeasible_disk",)


def check_against_monotone(name):
    nlp, bounds, p, _ = ALL_CASES[name]()
    mono = solve_ipm(nlp, p, bounds)
    adap = solve_ipm(nlp, p, bounds, options={"mu_strategy": "adaptive"})
    assert adap.status == mono.status, (adap.status, mono.status)
    assert abs(adap.objective - mono.objective) <= 1e-6 * max(1.0, abs(mono.objective))
    # the adaptive path is a different algorithm: its barrier parameters differ from monotone's
    mu_a, mu_m = np.asarray(adap.history["mu"]), np.asarray(mono.history["mu"])
    n = min(len(mu_a), len(mu_m))
    assert not np.array_equal(mu_a[1:n], mu_m[1:n])


@pytest.mark.parametrize("name", QUICK)
def test_adaptive_converges_to_the_monotone_optimum(name):
    check_against_monotone(name)


@pytest.mark.slow
@pytest.mark.parametrize("name", [k for k in ALL_CASES if k not in QUICK])
def test_adaptive_converges_to_the_monotone_optimum_on_every_test_problem(name):
    check_against_monotone(name)


def test_adaptive_under_vmap_matches_single_solves():
    nlp, bounds, _, _ = tp.hs071()
    P = jnp.asarray([[25.0, 40.0], [24.0, 41.0]])
    res = batch_solve_ipm(nlp, P, bounds, options={"mu_strategy": "adaptive"})
    for pk, rb in zip(P, res):
        rs = solve_ipm(nlp, pk, bounds, options={"mu_strategy": "adaptive"})
        assert rb.success and rs.iterations == rb.iterations
        assert math.isclose(rs.objective, rb.objective, rel_tol=1e-9)
    assert abs(res[0].objective - 17.0140172891) <= 1e-6 * 17.0140172891  # the monotone update's optimum
