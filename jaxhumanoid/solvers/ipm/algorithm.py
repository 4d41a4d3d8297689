"""Primal-dual interior-point method with filter line search, after Waechter & Biegler (2006).

Equation numbers refer to the IPOPT paper (Math. Program. 106:25-57, 2006). Problem form:

    min f(x)  s.t.  g(x) - s = 0,  gl <= s <= gu,  xl <= x <= xu            (1), (2)

(scaled and relaxed as in ``problem``). The barrier problem (3) (``barrier``) is solved
approximately for a decreasing sequence of mu (monotone Fiacco-McCormick, (7)) by primal-dual
Newton steps (11)-(13) (``direction``, ``step``) with inertia correction (Algorithm IC,
``inertia``), fraction to the boundary (15), the safeguard (16), a backtracking filter line
search with second-order corrections and IPOPT's watchdog (``linesearch``, ``filter``) and
IPOPT's feasibility-restoration phase (``restoration``), whose iterations count as iterations,
as in IPOPT's log; ``termination`` holds the optimality errors (5) and the status decision.

One iteration here (``iteration``) is the algorithm's steps A-3 to A-8 (barrier update, search
direction, line search, acceptance of the trial point); ``run`` is the loop, one
``lax.while_loop``: a pure function of the context (NLP, KKT structure, options) and the
problem data that can be jitted and ``vmap``-ped over a batch (converged members freeze).
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
from jax import lax

from jaxhumanoid.solvers.ipm import barrier, mu_oracle
from jaxhumanoid.solvers.ipm.direction import Newton, kkt_factor, newton_step, search_direction
from jaxhumanoid.solvers.ipm.filter import filter_add, filter_reset
from jaxhumanoid.solvers.ipm.linesearch import LineSearch, line_search
from jaxhumanoid.solvers.ipm.options import IPMOptions, make_options
from jaxhumanoid.solvers.ipm.problem import Context, derivs, make_context, make_prob, push, scaled, solution, theta_of
from jaxhumanoid.solvers.ipm.restoration import (
    enter_restoration,
    leave_restoration,
    pn_dual_steps,
    pn_take_step,
    restoration_done,
)
from jaxhumanoid.solvers.ipm.state import (
    HIST_FIELDS,
    INT_FIELDS,
    Evals,
    Iterate,
    Prob,
    Solution,
    State,
    StepInfo,
    Watchdog,
    fresh_globalization,
    inactive_resto,
    tree_where,
)
from jaxhumanoid.solvers.ipm.step import dual_ratios, dual_steps, kappa_sigma_reset, ls_multipliers, max_abs, smallest
from jaxhumanoid.solvers.ipm.termination import check, empty_terms, errors_at, step_status
from jaxhumanoid.solvers.status import Status


def running():
    """The status code of a state no termination test has stopped."""
    return jnp.full((), Status.Running, jnp.int32)


def initial_state(ctx: Context, P: Prob, x, raw: Evals) -> State:
    """The state at the starting point x of ``make_prob`` (with its unscaled evaluations
    ``raw``): slacks pushed into their bounds (Sec. 3.6), least-squares multipliers, an empty
    filter with IPOPT's theta_min/theta_max, and empty history arrays."""
    o, n, m = ctx.o, ctx.n, ctx.m
    H = o.max_iter + 1
    ev = scaled(ctx, P, raw)
    g = ev.g
    s = push(g, P.gl, P.gu, P.hsl, P.hsu, o.slack_bound_push, o.slack_bound_frac)
    s = jnp.where(P.eq, P.gl, jnp.where(P.free, g, s))
    bm = o.bound_mult_init_val
    it = Iterate(
        x=x,
        s=s,
        y=jnp.zeros(m),
        zl=jnp.where(P.hxl, bm, 0.0),
        zu=jnp.where(P.hxu, bm, 0.0),
        vl=jnp.where(P.hsl, bm, 0.0),
        vu=jnp.where(P.hsu, bm, 0.0),
    )
    it = it._replace(y=ls_multipliers(ctx, P, it, ev))
    theta0 = theta_of(P, g, s)
    z0 = jnp.zeros(())
    hist = {
        key: jnp.zeros(H if o.keep_history else 1, dtype=jnp.int32 if key in INT_FIELDS else float)
        for key in HIST_FIELDS
    }
    return State(
        it=it,
        ev=ev,
        mu=jnp.asarray(o.mu_init, float),
        k=jnp.zeros((), jnp.int32),
        done=jnp.zeros((), bool),
        status=running(),
        gl=fresh_globalization(
            o.filter_size, o.theta_min_fact * jnp.maximum(1.0, theta0), o.theta_max_fact * jnp.maximum(1.0, theta0)
        ),
        n_acceptable=jnp.zeros((), jnp.int32),
        tiny_count=jnp.zeros((), jnp.int32),
        resto_iters=jnp.zeros((), jnp.int32),
        hist=hist,
        terms=empty_terms(n),
        rs=inactive_resto(n, m, o.filter_size),
        wd=Watchdog(
            shortened=jnp.zeros((), jnp.int32),
            on=z0 > 0,
            trials=jnp.zeros((), jnp.int32),
            it=it,
            ev=ev,
            theta=z0,
            phi=z0,
            gd=z0,
            skip_first=z0 > 0,
        ),
        cur_acc=jnp.zeros((), bool),
        acc_it=it,
        acc_ev=ev,
        has_acc=jnp.zeros((), bool),
        am=mu_oracle.fresh_adaptive(o, P, it) if o.mu_strategy == "adaptive" else None,
    )


def initial_info(S: State) -> StepInfo:
    """The history row of iteration 0."""
    zf, zi = jnp.zeros(()), jnp.zeros((), jnp.int32)
    return StepInfo(
        mu=S.mu,
        d_norm=zf,
        reg=zf,
        alpha_du=zf,
        alpha_pr=zf,
        ls=zi,
        kind=zi,
        resto_iters=zi,
        n_fact=zi,
        mode=zi,
        res_ratio=zf,
    )


def barrier_update(ctx: Context, P: Prob, S: State):
    """A-3: the barrier parameter update (7), possibly several times (and once after a tiny
    step); not in the first iteration of a restoration phase (IPOPT). A decrease empties the
    filter. Returns (S, mu, number of decreases)."""
    it, ev, R = S.it, S.ev, S.rs
    mu, nupd = barrier.update_mu(
        ctx.o,
        S.mu,
        barrier.mu_floor(ctx.o, P),
        lambda mu_: errors_at(ctx, P, it, ev, R, S.terms, mu_).Emu,
        (S.tiny_count > 0) & ~R.on,
        R.fresh,
    )
    S = lax.cond(nupd > 0, lambda s_: s_._replace(gl=filter_reset(ctx.o, s_.gl)), lambda s_: s_, S)
    return S, mu, nupd


def adaptive_barrier_and_direction(ctx: Context, P: Prob, S: State):
    """A-3 and A-4 with ``mu_strategy="adaptive"`` (``mu_oracle``): the mode decision (the
    monotone update (7) in the restoration phase), one factorisation, then in free mode the
    oracle's mu and step, else the Newton step for the fixed mode's mu.

    Returns (S, mu, tau, number of barrier updates, Newton)."""
    o = ctx.o

    def resto_rule(s_):
        s2, mu_, nupd_ = barrier_update(ctx, P, s_)
        return s2, mu_, jnp.maximum(o.tau_min, 1.0 - mu_), nupd_, jnp.zeros((), bool)

    S, mu, tau, nupd, free = lax.cond(S.rs.on, resto_rule, lambda s_: mu_oracle.adaptive_mode(ctx, P, s_), S)
    ic = kkt_factor(ctx, P, S, mu)
    mu, nw = lax.cond(
        free,
        lambda: mu_oracle.oracle_direction(ctx, P, S, ic, tau),
        lambda: (mu, newton_step(ctx, P, S, ic, mu)),
    )
    return S, mu, tau, nupd, nw


def barrier_and_direction(ctx: Context, P: Prob, S: State):
    """A-3 and A-4: the barrier update and the search direction for the new mu, with tau =
    max(tau_min, 1 - mu) of (15) (the adaptive update chooses its own).

    Returns (S, mu, tau, number of barrier updates, Newton)."""
    if ctx.o.mu_strategy == "adaptive":
        return adaptive_barrier_and_direction(ctx, P, S)
    S, mu, nupd = barrier_update(ctx, P, S)
    tau = jnp.maximum(ctx.o.tau_min, 1.0 - mu)
    nw: Newton = search_direction(ctx, P, S, mu)
    return S, mu, tau, nupd, nw


def take_step(ctx: Context, P: Prob, S: State, ls: LineSearch, mu, tau):
    """The trial point of the line search as the next iterate: primal step a_pr, bound
    multipliers by the dual steps (11) with their own fraction to the boundary and the
    safeguard (16), the filter augmented after an h-type step. Returns (State, alpha_du)."""
    o, it, R = ctx.o, S.it, S.rs
    rr = R.on & ~P.free
    D = ls.d
    a_pr = ls.a_pr
    dzl, dzu, dvl, dvu = dual_steps(P, it, D.dx, D.ds, mu)
    dzp, dzn = pn_dual_steps(R, rr, D.dp, D.dn, mu)
    a_du = smallest(
        dual_ratios(it.zl, dzl, P.hxl, tau),
        dual_ratios(it.zu, dzu, P.hxu, tau),
        dual_ratios(it.vl, dvl, P.hsl, tau),
        dual_ratios(it.vu, dvu, P.hsu, tau),
        dual_ratios(R.zp, dzp, rr, tau),
        dual_ratios(R.zn, dzn, rr, tau),
    )
    x_n = it.x + a_pr * D.dx
    s_n = it.s + a_pr * D.ds
    s_n = jnp.where(P.free, ls.g, jnp.where(P.eq, P.gl, s_n))
    y_n = it.y + a_pr * D.dy
    zl, zu, vl, vu = kappa_sigma_reset(
        o, P, x_n, s_n, it.zl + a_du * dzl, it.zu + a_du * dzu, it.vl + a_du * dvl, it.vu + a_du * dvu, mu
    )
    R_acc = pn_take_step(o, R, rr, a_pr, a_du, D.dp, D.dn, dzp, dzn, mu)
    S_acc = lax.cond(
        ls.ftype, lambda s_: s_, lambda s_: s_._replace(gl=filter_add(o, s_.gl, ls.ref.theta, ls.ref.phi)), S
    )
    it_n = Iterate(x=x_n, s=s_n, y=y_n, zl=zl, zu=zu, vl=vl, vu=vu)
    return S_acc._replace(it=it_n, rs=R_acc), a_du


def step_kind(ls: LineSearch, start_resto):
    """The letter after alpha_pr in IPOPT's log: R restoration starts, s tiny step, w/W watchdog
    tentative step / reset, F/H (f/h) f- or h-type step with (without) second-order correction."""
    return jnp.where(
        start_resto,
        ord("R"),
        jnp.where(
            ls.tiny,
            ord("s"),
            jnp.where(
                ls.wd_tentative,
                ord("w"),
                jnp.where(
                    ls.wd_reset,
                    ord("W"),
                    jnp.where(
                        ls.use_soc, jnp.where(ls.ftype, ord("F"), ord("H")), jnp.where(ls.ftype, ord("f"), ord("h"))
                    ),
                ),
            ),
        ),
    )


def next_watchdog(o: IPMOptions, S: State, ls: LineSearch, start_resto) -> Watchdog:
    """The watchdog after the step: the count of shortened steps, a tentative step continuing
    it, the reference point stored when it starts."""
    W, resto = ls.wd, S.rs.on
    shortened = ls.accepted & ~ls.in_wd & ~resto & (ls.a_pr < ls.amax)
    start_wd = ls.start_wd
    return Watchdog(
        shortened=jnp.where(shortened, W.shortened + 1, 0).astype(jnp.int32),
        on=ls.wd_tentative & ~start_resto,
        trials=jnp.where(ls.wd_tentative, W.trials + 1, 0).astype(jnp.int32),
        it=tree_where(start_wd, S.it, W.it),
        ev=tree_where(start_wd, S.ev, W.ev),
        theta=jnp.where(start_wd, ls.theta_k, W.theta),
        phi=jnp.where(start_wd, ls.phi_k, W.phi),
        gd=jnp.where(start_wd, ls.gd, W.gd),
        skip_first=ls.wd_reset,
    )


def transition(ctx: Context, P: Prob, S: State, S_acc: State, ls: LineSearch, mu):
    """A-7/A-8 and the phase changes: an accepted step changes the iterate, the restoration
    variables and the filter; a failed line search stops at an acceptable point ("Solved_To_
    Acceptable_Level", as IPOPT), else starts the restoration phase (A-5.5 / A-9), inside which it
    ends the phase; an accepted restoration step that passes the return test leaves it.

    Returns (State with the new iterate and evaluations, start_resto, resto_failed, rollback)."""
    resto = S.rs.on
    ls_failed = ~ls.accepted & ~ls.wd_reset  # includes a failed inertia correction (IC-6)
    stop_acceptable = ls_failed & S.cur_acc & ~resto
    start_resto = ls_failed & ~S.cur_acc & ~resto
    resto_failed = ls_failed & resto
    S_next = S._replace(**{f: tree_where(ls.accepted, getattr(S_acc, f), getattr(S, f)) for f in ("it", "rs", "gl")})

    def start(s_):
        # the outer filter takes the current iterate before it is stashed
        s_ = s_._replace(gl=filter_add(ctx.o, s_.gl, ls.theta_k, ls.phi_k))
        return enter_restoration(ctx, P, s_, mu, ls.theta_k, ls.phi_k)

    S_next = lax.cond(start_resto, start, lambda s_: s_._replace(mu=mu), S_next)
    back = ls.accepted & resto & restoration_done(ctx.o, P, S.rs, ls.f, ls.g, S_acc.it.x, S_acc.it.s)
    S_next = lax.cond(back, lambda s_: leave_restoration(ctx, P, s_), lambda s_: s_, S_next)
    f_next = jnp.where(ls.accepted, ls.f, S.ev.f)
    g_next = jnp.where(ls.accepted, ls.g, S.ev.g)
    grad_n, jac_n = derivs(ctx, P, S_next.it.x)
    ev_next = Evals(f=f_next, g=g_next, grad=grad_n, jac=jac_n)
    # a failed restoration falls back to the last acceptable iterate; a failed watchdog to the
    # point where it started
    rollback = resto_failed & S.has_acc
    it_next = tree_where(rollback, S.acc_it, S_next.it)
    ev_next = tree_where(rollback, S.acc_ev, ev_next)
    it_next = tree_where(ls.wd_reset, ls.wd.it, it_next)
    ev_next = tree_where(ls.wd_reset, ls.wd.ev, ev_next)
    return S_next._replace(it=it_next, ev=ev_next), start_resto, resto_failed, stop_acceptable | rollback


def iteration(ctx: Context, P: Prob, S: State):
    """One iteration of the algorithm (A-3 to A-8). Returns (State, status it sets, StepInfo)."""
    resto = S.rs.on
    S, mu, tau, nupd, nw = barrier_and_direction(ctx, P, S)
    ls = line_search(ctx, P, S, nw, mu, tau, nupd)
    S_acc, a_du = take_step(ctx, P, S, ls, mu, tau)
    S_next, start_resto, resto_failed, stop_acceptable = transition(ctx, P, S, S_acc, ls, mu)
    status = step_status(stop_acceptable, resto_failed, nw.ok)
    D = ls.d
    # ||d|| as IPOPT's log: the primal step (x, s and, in the restoration phase, p and n)
    d_norm = max_abs(D.dx, D.ds, D.dp, D.dn)
    resto_iters = S.resto_iters + resto.astype(jnp.int32)
    info = StepInfo(
        mu=mu,
        d_norm=d_norm,
        reg=nw.ic.dw,
        alpha_du=jnp.where(ls.accepted, a_du, 0.0),
        alpha_pr=jnp.where(ls.accepted, ls.a_pr, 0.0),
        ls=ls.n_trials,
        kind=step_kind(ls, start_resto),
        resto_iters=resto_iters,
        n_fact=nw.ic.n_fact,
        mode=resto.astype(jnp.int32),
        res_ratio=nw.res_ratio,
    )
    S_next = S_next._replace(
        tiny_count=jnp.where(ls.tiny, S.tiny_count + 1, 0).astype(jnp.int32),
        wd=next_watchdog(ctx.o, S, ls, start_resto),
        resto_iters=resto_iters,
        k=S.k + 1,
    )
    # the regularisation history belongs to the problem being solved (IPOPT's restoration
    # phase has its own); entering and leaving the restoration set it themselves
    upd = (~resto & ~start_resto) | (resto & S_next.rs.on)
    S_next = S_next._replace(
        gl=S_next.gl._replace(
            dw_last=jnp.where(upd, nw.ic.dw_last, S_next.gl.dw_last), pert=jnp.where(upd, nw.ic.pert, S_next.gl.pert)
        )
    )
    return S_next, status, info


def start(ctx: Context, x0, xl, xu, gl, gu, p) -> tuple[State, Prob]:
    """The scaled problem and the checked initial state (iteration 0) from the user's data."""
    P, x, raw = make_prob(ctx, x0, xl, xu, gl, gu, p)
    return start_at(ctx, P, x, raw)


def start_at(ctx: Context, P: Prob, x, raw: Evals) -> tuple[State, Prob]:
    """The checked initial state (iteration 0) at x of the scaled problem P, given the unscaled
    evaluations ``raw`` there."""
    S = initial_state(ctx, P, x, raw)
    return check(ctx, P, S, initial_info(S), running()), P


def advance(ctx: Context, P: Prob, S: State, k_stop=None) -> State:
    """Iterations from S until a termination test fires (or, with ``k_stop``, iteration k_stop)."""

    def body(S_):
        S2, status, info = iteration(ctx, P, S_)
        return check(ctx, P, S2, info, status)

    if k_stop is None:
        return lax.while_loop(lambda S_: ~S_.done, body, S)
    return lax.while_loop(lambda S_: ~S_.done & (S_.k < k_stop), body, S)


def run(ctx: Context, x0, xl, xu, gl, gu, p):
    """The whole solve from the user's data: scaled problem, initial state, the loop.
    Returns (final State, Prob) of the scaled problem (``problem.solution`` unscales)."""
    S, P = start(ctx, x0, xl, xu, gl, gu, p)
    return advance(ctx, P, S), P


def solve(nlp, options: IPMOptions, x0, xl, xu, gl, gu, p) -> Solution:
    """Pure solver core: ``options`` a pytree (float leaves may be traced)."""
    ctx = make_context(nlp, options)
    S, P = run(ctx, x0, xl, xu, gl, gu, p)
    return solution(ctx, S, P)


def make_ipm(nlp, options: IPMOptions | dict | None = None) -> Callable:
    """``run(x0, xl, xu, gl, gu, p, opts=None) -> Solution``, jit/vmap-able, for this NLP;
    ``opts`` (an IPMOptions, default ``options``) may carry traced float fields."""
    default = make_options(options)

    def run_(x0, xl, xu, gl, gu, p, opts: IPMOptions | None = None):
        return solve(nlp, default if opts is None else opts, x0, xl, xu, gl, gu, p)

    return run_
