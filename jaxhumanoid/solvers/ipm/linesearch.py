"""Step A-5 of the IPOPT paper's algorithm: the backtracking filter line search (Sec. 2.3-2.4).

From alpha_max of the fraction to the boundary (15), trial step sizes are halved until a trial
point is acceptable: to the filter (``filter``) and, when the switching condition (19)
grad phi^T d < 0 and alpha (-grad phi^T d)^s_phi > delta theta^s_theta holds at a small theta
(<= theta_min), by the Armijo condition (20) phi <= phi_k + eta_phi alpha grad phi^T d, otherwise
by the sufficient decrease (18) of theta or phi. Before backtracking, up to ``max_soc``
second-order corrections (Sec. 2.4) are tried when the first trial did not reduce theta; below
alpha_min (23) the line search fails (and the restoration phase starts). IPOPT's watchdog
judges tentative full steps against the point where it started (``state.Watchdog``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxhumanoid.solvers.ipm.direction import Newton, corrected_direction, directional_derivative
from jaxhumanoid.solvers.ipm.filter import filter_ok
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import Context, evaluate
from jaxhumanoid.solvers.ipm.restoration import merit, resto_resid
from jaxhumanoid.solvers.ipm.state import Direction, Globalization, Iterate, Prob, Resto, State, Watchdog, tree_where
from jaxhumanoid.solvers.ipm.step import boundary_ratios, dual_ratios, max_abs, smallest

EPS = float(np.finfo(np.float64).eps)


class Reference(NamedTuple):
    """The point trial points are judged against: the current iterate, or the watchdog's start."""

    theta: jax.Array
    phi: jax.Array
    gd: jax.Array  # directional derivative grad phi^T d


class Trial(NamedTuple):
    """A trial point's evaluations, slacks and merit (theta, phi); inf where not finite."""

    f: jax.Array
    g: jax.Array
    s: jax.Array
    theta: jax.Array
    phi: jax.Array


class SOC(NamedTuple):
    """Loop state of the second-order corrections."""

    p: jax.Array  # corrections done
    csoc: jax.Array  # (m,) accumulated constraint residual of the next correction
    theta_old: jax.Array
    active: jax.Array
    acc: jax.Array
    ftype: jax.Array
    a: jax.Array
    d: Direction
    f: jax.Array
    g: jax.Array
    s: jax.Array


class Backtrack(NamedTuple):
    """Loop state of the backtracking (alpha halved)."""

    a: jax.Array
    t: jax.Array  # trials made (the first trial at alpha_max included)
    acc: jax.Array
    ftype: jax.Array
    f: jax.Array
    g: jax.Array
    s: jax.Array
    fail: jax.Array


class LineSearch(NamedTuple):
    """Outcome of the line search of one iteration."""

    accepted: jax.Array
    a_pr: jax.Array  # primal step size taken
    amax: jax.Array  # alpha_max of (15)
    ftype: jax.Array  # f-type step (or one that leaves the filter alone)
    d: Direction  # the direction taken (corrected or not)
    f: jax.Array  # evaluations at the accepted trial
    g: jax.Array
    n_trials: jax.Array
    use_soc: jax.Array
    tiny: jax.Array  # the step is negligible (accepted without tests)
    theta_k: jax.Array  # merit and directional derivative at the current iterate
    phi_k: jax.Array
    gd: jax.Array
    ref: Reference
    wd: Watchdog  # the watchdog at the start of the iteration (after a barrier update)
    start_wd: jax.Array
    in_wd: jax.Array
    wd_tentative: jax.Array
    wd_reset: jax.Array


def alpha_min(o: IPMOptions, theta, theta_min, gd):
    """Smallest step size (23) before the line search gives up, times alpha_min_frac."""
    gd_neg = gd < 0
    mgd = jnp.where(gd_neg, -gd, 1.0)
    return o.alpha_min_frac * jnp.where(
        gd_neg,
        jnp.where(
            theta <= theta_min,
            jnp.minimum(
                o.gamma_theta, jnp.minimum(o.gamma_phi * theta / mgd, o.delta * theta**o.s_theta / mgd**o.s_phi)
            ),
            jnp.minimum(o.gamma_theta, o.gamma_phi * theta / mgd),
        ),
        o.gamma_theta,
    )


def switching(o: IPMOptions, ref: Reference, a):
    """Switching condition (19) at step size a."""
    gd_neg = ref.gd < 0
    mgd = jnp.where(gd_neg, -ref.gd, 1.0)
    return gd_neg & (a * mgd**o.s_phi > o.delta * ref.theta**o.s_theta)


def acceptable(o: IPMOptions, G: Globalization, ref: Reference, a, theta_t, phi_t):
    """(accepted, filter not augmented): the Armijo test (20) applies when theta_ref <= theta_min
    and the switching condition (19) holds, else the sufficient decrease (18); as in IPOPT's
    implementation, the filter is left alone whenever the switching condition and Armijo hold,
    whatever theta_ref."""
    sw = switching(o, ref, a)
    armijo = phi_t <= ref.phi + o.eta_phi * a * ref.gd
    suff = (theta_t <= (1 - o.gamma_theta) * ref.theta) | (phi_t <= ref.phi - o.gamma_phi * ref.theta)
    return filter_ok(G, theta_t, phi_t) & jnp.where((ref.theta <= G.theta_min) & sw, armijo, suff), sw & armijo


def trial_eval(ctx: Context, P: Prob, R: Resto, x, s, pv, nv, mu) -> Trial:
    """Evaluate a trial point (free rows' slacks follow g)."""
    f, g = evaluate(ctx, P, x)
    s = jnp.where(P.free, g, s)
    theta, phi = merit(ctx.o, P, R, f, g, x, s, pv, nv, mu)
    finite = jnp.isfinite(f) & jnp.all(jnp.isfinite(g)) & jnp.isfinite(phi)
    return Trial(f=f, g=g, s=s, theta=jnp.where(finite, theta, jnp.inf), phi=jnp.where(finite, phi, jnp.inf))


def trial_at(ctx: Context, P: Prob, it: Iterate, R: Resto, mu, a, d: Direction) -> Trial:
    """The trial point at step size a along d."""
    return trial_eval(ctx, P, R, it.x + a * d.dx, it.s + a * d.ds, R.p + a * d.dp, R.n + a * d.dn, mu)


def step_max(P: Prob, it: Iterate, R: Resto, rr, tau, d: Direction):
    """Fraction to the boundary (15) for x, s and, in the restoration phase, p, n."""
    pn = dual_ratios(R.p, d.dp, rr, tau), dual_ratios(R.n, d.dn, rr, tau)
    return smallest(*boundary_ratios(P, it.x, it.s, d.dx, d.ds, tau), *pn)


def tiny_step(it: Iterate, d: Direction, ok_step, resto):
    """The step is below 10 eps relative to the iterate (IPOPT's tiny step)."""
    rel = max_abs(d.dx / (1.0 + jnp.abs(it.x)), d.ds / (1.0 + jnp.abs(it.s)))
    return (rel < 10 * EPS) & ok_step & ~resto


def watchdog_start(o: IPMOptions, W: Watchdog, nupd, resto):
    """The watchdog after a barrier update (which ends it and its count) and whether it starts:
    after ``watchdog_shortened_iter_trigger`` shortened steps, outside the restoration phase."""
    W = W._replace(shortened=jnp.where(nupd > 0, 0, W.shortened), on=W.on & (nupd == 0))
    start = (
        (~W.on)
        & (~resto)
        & (W.shortened >= o.watchdog_shortened_iter_trigger)
        & (o.watchdog_shortened_iter_trigger > 0)
        & (~W.skip_first)
    )
    return W, start


FIRST, CORRECT, HALVE, DONE = 0, 1, 2, 3  # phases of the line search's loop


class Search(NamedTuple):
    """Loop state of the line search: the phase of the next trial (``FIRST`` at alpha_max,
    ``CORRECT`` a second-order correction, ``HALVE`` backtracking, ``DONE``), the first trial and
    its verdict, and the states of the corrections and of the backtracking."""

    phase: jax.Array
    first: Trial
    acc1: jax.Array
    ft1: jax.Array
    soc: SOC
    bt: Backtrack


class Criteria(NamedTuple):
    """What the line search of one iteration judges its trials by."""

    ref: Reference
    theta_k: jax.Array
    amax: jax.Array
    a_min: jax.Array
    tiny: jax.Array
    W: Watchdog
    in_wd: jax.Array


def _start(ctx: Context, S: State, nw: Newton) -> Search:
    """The loop's state before the first trial (every field but ``phase`` is overwritten)."""
    z, zi, zb = jnp.zeros(()), jnp.zeros((), jnp.int32), jnp.zeros((), bool)
    g, s = jnp.zeros(ctx.m), jnp.zeros(ctx.m)
    trial = Trial(f=z, g=g, s=s, theta=z, phi=z)
    return Search(
        phase=jnp.full((), FIRST, jnp.int32),
        first=trial,
        acc1=zb,
        ft1=zb,
        soc=SOC(p=zi, csoc=g, theta_old=z, active=zb, acc=zb, ftype=zb, a=z, d=nw.d, f=z, g=g, s=s),
        bt=Backtrack(a=z, t=zi, acc=zb, ftype=zb, f=z, g=g, s=s, fail=zb),
    )


def _leave_corrections(L: Search, nw: Newton, B: Criteria) -> Search:
    """After the corrections (or none): backtracking starts if no trial was accepted, unless
    alpha_max / 2 is already below alpha_min (a failed line search)."""
    start = (~L.acc1) & (~L.soc.acc) & nw.ok & ~B.in_wd
    fail = (0.5 * B.amax < B.a_min) & start
    phase = jnp.where(start & ~fail, HALVE, DONE).astype(jnp.int32)
    return L._replace(phase=phase, bt=L.bt._replace(fail=fail))


def _after_first(ctx: Context, P: Prob, S: State, nw: Newton, B: Criteria, L: Search, t: Trial) -> Search:
    """The first trial, at alpha_max: accepted, or corrections if it did not reduce theta."""
    o, R, d = ctx.o, S.rs, nw.d
    acc1, ft1 = acceptable(o, S.gl, B.ref, B.amax, t.theta, t.phi)
    acc1 = (acc1 | B.tiny) & ~B.W.skip_first
    correct = (~acc1) & (t.theta >= B.theta_k) & nw.ok & (o.max_soc > 0) & ~B.in_wd & ~B.W.skip_first
    csoc = B.amax * nw.c + resto_resid(P, R, t.g, t.s, R.p + B.amax * d.dp, R.n + B.amax * d.dn)
    zi, zb = jnp.zeros((), jnp.int32), jnp.zeros((), bool)
    soc = SOC(p=zi, csoc=csoc, theta_old=t.theta, active=correct, acc=zb, ftype=zb, a=B.amax, d=d, f=t.f, g=t.g, s=t.s)
    bt = Backtrack(a=0.5 * B.amax, t=jnp.ones((), jnp.int32), acc=zb, ftype=zb, f=t.f, g=t.g, s=t.s, fail=zb)
    L = Search(phase=L.phase, first=t, acc1=acc1, ft1=ft1, soc=soc, bt=bt)
    return tree_where(correct, L._replace(phase=jnp.full((), CORRECT, jnp.int32)), _leave_corrections(L, nw, B))


def _after_correction(
    ctx: Context, P: Prob, S: State, nw: Newton, B: Criteria, L: Search, t: Trial, a, d: Direction
) -> Search:
    """A second-order correction (Sec. 2.4), judged at alpha_max; the next one while none is
    accepted, fewer than ``max_soc`` were made and theta decreased by kappa_soc."""
    o, R, Q = ctx.o, S.rs, L.soc
    acc, ftype = acceptable(o, S.gl, B.ref, B.amax, t.theta, t.phi)
    p = Q.p + 1
    cont = (~acc) & (p < o.max_soc) & (t.theta <= o.kappa_soc * Q.theta_old)
    csoc = a * Q.csoc + resto_resid(P, R, t.g, t.s, R.p + a * d.dp, R.n + a * d.dn)
    L = L._replace(
        soc=SOC(p=p, csoc=csoc, theta_old=t.theta, active=cont, acc=acc, ftype=ftype, a=a, d=d, f=t.f, g=t.g, s=t.s)
    )
    return tree_where(cont, L, _leave_corrections(L, nw, B))


def _after_halving(ctx: Context, S: State, B: Criteria, L: Search, t: Trial) -> Search:
    """A backtracking trial: accepted, or alpha halved unless below alpha_min or out of trials."""
    o, T = ctx.o, L.bt
    acc, ftype = acceptable(o, S.gl, B.ref, T.a, t.theta, t.phi)
    a_next = 0.5 * T.a
    fail = (~acc) & ((a_next < B.a_min) | (T.t + 1 >= o.max_ls_trials))
    bt = Backtrack(a=jnp.where(acc, T.a, a_next), t=T.t + 1, acc=acc, ftype=ftype, f=t.f, g=t.g, s=t.s, fail=fail)
    return L._replace(phase=jnp.where(acc | fail, DONE, HALVE).astype(jnp.int32), bt=bt)


def search(ctx: Context, P: Prob, S: State, nw: Newton, mu, tau, B: Criteria) -> Search:
    """Every trial point of one line search in one loop: the first trial at alpha_max, the
    corrections, then alpha halved from alpha_max / 2. The loop evaluates (f, g) at one place,
    which keeps the traced program, and so its compile time, small."""
    it, R = S.it, S.rs
    rr = R.on & ~P.free

    def correction(L):
        d_s = corrected_direction(ctx, P, nw, L.soc.csoc)
        return step_max(P, it, R, rr, tau, d_s), d_s

    def along(L):
        return jnp.where(L.phase == FIRST, B.amax, L.bt.a), nw.d

    def body(L):
        a, d = lax.cond(L.phase == CORRECT, correction, along, L)
        t = trial_at(ctx, P, it, R, mu, a, d)
        return lax.switch(
            L.phase,
            (
                lambda L_: _after_first(ctx, P, S, nw, B, L_, t),
                lambda L_: _after_correction(ctx, P, S, nw, B, L_, t, a, d),
                lambda L_: _after_halving(ctx, S, B, L_, t),
            ),
            L,
        )

    return lax.while_loop(lambda L: L.phase != DONE, body, _start(ctx, S, nw))


def line_search(ctx: Context, P: Prob, S: State, nw: Newton, mu, tau, nupd) -> LineSearch:
    """The line search of S's iterate along the Newton step: the first trial at alpha_max,
    second-order corrections, backtracking, and the watchdog's tentative steps."""
    o = ctx.o
    it, ev, R = S.it, S.ev, S.rs
    resto = R.on
    rr = resto & ~P.free
    d, ok_step = nw.d, nw.ok
    theta_k, phi_k = merit(o, P, R, ev.f, ev.g, it.x, it.s, R.p, R.n, mu)
    gd = directional_derivative(nw)
    amax = step_max(P, it, R, rr, tau, d)
    a_min = alpha_min(o, theta_k, S.gl.theta_min, gd)

    # while the watchdog is on, trial points are judged against the point where it started
    W, start_wd = watchdog_start(o, S.wd, nupd, resto)
    in_wd = W.on | start_wd
    ref = Reference(jnp.where(W.on, W.theta, theta_k), jnp.where(W.on, W.phi, phi_k), jnp.where(W.on, W.gd, gd))
    tiny = tiny_step(it, d, ok_step, resto)
    B = Criteria(ref=ref, theta_k=theta_k, amax=amax, a_min=a_min, tiny=tiny, W=W, in_wd=in_wd)
    L = search(ctx, P, S, nw, mu, tau, B)
    first, acc1, ft1, soc, ls = L.first, L.acc1, L.ft1, L.soc, L.bt

    # watchdog outcome: an acceptable full step ends it; otherwise the full step is taken
    # tentatively, or, after watchdog_trial_iter_max of them, the iterate goes back
    wd_fail = in_wd & ok_step & ~acc1
    wd_reset = wd_fail & (W.trials + 1 > o.watchdog_trial_iter_max)
    wd_tentative = wd_fail & ~wd_reset

    use_soc = (~acc1) & soc.acc
    use_bt = (~acc1) & (~soc.acc) & ls.acc
    accepted = ok_step & (acc1 | soc.acc | ls.acc | wd_tentative)
    a_pr = jnp.where(acc1 | wd_tentative, amax, jnp.where(use_soc, soc.a, ls.a))
    ftype = jnp.where(acc1, ft1, jnp.where(use_soc, soc.ftype, ls.ftype)) | tiny | wd_tentative
    d_taken = tree_where(use_soc, soc.d, d)
    f_new = jnp.where(acc1, first.f, jnp.where(use_soc, soc.f, ls.f))
    g_new = jnp.where(acc1, first.g, jnp.where(use_soc, soc.g, ls.g))
    n_trials = 1 + soc.p + jnp.where(use_bt | (~accepted), ls.t - 1, 0)
    return LineSearch(
        accepted=accepted,
        a_pr=a_pr,
        amax=amax,
        ftype=ftype,
        d=d_taken,
        f=f_new,
        g=g_new,
        n_trials=n_trials,
        use_soc=use_soc,
        tiny=tiny,
        theta_k=theta_k,
        phi_k=phi_k,
        gd=gd,
        ref=ref,
        wd=W,
        start_wd=start_wd,
        in_wd=in_wd,
        wd_tentative=wd_tentative,
        wd_reset=wd_reset,
    )
