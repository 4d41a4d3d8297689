"""Optimality errors (5), the convergence and acceptable-level tests, and the status decision.

IPOPT paper, Sec. 2.1: E_mu = max(||grad L||_inf / s_d, ||c||_inf, ||XZe - mu e||_inf / s_c) with
the multiplier scalings s_d = max(s_max, (||y||_1 + ||z||_1)/(m + n_z))/s_max and
s_c = max(s_max, ||z||_1/n_z)/s_max; E_0 decides convergence (E_0 <= tol, with IPOPT's unscaled
tests on the constraint violation, dual infeasibility and complementarity). In the restoration
phase the errors are those of the restoration problem. The status is the first that applies of
a priority list (``decide_status``), ``Status.Running`` when none does.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxhumanoid.solvers.ipm.barrier import mu_floor
from jaxhumanoid.solvers.ipm.problem import Context, constr_resid, jt_mult, slacks
from jaxhumanoid.solvers.ipm.restoration import objective_grad, resto_resid
from jaxhumanoid.solvers.ipm.state import HIST_FIELDS, Evals, Iterate, Prob, Resto, State, StepInfo, tree_where
from jaxhumanoid.solvers.ipm.step import flat, max_abs
from jaxhumanoid.solvers.status import Status


class Errors(NamedTuple):
    """Optimality errors (5) of the problem being solved (scalars)."""

    E0: jax.Array  # E_0 and E_mu (scaled problem)
    Emu: jax.Array
    dual: jax.Array  # dual infeasibility, constraint violation (of the restoration problem in
    primal: jax.Array  # its phase) and complementarity, scaled
    compl: jax.Array
    pr_s: jax.Array  # the original problem's constraint violation, scaled and unscaled
    pr_u: jax.Array
    du_u: jax.Array  # dual infeasibility and complementarity in the user's units
    co_u: jax.Array


class ErrorTerms(NamedTuple):
    """The parts of the optimality errors (5) at an iterate that do not depend on mu, from which
    ``errors_at`` gives the errors for any mu without the Jacobian product again: ``check``
    keeps them in the state for the next iteration's barrier update."""

    jt: jax.Array  # (n,) J^T y
    dual_s: jax.Array  # dual infeasibility of the slack (and p, n) rows
    primal: jax.Array  # constraint violation of the problem being solved
    sd: jax.Array  # the multiplier scalings s_d, s_c of (5)
    sc: jax.Array
    c_max: jax.Array  # largest and smallest complementarity product on a finite bound (-inf,
    c_min: jax.Array  # +inf without bounds): max_i |c_i - mu| = max(c_max - mu, mu - c_min)
    pr_s: jax.Array  # the original problem's constraint violation, scaled and unscaled
    pr_u: jax.Array


def error_terms(ctx: Context, P: Prob, it: Iterate, ev: Evals, R: Resto) -> ErrorTerms:
    """``ErrorTerms`` of the problem being solved (in the restoration phase, of the restoration
    problem) at ``it``."""
    o = ctx.o
    x, s, y = it.x, it.s, it.y
    rr = R.on & ~P.free
    rho = o.resto_penalty_parameter
    dxl, dxu, dsl, dsu = slacks(P, x, s)
    gLs = jnp.where(P.hsl | P.hsu, -y - it.vl + it.vu, 0.0)
    gLpn = jnp.where(rr, jnp.maximum(jnp.abs(rho - y - R.zp), jnp.abs(rho + y - R.zn)), 0.0)
    c_orig = constr_resid(P, ev.g, s)
    products = (
        (dxl * it.zl, P.hxl),
        (dxu * it.zu, P.hxu),
        (dsl * it.vl, P.hsl),
        (dsu * it.vu, P.hsu),
        (R.p * R.zp, rr),
        (R.n * R.zn, rr),
    )
    c_max = jnp.max(flat([jnp.where(m_, v, -jnp.inf) for v, m_ in products]), initial=-jnp.inf)
    c_min = jnp.min(flat([jnp.where(m_, v, jnp.inf) for v, m_ in products]), initial=jnp.inf)
    nz = (jnp.sum(flat([P.hxl, P.hxu, P.hsl, P.hsu])) + 2 * jnp.sum(rr)).astype(float)
    z1 = (
        jnp.sum(jnp.abs(it.zl))
        + jnp.sum(jnp.abs(it.zu))
        + jnp.sum(jnp.abs(it.vl))
        + jnp.sum(jnp.abs(it.vu))
        + jnp.sum(jnp.where(rr, R.zp + R.zn, 0.0))
    )
    return ErrorTerms(
        jt=jt_mult(ctx, ev.jac, y),
        dual_s=max_abs(gLs, gLpn),
        primal=jnp.max(jnp.abs(resto_resid(P, R, ev.g, s, R.p, R.n)), initial=0.0),
        sd=jnp.maximum(o.s_max, (jnp.sum(jnp.abs(y)) + z1) / jnp.maximum(1.0, ctx.m + nz)) / o.s_max,
        sc=jnp.maximum(o.s_max, z1 / jnp.maximum(1.0, nz)) / o.s_max,
        c_max=c_max,
        c_min=c_min,
        pr_s=jnp.max(jnp.abs(c_orig), initial=0.0),
        pr_u=jnp.max(jnp.abs(c_orig) / P.sg, initial=0.0),
    )


def empty_terms(n: int) -> ErrorTerms:
    """Placeholder ``ErrorTerms`` (the shapes of a state before its first ``check``)."""
    z = jnp.zeros(())
    return ErrorTerms(jt=jnp.zeros(n), dual_s=z, primal=z, sd=z, sc=z, c_max=z, c_min=z, pr_s=z, pr_u=z)


def complementarity(T: ErrorTerms, mu):
    """max(0, max_i |c_i - mu|) over the complementarity products c_i on finite bounds."""
    return jnp.maximum(0.0, jnp.maximum(T.c_max - mu, mu - T.c_min))


def errors_at(ctx: Context, P: Prob, it: Iterate, ev: Evals, R: Resto, T: ErrorTerms, mu) -> Errors:
    """Optimality errors (5) at ``it`` for barrier parameter ``mu`` from its ``ErrorTerms``: only
    the gradient of the restoration problem's proximity term and the complementarity depend on mu."""
    gf = objective_grad(ctx.o, R, ev.grad, it.x, mu)
    gLx = jnp.where(P.fixed, 0.0, gf + T.jt - it.zl + it.zu)
    dual = jnp.maximum(jnp.max(jnp.abs(gLx), initial=0.0), T.dual_s)
    c0 = complementarity(T, 0.0)
    return Errors(
        E0=jnp.maximum(jnp.maximum(dual / T.sd, T.primal), c0 / T.sc),
        Emu=jnp.maximum(jnp.maximum(dual / T.sd, T.primal), complementarity(T, mu) / T.sc),
        dual=dual,
        primal=T.primal,
        compl=c0,
        pr_s=T.pr_s,
        pr_u=T.pr_u,
        du_u=dual / P.sf,
        co_u=c0 / P.sf,
    )


def errors(ctx: Context, P: Prob, it: Iterate, ev: Evals, mu, R: Resto) -> Errors:
    """Optimality errors (5) of the problem being solved (in the restoration phase, of the
    restoration problem)."""
    return errors_at(ctx, P, it, ev, R, error_terms(ctx, P, it, ev, R), mu)


def first_applicable(rules, default):
    """The code of the first (condition, code) pair whose condition holds, else ``default``."""
    out = default
    for cond, code in reversed(rules):
        out = jnp.where(cond, code, out)
    return jnp.asarray(out).astype(jnp.int32)


def decide_status(
    prior,
    finite,
    converged,
    resto_converged,
    resto_code,
    acceptable_stop,
    tiny_stop,
    acceptable_point,
    out_of_iterations,
):
    """The loop's status after an iteration, in priority order: a status the iteration itself
    set (``prior``), non-finite evaluations, convergence, a converged restoration problem
    (``resto_code``), the acceptable level held long enough, a step too small at the smallest
    mu (at an acceptable point or not), the iteration limits; else Running."""
    return first_applicable(
        [
            (prior != Status.Running, prior),
            (~finite, Status.Invalid_Number_Detected),
            (converged, Status.Solve_Succeeded),
            (resto_converged, resto_code),
            (acceptable_stop, Status.Solved_To_Acceptable_Level),
            (
                tiny_stop,
                jnp.where(
                    acceptable_point, Status.Solved_To_Acceptable_Level, Status.Search_Direction_Becomes_Too_Small
                ),
            ),
            (out_of_iterations, Status.Maximum_Iterations_Exceeded),
        ],
        Status.Running,
    )


def step_status(stop_acceptable, resto_failed, ok_step):
    """The status one iteration sets itself: a failed line search at an acceptable point (or a
    rollback to one) stops at the acceptable level; a failed restoration phase ends it."""
    return first_applicable(
        [
            (stop_acceptable, Status.Solved_To_Acceptable_Level),
            (resto_failed & ok_step, Status.Restoration_Failed),
            (resto_failed, Status.Error_In_Step_Computation),
        ],
        Status.Running,
    )


def check(ctx: Context, P: Prob, S: State, info: StepInfo, status) -> State:
    """Termination tests of the new iterate, its history row and the acceptable-point memory."""
    o = ctx.o
    terms = error_terms(ctx, P, S.it, S.ev, S.rs)
    err = errors_at(ctx, P, S.it, S.ev, S.rs, terms, S.mu)
    k = S.k
    resto = S.rs.on
    conv = (
        (o.tol >= err.E0)
        & (err.pr_u <= o.constr_viol_tol)
        & (err.du_u <= o.dual_inf_tol)
        & (err.co_u <= o.compl_inf_tol)
    ) & ~resto
    acc_pt = (
        (o.acceptable_tol >= err.E0)
        & (err.pr_u <= o.acceptable_constr_viol_tol)
        & (err.du_u <= o.acceptable_dual_inf_tol)
        & (err.co_u <= o.acceptable_compl_inf_tol)
    )
    n_acc = jnp.where(acc_pt, S.n_acceptable + 1, 0).astype(jnp.int32)
    # the restoration problem itself converged (or stalled at an acceptable point) without
    # reaching a point the outer filter accepts: local infeasibility, unless it is feasible
    resto_conv = resto & ((o.tol >= err.E0) | ((n_acc >= o.acceptable_iter) & (o.acceptable_iter > 0)))
    resto_code = jnp.where(err.pr_s > 1e2 * o.tol, Status.Infeasible_Problem_Detected, Status.Restoration_Failed)
    finite = jnp.isfinite(S.ev.f) & jnp.all(jnp.isfinite(flat([S.ev.g, S.ev.grad, S.ev.jac])))
    tiny_stop = (S.tiny_count >= 2) & (S.mu <= mu_floor(o, P) * 1.0000001)
    new_status = decide_status(
        status,
        finite,
        conv,
        resto_conv,
        resto_code,
        (n_acc >= o.acceptable_iter) & (o.acceptable_iter > 0) & ~resto,
        tiny_stop,
        acc_pt,
        (k >= o.max_iter) | (S.resto_iters > o.max_resto_iter),
    )
    hist = S.hist
    if o.keep_history:
        row = dict(obj=S.ev.f / P.sf, inf_pr=err.pr_u, inf_du=err.dual, compl=err.compl, **info._asdict())
        hist = {key: hist[key].at[k].set(jnp.asarray(row[key]).astype(hist[key].dtype)) for key in HIST_FIELDS}
    keep = acc_pt & finite & ~resto
    return S._replace(
        done=new_status != Status.Running,
        status=new_status,
        terms=terms,
        n_acceptable=n_acc,
        hist=hist,
        cur_acc=keep,
        acc_it=tree_where(keep, S.it, S.acc_it),
        acc_ev=tree_where(keep, S.ev, S.acc_ev),
        has_acc=S.has_acc | keep,
    )
