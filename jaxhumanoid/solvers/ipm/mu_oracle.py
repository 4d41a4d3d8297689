"""The adaptive barrier-parameter update, ``mu_strategy="adaptive"``: IPOPT 3.14's adaptive update
with its default oracles, after Nocedal, Waechter & Waltz (2009), "Adaptive barrier update
strategies for nonlinear interior methods", SIAM J. Optim. 19(4):1674-1693 (NWW). Equation numbers
(13), (15), (7) refer to the IPOPT paper, as in the other modules.

Free mode (the quality-function oracle, NWW's quality-function rule). With the average
complementarity avrg = (sum of slack_i z_i over the n_c finite bounds) / n_c, the step for
mu = sigma avrg is affine in sigma:

    d(sigma) = d_aff + sigma d_cen

d_aff: the Newton step (13) for mu = 0 (affine scaling); d_cen: avrg times the derivative of the
step in mu (centering); two solves with one factorisation. sigma minimises the quality function
(IPOPT's defaults: 2-norm-squared, no centrality and no balancing term)

    q(sigma) = (1 - a_du)^2 ||grad L||^2 / n_d + (1 - a_pr)^2 ||c||^2 / n_p
               + ||(s_b + a_pr ds_b(sigma)) * (z + a_du dz(sigma))||^2 / n_c

(n_d: free variables plus inequality rows, n_p = m, s_b the slacks to all finite bounds, a_pr,
a_du the fraction-to-the-boundary steps (15) of d(sigma) with tau = max(tau_min, 1 - E_0)), by a
golden-section search on [1, min(sigma_max, mu_max/avrg)] when q(1 - 0.01) > q(1), else on
[max(sigma_min, mu_min/avrg), 0.99]; then mu = sigma avrg, clipped to [mu_min, mu_max] with
mu_max = mu_max_fact times avrg at the start point and mu_min = min(mu_min option,
min(tol, compl_inf_tol) / 2) (IPOPT).

Globalisation (IPOPT's obj-constr-filter, NWW's safeguard): a filter of the (f, ||c||_1) pairs of
the points accepted in free mode. The current point makes sufficient progress when, for every
entry, f + margin <= f_i or theta + margin <= theta_i, margin = filter_margin_fact *
min(filter_max_margin, E_0). Free mode continues, and adds the point, while the iterates make
progress and the last step was not tiny; else fixed mode: mu = adaptive_mu_monotone_init_factor
* avrg (fixed_mu_oracle = average_compl), then the monotone rule, one decrease (7) per iteration
when E_mu <= kappa_eps mu (or after a tiny step), tau = max(tau_min, 1 - mu). As in IPOPT 3.14,
fixed mode returns to free mode as soon as the current point makes sufficient progress with
respect to that filter (the barrier error E_mu decides the decreases inside fixed mode). Every
change of mu empties the line search's filter. The matrix of free mode is factored with the
previous mu in its regularisation delta_c, as IPOPT's oracle does (mu is not known yet).

Simplifications, with their reasons:

* The restoration phase keeps the monotone rule (``barrier.update_mu``) and the adaptive state
  is left as it is while it runs (IPOPT runs its restoration with the adaptive update too): the
  restoration problem's proximity term weighs sqrt(mu), so its step is not affine in mu and the
  two-solve oracle does not apply as it stands; the restoration phase is rare in free mode.
* The filter holds ``filter_size`` entries (dominated ones are dropped, as in IPOPT); when all
  are taken the oldest-written slot is overwritten (IPOPT's list is unbounded; arrays here have
  a fixed shape).
* The step uses the clipped mu, d_aff + (mu / avrg) d_cen (IPOPT's uses the oracle's sigma, which
  lies in [mu_min, mu_max] / avrg except for degenerate search intervals).
* Not exposed: IPOPT's absolute mu_max, mu_target (0), adaptive_mu_safeguard_factor (0),
  adaptive_mu_restore_previous_iterate (no), the other oracles and globalisations.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax import lax

from jaxhumanoid.solvers.ipm.barrier import barrier_grad, mu_floor, next_mu
from jaxhumanoid.solvers.ipm.direction import newton, residuals
from jaxhumanoid.solvers.ipm.filter import filter_reset
from jaxhumanoid.solvers.ipm.inertia import Inertia
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import Context, jt_mult, slacks, theta_of
from jaxhumanoid.solvers.ipm.state import AdaptiveMu, Direction, Iterate, Prob, State, tree_where
from jaxhumanoid.solvers.ipm.step import dual_ratios, dual_steps, frac_to_boundary, smallest, solve_reduced
from jaxhumanoid.solvers.ipm.termination import errors_at

GOLDEN = (3.0 - math.sqrt(5.0)) / 2.0
UNKNOWN = -100.0  # a quality-function value not evaluated yet (q >= 0), IPOPT's marker


def avrg_compl(P: Prob, it: Iterate):
    """(average complementarity over the finite bounds of x and s, their number n_c)."""
    dxl, dxu, dsl, dsu = slacks(P, it.x, it.s)
    pairs = ((dxl, it.zl, P.hxl), (dxu, it.zu, P.hxu), (dsl, it.vl, P.hsl), (dsu, it.vu, P.hsu))
    total = sum(jnp.sum(jnp.where(m_, d * z, 0.0)) for d, z, m_ in pairs)
    n_c = sum(jnp.sum(m_) for _, _, m_ in pairs)
    return total / jnp.maximum(n_c, 1), n_c


def fresh_adaptive(o: IPMOptions, P: Prob, it: Iterate) -> AdaptiveMu:
    """Free mode, an empty filter and mu_max = mu_max_fact * avrg at the start point ``it``."""
    inf = jnp.full(o.filter_size, jnp.inf)
    return AdaptiveMu(
        free=jnp.ones((), bool),
        mu_max=o.mu_max_fact * avrg_compl(P, it)[0],
        filt_f=inf,
        filt_theta=inf,
        filt_n=jnp.zeros((), jnp.int32),
    )


def adaptive_state(S: State) -> AdaptiveMu:
    """S's adaptive-update state (present with ``mu_strategy="adaptive"``)."""
    if S.am is None:
        raise ValueError("the state carries no adaptive barrier update (mu_strategy is not 'adaptive')")
    return S.am


def mu_range(o: IPMOptions, P: Prob, A: AdaptiveMu):
    """(mu_min, mu_max) of the adaptive update; compl_inf_tol in the scaled problem's units."""
    return jnp.minimum(o.mu_min, 0.5 * jnp.minimum(o.tol, o.compl_inf_tol * P.sf)), A.mu_max


def sufficient_progress(o: IPMOptions, A: AdaptiveMu, f, theta, E0):
    """The point (f, theta) improves on every filter entry by the margin (IPOPT's test)."""
    margin = o.filter_margin_fact * jnp.minimum(o.filter_max_margin, E0)
    return jnp.all((f + margin <= A.filt_f) | (theta + margin <= A.filt_theta))


def remember(o: IPMOptions, A: AdaptiveMu, f, theta) -> AdaptiveMu:
    """The filter with (f, theta) added and the entries it dominates dropped; the new entry takes
    the first unused slot, else the oldest-written one."""
    dominated = (f <= A.filt_f) & (theta <= A.filt_theta)
    ff = jnp.where(dominated, jnp.inf, A.filt_f)
    ft = jnp.where(dominated, jnp.inf, A.filt_theta)
    unused = jnp.isinf(ft) & jnp.isinf(ff)
    i = jnp.where(jnp.any(unused), jnp.argmax(unused), A.filt_n % o.filter_size)
    return A._replace(filt_f=ff.at[i].set(f), filt_theta=ft.at[i].set(theta), filt_n=A.filt_n + 1)


def adaptive_mode(ctx: Context, P: Prob, S: State):
    """The mode decision of the adaptive update at S's iterate (outside the restoration phase).

    Free mode when the point makes sufficient progress and the last step was not tiny (or there
    are no bounds: then mu = mu_min), which adds the point to the filter; else fixed mode, mu from
    the average complementarity when it starts, else one monotone decrease (7) if
    E_mu <= kappa_eps mu or after a tiny step. The line search's filter is emptied when mu changes.

    Returns (State with ``am`` and the filter updated, mu to factor with (the previous mu in
    free mode), tau, number of barrier updates (0/1), free mode)."""
    o, it, ev, A = ctx.o, S.it, S.ev, adaptive_state(S)
    err = errors_at(ctx, P, it, ev, S.rs, S.terms, S.mu)
    theta = theta_of(P, ev.g, it.s)
    tiny = S.tiny_count > 0
    avg, n_c = avrg_compl(P, it)
    free = (sufficient_progress(o, A, ev.f, theta, err.E0) & ~tiny) | (n_c == 0)
    A_new = tree_where(free, remember(o, A, ev.f, theta), A)._replace(free=free)
    mu_min, mu_max = mu_range(o, P, A)
    mu_start = jnp.minimum(jnp.maximum(o.adaptive_mu_monotone_init_factor * avg, mu_min), mu_max)
    decrease = (err.Emu <= o.kappa_eps * S.mu) | tiny
    mu_dec = jnp.where(decrease, next_mu(o, S.mu, mu_floor(o, P)), S.mu)
    mu = jnp.where(free, S.mu, jnp.where(A.free, mu_start, mu_dec))
    reset = free | A.free | decrease
    S = lax.cond(reset, lambda s_: s_._replace(gl=filter_reset(o, s_.gl)), lambda s_: s_, S)
    # tau: max(tau_min, 1 - E_0) in free mode (tau_min without bounds), max(tau_min, 1 - mu) else
    tau_free = jnp.where(n_c == 0, o.tau_min, jnp.maximum(o.tau_min, 1.0 - err.E0))
    tau = jnp.where(free, tau_free, jnp.maximum(o.tau_min, 1.0 - mu))
    return S._replace(am=A_new), mu, tau, reset.astype(jnp.int32), free


def quality_function(P: Prob, it: Iterate, tau, aff: Direction, cen: Direction, avg, norms, sigma):
    """q(sigma) of the step d_aff + sigma d_cen for mu = sigma avrg (2-norm-squared variant).

    ``norms``: (||grad L||^2, ||c||^2 at the iterate, n_d, n_p, n_c)."""
    sq_dual, sq_primal, n_d, n_p, n_c = norms
    dx = aff.dx + sigma * cen.dx
    ds = aff.ds + sigma * cen.ds
    dzl, dzu, dvl, dvu = dual_steps(P, it, dx, ds, sigma * avg)
    a_pr = frac_to_boundary(P, it.x, it.s, dx, ds, tau)
    zs = ((it.zl, dzl, P.hxl), (it.zu, dzu, P.hxu), (it.vl, dvl, P.hsl), (it.vu, dvu, P.hsu))
    a_du = smallest(*(dual_ratios(z, dz, m_, tau) for z, dz, m_ in zs))
    dxl, dxu, dsl, dsu = slacks(P, it.x, it.s)
    new_slacks = (dxl + a_pr * dx, dxu - a_pr * dx, dsl + a_pr * ds, dsu - a_pr * ds)
    compl = sum(jnp.sum(jnp.where(m_, (sl * (z + a_du * dz)) ** 2, 0.0)) for sl, (z, dz, m_) in zip(new_slacks, zs))
    return (
        (1.0 - a_du) ** 2 * sq_dual / jnp.maximum(n_d, 1)
        + (1.0 - a_pr) ** 2 * sq_primal / jnp.maximum(n_p, 1)
        + compl / jnp.maximum(n_c, 1)
    )


def section_choice(q, lo_in, up_in, c, sigma_tol, qf_tol):
    """IPOPT's pick after the section search ``c`` = (lo, up, m1, m2, q_lo, q_up, q1, q2, n): the
    best of the four points when the q values have levelled off (qf_tol), else the better inner
    point, or the interval's end that never moved if it is better still (evaluated if unknown)."""
    lo, up, m1, m2, q_lo, q_up, q1, q2, _ = c
    qs = jnp.stack([q_lo, q1, q2, q_up])
    levelled = (up - lo >= sigma_tol * up) & (1.0 - jnp.min(qs) / jnp.max(qs) < qf_tol)
    best4 = jnp.stack([lo, m1, m2, up])[jnp.argmin(qs)]
    inner, q_inner = jnp.where(q1 < q2, m1, m2), jnp.minimum(q1, q2)
    at_up = up == up_in
    at_end = at_up | (lo == lo_in)
    end = jnp.where(at_up, up, lo)
    q_end = jnp.where(at_up, q_up, q_lo)
    q_end = jnp.where(q_end < 0.0, q(end), q_end)
    return jnp.where(levelled, best4, jnp.where(at_end & (q_end < q_inner), end, inner))


def golden_section(q, lo, up, q_lo, q_up, sigma_tol, qf_tol, max_steps: int):
    """Golden-section search for the minimiser of a unimodal ``q`` on [lo, up] (IPOPT's
    section search): ``q_lo``, ``q_up`` the end values (UNKNOWN if not evaluated); stops when
    up - lo < sigma_tol up, when the q values differ by less than the fraction qf_tol, or after
    ``max_steps`` sections. Each section evaluates q once. Returns sigma (a scalar)."""
    lo_in, up_in = lo, up
    m1, m2 = lo + GOLDEN * (up - lo), lo + (1.0 - GOLDEN) * (up - lo)

    def cond(c):
        lo_, up_, _, _, ql, qu, q1, q2, n = c
        qs = jnp.stack([ql, qu, q1, q2])
        return (up_ - lo_ >= sigma_tol * up_) & (1.0 - jnp.min(qs) / jnp.max(qs) >= qf_tol) & (n < max_steps)

    def body(c):
        lo_, up_, m1_, m2_, ql, qu, q1, q2, n = c
        right = q1 > q2  # the minimiser lies in [m1, up]
        lo_n, ql_n = jnp.where(right, m1_, lo_), jnp.where(right, q1, ql)
        up_n, qu_n = jnp.where(right, up_, m2_), jnp.where(right, qu, q2)
        keep, q_keep = jnp.where(right, m2_, m1_), jnp.where(right, q2, q1)
        new = lo_n + jnp.where(right, 1.0 - GOLDEN, GOLDEN) * (up_n - lo_n)
        q_new = q(new)
        m1_n, q1_n = jnp.where(right, keep, new), jnp.where(right, q_keep, q_new)
        m2_n, q2_n = jnp.where(right, new, keep), jnp.where(right, q_new, q_keep)
        return lo_n, up_n, m1_n, m2_n, ql_n, qu_n, q1_n, q2_n, n + 1

    floats = tuple(jnp.asarray(v, float) for v in (lo, up, m1, m2, q_lo, q_up, q(m1), q(m2)))
    c = lax.while_loop(cond, body, (*floats, jnp.zeros((), jnp.int32)))
    return section_choice(q, lo_in, up_in, c, sigma_tol, qf_tol)


def oracle_sigma(o: IPMOptions, q, avg, mu_min, mu_max):
    """The centering parameter of the quality-function oracle: the side of sigma = 1 on which q
    decreases (from q(1) and q(1 - max(1e-4, sigma_tol))), then the section search there, within
    [sigma_min, sigma_max] and [mu_min, mu_max] / avrg."""
    tol = o.quality_function_section_sigma_tol
    q1 = q(jnp.ones(()))
    s1m = 1.0 - jnp.maximum(1e-4, tol)
    q1m = q(s1m)
    up_side = q1m > q1
    lo_b = jnp.maximum(o.sigma_min, mu_min / avg)
    lo = jnp.where(up_side, 1.0, lo_b)
    up = jnp.where(up_side, jnp.minimum(o.sigma_max, mu_max / avg), jnp.minimum(jnp.maximum(lo_b, s1m), mu_max / avg))
    q_lo = jnp.where(up_side, q1, UNKNOWN)
    q_up = jnp.where(up_side, UNKNOWN, q1m)
    sigma = golden_section(
        q, lo, up, q_lo, q_up, tol, o.quality_function_section_qf_tol, o.quality_function_max_section_steps
    )
    return jnp.where(lo >= up, jnp.where(up_side, up, lo), sigma)


def oracle_norms(ctx: Context, P: Prob, S: State, c, n_c):
    """(||grad L||^2 over x and s, ||c||^2, n_d, n_p, n_c) of the quality function at S's iterate."""
    it, ev = S.it, S.ev
    gLx = jnp.where(P.fixed, 0.0, ev.grad + jt_mult(ctx, ev.jac, it.y) - it.zl + it.zu)
    gLs = jnp.where(P.hsl | P.hsu, -it.y - it.vl + it.vu, 0.0)
    n_d = jnp.sum(~P.fixed) + jnp.sum(~P.eq)
    return jnp.sum(gLx**2) + jnp.sum(gLs**2), jnp.sum(c**2), n_d, ctx.m, n_c


def oracle_direction(ctx: Context, P: Prob, S: State, ic: Inertia, tau):
    """Free mode's barrier parameter and step: the affine and centering steps (13) with the
    factorisation ``ic``, sigma by ``oracle_sigma``, mu = sigma avrg clipped to [mu_min, mu_max]
    (mu_min without bounds) and the step d_aff + (mu / avrg) d_cen. Returns (mu, Newton)."""
    it = S.it
    avg, n_c = avrg_compl(P, it)
    mu_min, mu_max = mu_range(ctx.o, P, adaptive_state(S))
    zm = jnp.zeros(ctx.m)
    _, _, _, _, rx0, rs0, _, _, c = residuals(ctx, P, S, 0.0)
    dx, ds, dy, dp, dn, ratio_a = solve_reduced(ctx, P, ic.A, ic.B, ic.fac, ic.invs, rx0, rs0, zm, zm, c)
    d_aff = Direction(dx=dx, ds=ds, dy=dy, dp=dp, dn=dn)
    gx_c, gs_c = barrier_grad(P, jnp.zeros(ctx.n), it.x, it.s, avg, ctx.o.kappa_d)
    rs_c = jnp.where(P.hsl | P.hsu, gs_c, 0.0)
    dx, ds, dy, dp, dn, ratio_c = solve_reduced(ctx, P, ic.A, ic.B, ic.fac, ic.invs, gx_c, rs_c, zm, zm, zm)
    d_cen = Direction(dx=dx, ds=ds, dy=dy, dp=dp, dn=dn)
    norms = oracle_norms(ctx, P, S, c, n_c)

    def q(sigma):
        return quality_function(P, it, tau, d_aff, d_cen, avg, norms, sigma)

    sigma = oracle_sigma(ctx.o, q, avg, mu_min, mu_max)
    mu = jnp.where(n_c == 0, mu_min, jnp.minimum(jnp.maximum(sigma * avg, mu_min), mu_max))
    sig = jnp.where(avg > 0, mu / jnp.where(avg > 0, avg, 1.0), 0.0)
    d = jax.tree.map(lambda a, b: a + sig * b, d_aff, d_cen)
    return mu, newton(ic, d, jnp.maximum(ratio_a, ratio_c), residuals(ctx, P, S, mu))
