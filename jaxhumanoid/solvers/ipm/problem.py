"""The scaled NLP the interior-point method iterates on, and the context every part reads.

The user's problem min f(x) s.t. gl <= g(x) <= gu, xl <= x <= xu becomes (IPOPT paper, (1)-(2))

    min sf f(x)  s.t.  sg g(x) - s = 0,  sg gl <= s <= sg gu,  xl <= x <= xu

with gradient-based scaling factors sf, sg (Sec. 3.8), finite bounds relaxed by
``bound_relax_factor``, fixed variables (xl == xu) as parameters, equality rows without a slack
and rows without finite bounds ("free") ignored. Shapes: n variables, m constraints.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.state import Evals, Prob, Solution, State


class Context(NamedTuple):
    """What every part of the method reads and none changes: the NLP, the static structure of
    its KKT matrix, the options (float fields possibly traced) and the sparsity patterns."""

    nlp: Any
    st: kkt.KKTStructure
    o: IPMOptions
    jr: np.ndarray  # (nnz_jac,) Jacobian rows / columns
    jc: np.ndarray
    hr: np.ndarray  # (nnz_hess,) Hessian rows / columns (lower triangle)
    hc: np.ndarray
    cst: kkt.CondensedStructure | None = None  # the condensed KKT solve's structure, if chosen

    @property
    def n(self) -> int:
        return self.nlp.n

    @property
    def m(self) -> int:
        return self.nlp.m


def make_context(nlp, o: IPMOptions) -> Context:
    return Context(
        nlp=nlp,
        st=kkt.structure_of(nlp),
        o=o,
        jr=np.asarray(nlp.jac_rows, np.int64),
        jc=np.asarray(nlp.jac_cols, np.int64),
        hr=np.asarray(nlp.hess_rows, np.int64),
        hc=np.asarray(nlp.hess_cols, np.int64),
        cst=kkt.condensed_structure_of(nlp) if o.kkt_method == "condensed" else None,
    )


def segsum(vals, idx, size):
    """(size,) sums of ``vals`` grouped by ``idx``."""
    return jnp.zeros(size, dtype=vals.dtype).at[idx].add(vals)


def evaluate(ctx: Context, P: Prob, x):
    """Scaled objective () and constraints (m,) at x."""
    f = P.sf * ctx.nlp.f(x, P.p)
    g = P.sg * ctx.nlp.g(x, P.p)
    return f, g


def derivs(ctx: Context, P: Prob, x):
    """Scaled gradient (n,) and Jacobian values (nnz_jac,) at x."""
    grad = P.sf * ctx.nlp.grad(x, P.p)
    jac = P.sg[ctx.jr] * ctx.nlp.jac_values(x, P.p)
    return grad, jac


def scaled(ctx: Context, P: Prob, raw: Evals) -> Evals:
    """``raw`` (unscaled f, g, gradient and Jacobian values, ``raw_evals``) in the scaled problem's
    units, as ``evaluate`` and ``derivs`` give them."""
    return Evals(f=P.sf * raw.f, g=P.sg * raw.g, grad=P.sf * raw.grad, jac=P.sg[ctx.jr] * raw.jac)


def hessian(ctx: Context, P: Prob, x, y, resto):
    """Hessian of the Lagrangian (nnz_hess,); the restoration problem's objective has none in x
    besides the proximity term, which enters the diagonal (``restoration.prox_weight``)."""
    return ctx.nlp.hess_values(x, P.sg * y, jnp.where(resto, 0.0, P.sf), P.p)


def jt_mult(ctx: Context, jac, y):
    """J^T y (n,) from the Jacobian values."""
    return segsum(jac * y[ctx.jr], ctx.jc, ctx.n)


def slacks(P: Prob, x, s):
    """Distances to the finite bounds x - xl, xu - x, s - gl, gu - s (1 where no bound)."""
    dxl = jnp.where(P.hxl, x - P.xl, 1.0)
    dxu = jnp.where(P.hxu, P.xu - x, 1.0)
    dsl = jnp.where(P.hsl, s - P.gl, 1.0)
    dsu = jnp.where(P.hsu, P.gu - s, 1.0)
    return dxl, dxu, dsl, dsu


def constr_resid(P: Prob, g, s):
    """c(x, s) = g(x) - s on equality and bounded inequality rows (free rows: 0)."""
    c = jnp.where(P.eq, g - P.gl, g - s)
    return jnp.where(P.free, 0.0, c)


def theta_of(P: Prob, g, s):
    """Constraint violation ||c(x, s)||_1."""
    return jnp.sum(jnp.abs(constr_resid(P, g, s)))


def masks(ctx: Context, P: Prob):
    """Hessian and Jacobian entries that enter K (fixed variables and free rows drop out)."""
    return (
        jnp.where(P.fixed[ctx.hr] | P.fixed[ctx.hc], 0.0, 1.0),
        jnp.where(P.free[ctx.jr] | P.fixed[ctx.jc], 0.0, 1.0),
    )


def relax(b, mask, sign, factor):
    """IPOPT's bound relaxation: b + sign * factor * max(1, |b|) where ``mask``."""
    return jnp.where(mask, b + sign * factor * jnp.maximum(1.0, jnp.abs(b)), b)


def raw_evals(ctx: Context, xs, p) -> Evals:
    """Unscaled f, g, grad and Jacobian values at each row of xs (k, n), stacked: one traced
    evaluation for all rows (``lax.map``), so that the start adds no copy of the NLP's functions
    to the compiled program."""
    nlp = ctx.nlp
    f, g, grad, jac = lax.map(lambda x: (nlp.f(x, p), nlp.g(x, p), nlp.grad(x, p), nlp.jac_values(x, p)), xs)
    return Evals(f=f, g=g, grad=grad, jac=jac)


def scaling(ctx: Context, g0, j0, fixed):
    """Objective and constraint scaling factors sf (), sg (m,): gradient-based (Sec. 3.8) from
    the gradient g0 (n,) and Jacobian values j0 (nnz_jac,) at the starting point, max gradient
    entry scaled down to ``nlp_scaling_max_gradient``."""
    o, m = ctx.o, ctx.m
    if o.nlp_scaling_method == "gradient-based":
        gmax = jnp.max(jnp.abs(jnp.where(fixed, 0.0, g0)), initial=0.0)
        sf = jnp.maximum(
            o.nlp_scaling_min_value, jnp.minimum(1.0, o.nlp_scaling_max_gradient / jnp.maximum(gmax, 1e-300))
        )
        rmax = jnp.zeros(m).at[ctx.jr].max(jnp.abs(j0))
        sg = jnp.maximum(
            o.nlp_scaling_min_value, jnp.minimum(1.0, o.nlp_scaling_max_gradient / jnp.maximum(rmax, 1e-300))
        )
        sf = jnp.where(jnp.isfinite(sf), sf, 1.0) * o.obj_scaling_factor
        sg = jnp.where(jnp.isfinite(sg), sg, 1.0)
    else:
        sf = jnp.asarray(o.obj_scaling_factor, float)
        sg = jnp.ones(m)
    return sf, sg


class Prepared(NamedTuple):
    """The problem's bounds as the method sees them (``prepare``), before the scaling."""

    xl: jax.Array  # (n,) relaxed variable bounds
    xu: jax.Array
    gl: jax.Array  # (m,) relaxed constraint bounds (unscaled)
    gu: jax.Array
    hxl: jax.Array  # (n,) finite lower bound on x (not fixed)
    hxu: jax.Array
    fixed: jax.Array
    eq: jax.Array
    hsl: jax.Array
    hsu: jax.Array
    free: jax.Array
    x0: jax.Array  # the user's start with fixed variables at their value
    x: jax.Array  # the starting point: x0 pushed into the bounds (Sec. 3.6)


def prepare(ctx: Context, x0, xl, xu, gl, gu) -> Prepared:
    """The bounds' masks, finite bounds relaxed (``bound_relax_factor``) and the starting point:
    fixed variables at their value, pushed into the bounds (Sec. 3.6). Like IPOPT 3.14
    (honor_original_bounds = no) the final x is not projected back, which would break the
    stationarity of the returned multipliers."""
    o = ctx.o
    x0, xl, xu, gl, gu = (jnp.asarray(a, dtype=float) for a in (x0, xl, xu, gl, gu))
    fixed = xl == xu
    eq = gl == gu
    hxl = jnp.isfinite(xl) & ~fixed
    hxu = jnp.isfinite(xu) & ~fixed
    hsl = jnp.isfinite(gl) & ~eq
    hsu = jnp.isfinite(gu) & ~eq
    rf = o.bound_relax_factor
    xl, xu = relax(xl, hxl, -1.0, rf), relax(xu, hxu, 1.0, rf)
    gl, gu = relax(gl, hsl, -1.0, rf), relax(gu, hsu, 1.0, rf)
    free = ~eq & ~hsl & ~hsu
    x0 = jnp.where(fixed, xl, x0)
    x = push(x0, xl, xu, hxl, hxu, o.bound_push, o.bound_frac)
    return Prepared(
        xl=xl, xu=xu, gl=gl, gu=gu, hxl=hxl, hxu=hxu, fixed=fixed, eq=eq, hsl=hsl, hsu=hsu, free=free, x0=x0, x=x
    )


def scaled_prob(ctx: Context, B: Prepared, p, grad0, jac0) -> Prob:
    """The scaled problem's data, its scaling that of the gradient ``grad0`` and Jacobian values
    ``jac0`` at x0 before the push (Sec. 3.8)."""
    sf, sg = scaling(ctx, grad0, jac0, B.fixed)
    return Prob(
        p=p,
        xl=B.xl,
        xu=B.xu,
        gl=B.gl * sg,
        gu=B.gu * sg,
        hxl=B.hxl,
        hxu=B.hxu,
        fixed=B.fixed,
        eq=B.eq,
        hsl=B.hsl,
        hsu=B.hsu,
        free=B.free,
        sf=sf,
        sg=sg,
    )


def make_prob(ctx: Context, x0, xl, xu, gl, gu, p) -> tuple[Prob, jax.Array, Evals]:
    """The scaled problem's data, the starting point (``prepare``) and the unscaled evaluations
    there; the NLP's functions evaluated at x0 and x in one ``raw_evals``."""
    B = prepare(ctx, x0, xl, xu, gl, gu)
    ev = raw_evals(ctx, jnp.stack([B.x0, B.x]), p)
    return scaled_prob(ctx, B, p, ev.grad[0], ev.jac[0]), B.x, jax.tree.map(lambda a: a[1], ev)


def push(x, lo, hi, hlo, hhi, push_, frac):
    """Project x strictly inside [lo, hi] (Sec. 3.6, bound_push / bound_frac)."""
    width = jnp.where(hlo & hhi, hi - lo, jnp.inf)
    pl = jnp.minimum(push_ * jnp.maximum(1.0, jnp.abs(lo)), frac * width)
    pu = jnp.minimum(push_ * jnp.maximum(1.0, jnp.abs(hi)), frac * width)
    x = jnp.where(hlo, jnp.maximum(x, lo + pl), x)
    x = jnp.where(hhi, jnp.minimum(x, hi - pu), x)
    return x


def unscale(S: State, P: Prob):
    """(x, lam_g, z_l, z_u, f) in the user's units from a final state."""
    it = S.it
    lam = it.y * P.sg / P.sf
    return it.x, lam, it.zl / P.sf, it.zu / P.sf, S.ev.f / P.sf


def solution(ctx: Context, S: State, P: Prob) -> Solution:
    """The final state in the user's units (``unscale``) with the unscaled evaluations."""
    x, lam, zl, zu, f = unscale(S, P)
    return Solution(
        x=x,
        lam=lam,
        zl=zl,
        zu=zu,
        f=f,
        g=S.ev.g / P.sg,
        grad=S.ev.grad / P.sf,
        jac=S.ev.jac / P.sg[ctx.jr],
        status=S.status,
        k=S.k,
        hist=S.hist,
        resto_iters=S.resto_iters,
        fixed=P.fixed,
    )
