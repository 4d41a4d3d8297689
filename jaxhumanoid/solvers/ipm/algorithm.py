"""Primal-dual interior-point method with filter line search, after Waechter & Biegler (2006).

Equation numbers refer to the IPOPT paper (Math. Program. 106:25-57, 2006). Problem form:

    min f(x)  s.t.  g(x) - s = 0,  gl <= s <= gu,  xl <= x <= xu            (1), (2)

Equality rows (gl == gu) carry no slack (s = gl fixed); inequality rows get a slack s_j with log
barriers on its finite bounds; rows with no finite bound are "free" and ignored (their s tracks
g, their multiplier stays 0); fixed variables (xl == xu) are parameters (IPOPT's
``fixed_variable_treatment = make_parameter``). The barrier problem (3),

    phi_mu(x, s) = f(x) - mu sum ln(x - xl) - mu sum ln(xu - x) - mu sum ln(s - gl) - mu sum ln(gu - s)
                   (+ kappa_d mu times the distance to the bound of one-sided variables, Sec. 3.7)

is solved approximately for a decreasing sequence of mu (monotone Fiacco-McCormick, (7)) by
primal-dual Newton steps (11)-(13), with inertia correction (Algorithm IC, Sec. 3.1), fraction to
the boundary (15), the safeguard (16) on the bound multipliers, a backtracking filter line search
(Sec. 2.3: switching condition (19), Armijo (20), sufficient decrease (18), filter), second-order
corrections (Sec. 2.4) and a feasibility-restoration phase (Sec. 3.3, simplified: a damped
Gauss-Newton method on 1/2 ||g(x) - s||^2 with log barriers keeping the bounds, see
``_restoration``). All of it runs under one ``lax.while_loop``: ``make_ipm`` returns a pure
function that can be jitted and ``vmap``-ped over a batch (converged members freeze).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.solvers.ipm.options import IPMOptions, TracedOptions, float_vector, make_options

# status codes -> IPOPT's return-status strings
RUNNING = 0
STATUS = {
    0: "Running",
    1: "Solve_Succeeded",
    2: "Solved_To_Acceptable_Level",
    3: "Maximum_Iterations_Exceeded",
    4: "Infeasible_Problem_Detected",
    5: "Restoration_Failed",
    6: "Error_In_Step_Computation",
    7: "Invalid_Number_Detected",
    8: "Search_Direction_Becomes_Too_Small",
}
SUCCESS_CODES = (1, 2)
KAPPA_D = 1e-4          # linear damping of one-sided bounds (Sec. 3.7)
EPS = float(np.finfo(np.float64).eps)


class Prob(NamedTuple):
    """Per-instance numeric data of the scaled problem (everything a batch may vary)."""
    p: Any
    xl: jax.Array
    xu: jax.Array
    gl: jax.Array
    gu: jax.Array
    hxl: jax.Array      # finite lower bound on x (not fixed)
    hxu: jax.Array
    fixed: jax.Array    # xl == xu
    eq: jax.Array       # gl == gu
    hsl: jax.Array      # inequality row with finite lower bound
    hsu: jax.Array
    free: jax.Array     # inequality row without finite bounds
    sf: jax.Array       # objective scaling
    sg: jax.Array       # constraint scaling (m,)


class Iterate(NamedTuple):
    x: jax.Array
    s: jax.Array
    y: jax.Array
    zl: jax.Array
    zu: jax.Array
    vl: jax.Array
    vu: jax.Array


class Evals(NamedTuple):
    f: jax.Array        # scaled objective
    g: jax.Array        # scaled constraints
    grad: jax.Array     # scaled gradient
    jac: jax.Array      # scaled Jacobian values


class State(NamedTuple):
    it: Iterate
    ev: Evals
    mu: jax.Array
    k: jax.Array
    done: jax.Array
    status: jax.Array
    filt_theta: jax.Array
    filt_phi: jax.Array
    filt_n: jax.Array
    theta_min: jax.Array
    theta_max: jax.Array
    dw_last: jax.Array
    n_perturbed: jax.Array
    n_dc: jax.Array
    n_acceptable: jax.Array
    tiny_count: jax.Array
    cur_acc: jax.Array      # the current iterate passes the acceptable-level tests
    acc_it: Iterate         # the last acceptable iterate (IPOPT's fallback when the line search
    acc_ev: Evals           # and restoration fail, Sec. 3.3) and its evaluations
    has_acc: jax.Array
    resto_iters: jax.Array
    hist: dict


HIST_FIELDS = ("obj", "inf_pr", "inf_du", "mu", "d_norm", "reg", "alpha_du", "alpha_pr", "ls",
               "kind", "compl", "resto_iters", "n_fact")
INT_FIELDS = ("ls", "kind", "resto_iters", "n_fact")


def _segsum(vals, idx, size):
    return jnp.zeros(size, dtype=vals.dtype).at[idx].add(vals)


def make_ipm(nlp, options: IPMOptions | dict | None = None):
    """Pure, jit/vmap-able solver core ``run(x0, xl, xu, gl, gu, p, fopts=None) -> (State, Prob)``.

    The returned state holds the final iterate (scaled: use ``unscale`` for user units), the
    status code (``STATUS``) and the fixed-size history arrays (row k = iteration k). ``fopts``
    (``options.float_vector``) overrides every float option at run time, so tolerances, mu_init
    etc. can change without recompiling; integer/boolean/string options are static.
    """
    o_static = make_options(options)
    o = o_static
    st = kkt.structure_of(nlp)
    n, m = nlp.n, nlp.m
    jr = np.asarray(nlp.jac_rows, np.int64)
    jc = np.asarray(nlp.jac_cols, np.int64)
    hr = np.asarray(nlp.hess_rows, np.int64)
    hc = np.asarray(nlp.hess_cols, np.int64)
    H = o.max_iter + 1

    # ---------------------------------------------------------------- evaluation (scaled NLP)
    def evaluate(P, x):
        f = P.sf * nlp.f(x, P.p)
        g = P.sg * nlp.g(x, P.p)
        return f, g

    def derivs(P, x):
        grad = P.sf * nlp.grad(x, P.p)
        jac = P.sg[jr] * nlp.jac_values(x, P.p)
        return grad, jac

    def hessian(P, x, y):
        return nlp.hess_values(x, P.sg * y, P.sf, P.p)

    def jt_mult(jac, y):
        return _segsum(jac * y[jr], jc, n)

    def j_mult(jac, dx):
        return _segsum(jac * dx[jc], jr, m)

    def refinement():
        return o.min_refinement_steps, o.max_refinement_steps, o.residual_ratio_max

    # ---------------------------------------------------------------- barrier pieces
    def slacks(P, x, s):
        dxl = jnp.where(P.hxl, x - P.xl, 1.0)
        dxu = jnp.where(P.hxu, P.xu - x, 1.0)
        dsl = jnp.where(P.hsl, s - P.gl, 1.0)
        dsu = jnp.where(P.hsu, P.gu - s, 1.0)
        return dxl, dxu, dsl, dsu

    def barrier_phi(P, f, x, s, mu):
        """phi_mu of (3) plus the one-sided linear damping (Sec. 3.7)."""
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        logs = (jnp.sum(jnp.where(P.hxl, jnp.log(dxl), 0.0)) + jnp.sum(jnp.where(P.hxu, jnp.log(dxu), 0.0))
                + jnp.sum(jnp.where(P.hsl, jnp.log(dsl), 0.0)) + jnp.sum(jnp.where(P.hsu, jnp.log(dsu), 0.0)))
        damp = (jnp.sum(jnp.where(P.hxl & ~P.hxu, dxl, 0.0)) + jnp.sum(jnp.where(P.hxu & ~P.hxl, dxu, 0.0))
                + jnp.sum(jnp.where(P.hsl & ~P.hsu, dsl, 0.0)) + jnp.sum(jnp.where(P.hsu & ~P.hsl, dsu, 0.0)))
        return f - mu * logs + KAPPA_D * mu * damp

    def barrier_grad(P, grad, x, s, mu):
        """(grad_x phi_mu, grad_s phi_mu)."""
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        kd = KAPPA_D * mu
        gx = (grad - jnp.where(P.hxl, mu / dxl, 0.0) + jnp.where(P.hxu, mu / dxu, 0.0)
              + jnp.where(P.hxl & ~P.hxu, kd, 0.0) - jnp.where(P.hxu & ~P.hxl, kd, 0.0))
        gs = (-jnp.where(P.hsl, mu / dsl, 0.0) + jnp.where(P.hsu, mu / dsu, 0.0)
              + jnp.where(P.hsl & ~P.hsu, kd, 0.0) - jnp.where(P.hsu & ~P.hsl, kd, 0.0))
        return jnp.where(P.fixed, 0.0, gx), jnp.where(P.hsl | P.hsu, gs, 0.0)

    def constr_resid(P, g, s):
        """c(x, s) = g(x) - s on equality and bounded inequality rows (free rows: 0)."""
        c = jnp.where(P.eq, g - P.gl, g - s)
        return jnp.where(P.free, 0.0, c)

    def theta_of(P, g, s):
        return jnp.sum(jnp.abs(constr_resid(P, g, s)))

    # ---------------------------------------------------------------- optimality error (5)
    def errors(P, it, ev, mu):
        x, s, y = it.x, it.s, it.y
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        gLx = jnp.where(P.fixed, 0.0, ev.grad + jt_mult(ev.jac, y) - it.zl + it.zu)
        gLs = jnp.where(P.hsl | P.hsu, -y - it.vl + it.vu, 0.0)
        dual = jnp.maximum(jnp.max(jnp.abs(gLx), initial=0.0), jnp.max(jnp.abs(gLs), initial=0.0))
        c = constr_resid(P, ev.g, s)
        primal = jnp.max(jnp.abs(c), initial=0.0)

        def compl(m_):
            return jnp.maximum(
                jnp.maximum(jnp.max(jnp.where(P.hxl, jnp.abs(dxl * it.zl - m_), 0.0), initial=0.0),
                            jnp.max(jnp.where(P.hxu, jnp.abs(dxu * it.zu - m_), 0.0), initial=0.0)),
                jnp.maximum(jnp.max(jnp.where(P.hsl, jnp.abs(dsl * it.vl - m_), 0.0), initial=0.0),
                            jnp.max(jnp.where(P.hsu, jnp.abs(dsu * it.vu - m_), 0.0), initial=0.0)))

        nz = (jnp.sum(P.hxl) + jnp.sum(P.hxu) + jnp.sum(P.hsl) + jnp.sum(P.hsu)).astype(float)
        z1 = jnp.sum(jnp.abs(it.zl)) + jnp.sum(jnp.abs(it.zu)) + jnp.sum(jnp.abs(it.vl)) + jnp.sum(jnp.abs(it.vu))
        sd = jnp.maximum(o.s_max, (jnp.sum(jnp.abs(y)) + z1) / jnp.maximum(1.0, m + nz)) / o.s_max
        sc = jnp.maximum(o.s_max, z1 / jnp.maximum(1.0, nz)) / o.s_max
        c0 = compl(0.0)
        E0 = jnp.maximum(jnp.maximum(dual / sd, primal), c0 / sc)
        Emu = jnp.maximum(jnp.maximum(dual / sd, primal), compl(mu) / sc)
        # unscaled quantities for IPOPT's absolute tests
        pr_unscaled = jnp.max(jnp.abs(c) / P.sg, initial=0.0)
        du_unscaled = dual / P.sf
        co_unscaled = c0 / P.sf
        return dict(E0=E0, Emu=Emu, dual=dual, primal=primal, compl=c0, pr_u=pr_unscaled,
                    du_u=du_unscaled, co_u=co_unscaled, sd=sd, sc=sc)

    def emu_only(P, it, ev, mu):
        return errors(P, it, ev, mu)["Emu"]

    # ---------------------------------------------------------------- Newton step (13)
    def kkt_parts(P, it, Wvals, sig_x, sig_s, dw, dc):
        """Blocks of the reduced system (slack step eliminated) for given regularisation."""
        jac_mask = jnp.where(P.free[jr] | P.fixed[jc], 0.0, 1.0)
        h_mask = jnp.where(P.fixed[hr] | P.fixed[hc], 0.0, 1.0)
        ineq_b = P.hsl | P.hsu
        inv_s = jnp.where(ineq_b, 1.0 / (sig_s + dw), 0.0)
        diag_x = jnp.where(P.fixed, 1.0, sig_x + dw)
        diag_c = jnp.where(P.free, -1.0, -(dc + inv_s))
        return h_mask, jac_mask, inv_s, diag_x, diag_c

    def factorize(P, Wvals, jac, sig_x, sig_s, dw, dc, fast=True, base=None):
        """Assemble and factor; ``fast=False`` (eigh blocks only) keeps the rarely used call
        sites (restoration, multiplier initialisation) small for the compiler. ``base``: blocks
        assembled once with a zero diagonal, to which only the diagonal is added (IC trials)."""
        h_mask, jac_mask, inv_s, diag_x, diag_c = kkt_parts(P, None, Wvals, sig_x, sig_s, dw, dc)
        if base is None:
            A, B = kkt.assemble(st, Wvals * h_mask, jac * jac_mask, diag_x, diag_c)
        else:
            A, B = kkt.add_diagonal(st, base[0], diag_x, diag_c), base[1]
        fac = kkt.factor(st, A, B, fast=fast)
        return A, B, fac, inv_s

    def assemble_base(P, Wvals, jac):
        h_mask, jac_mask, _, _, _ = kkt_parts(P, None, Wvals, jnp.zeros(n), jnp.zeros(m), 0.0, 0.0)
        return kkt.assemble(st, Wvals * h_mask, jac * jac_mask, jnp.zeros(n), jnp.zeros(m))

    def solve_reduced(P, A, B, fac, inv_s, rx, rs, c):
        """Solve (13) given residuals r_x (grad_x phi + J^T y), r_s (grad_s phi - y), c."""
        bx = jnp.where(P.fixed, 0.0, -rx)
        bc = jnp.where(P.free, 0.0, -c - inv_s * rs)
        dx, dy = kkt.solve(st, fac, A, B, bx, bc, *refinement())
        ds = inv_s * (dy - rs)
        return dx, ds, dy

    def dual_steps(P, it, dx, ds, mu):
        """Bound-multiplier steps from the linearised complementarity (11)."""
        dxl, dxu, dsl, dsu = slacks(P, it.x, it.s)
        dzl = jnp.where(P.hxl, (mu - it.zl * dxl - it.zl * dx) / dxl, 0.0)
        dzu = jnp.where(P.hxu, (mu - it.zu * dxu + it.zu * dx) / dxu, 0.0)
        dvl = jnp.where(P.hsl, (mu - it.vl * dsl - it.vl * ds) / dsl, 0.0)
        dvu = jnp.where(P.hsu, (mu - it.vu * dsu + it.vu * ds) / dsu, 0.0)
        return dzl, dzu, dvl, dvu

    def sigmas(P, it):
        dxl, dxu, dsl, dsu = slacks(P, it.x, it.s)
        sig_x = jnp.where(P.hxl, it.zl / dxl, 0.0) + jnp.where(P.hxu, it.zu / dxu, 0.0)
        sig_s = jnp.where(P.hsl, it.vl / dsl, 0.0) + jnp.where(P.hsu, it.vu / dsu, 0.0)
        return sig_x, sig_s

    def frac_to_boundary(P, x, s, dx, ds, tau):
        """Largest alpha in (0, 1] keeping x, s strictly inside their bounds, (15)."""
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        a = jnp.ones(())
        a = jnp.minimum(a, jnp.min(jnp.where(P.hxl & (dx < 0), -tau * dxl / jnp.where(dx < 0, dx, -1.0), 1.0), initial=1.0))
        a = jnp.minimum(a, jnp.min(jnp.where(P.hxu & (dx > 0), tau * dxu / jnp.where(dx > 0, dx, 1.0), 1.0), initial=1.0))
        a = jnp.minimum(a, jnp.min(jnp.where(P.hsl & (ds < 0), -tau * dsl / jnp.where(ds < 0, ds, -1.0), 1.0), initial=1.0))
        a = jnp.minimum(a, jnp.min(jnp.where(P.hsu & (ds > 0), tau * dsu / jnp.where(ds > 0, ds, 1.0), 1.0), initial=1.0))
        return a

    def frac_dual(z, dz, mask, tau):
        return jnp.min(jnp.where(mask & (dz < 0), -tau * z / jnp.where(dz < 0, dz, -1.0), 1.0), initial=1.0)

    def kappa_sigma_reset(P, x, s, zl, zu, vl, vu, mu):
        """Safeguard (16): keep z_i (x_i - xl_i) within [mu/kappa_sigma, kappa_sigma mu]."""
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        ks = o.kappa_sigma

        def clip(z, d, mask):
            return jnp.where(mask, jnp.clip(z, mu / (ks * d), ks * mu / d), 0.0)

        return clip(zl, dxl, P.hxl), clip(zu, dxu, P.hxu), clip(vl, dsl, P.hsl), clip(vu, dsu, P.hsu)

    # ---------------------------------------------------------------- inertia correction (IC)
    def inertia_corrected_factor(P, Wvals, jac, sig_x, sig_s, dw_last, mu, skip_zero, jac_degen):
        """Algorithm IC (Sec. 3.1): smallest delta_w (and delta_c if K is singular) giving inertia
        (n, m, 0); a single traced factorisation inside one while_loop. The first pass has no
        shift, unless ``skip_zero`` (IPOPT's degenerate-Hessian heuristic: after
        ``degen_iters_max`` consecutive perturbed iterations, start from kappa_w^- delta_w_last;
        likewise delta_c > 0 from the start once K was singular that many iterations in a row)."""
        dw1 = jnp.where(dw_last == 0.0, o.first_hessian_perturbation,
                        jnp.maximum(o.min_hessian_perturbation, o.perturb_dec_fact * dw_last))
        inc = jnp.where(dw_last == 0.0, o.perturb_inc_fact_first, o.perturb_inc_fact)
        S_, nb = st.S, st.nb
        base = assemble_base(P, Wvals, jac)
        z3 = jnp.zeros((S_, nb, nb))
        fac0 = kkt.Factor(z3, jnp.zeros((S_, st.b_rows.size, nb)), jnp.zeros((), jnp.int64), jnp.zeros((), jnp.int64), jnp.zeros((), jnp.int64),
                          jnp.ones((S_, nb)))
        zero = jnp.zeros(())

        def cond(c):
            ok, dw, dc, t = c[:4]
            return (~ok) & (dw <= o.max_hessian_perturbation) & (t < o.max_inertia_trials)

        def body(c):
            _, dw, dc, t = c[:4]
            A_, B_, fac_, inv_s_ = factorize(P, Wvals, jac, sig_x, sig_s, dw, dc, base=base)
            fac_ = fac_._replace(npos=fac_.npos.astype(jnp.int64), nneg=fac_.nneg.astype(jnp.int64),
                                 nzero=fac_.nzero.astype(jnp.int64))
            ok = kkt.inertia_ok(st, fac_)
            first = (t == 0) & ~skip_zero
            new_dc = (dc == 0.0) & (fac_.nzero > 0)
            dc_n = jnp.where(new_dc, o.jacobian_regularization_value * mu ** o.jacobian_regularization_exponent, dc)
            # a singular K first gets delta_c > 0 at the same delta_w (IC-3); otherwise IC-4 / IC-6
            dw_n = jnp.where(ok, dw, jnp.where(first, dw1, jnp.where(new_dc & (dw > 0), dw, inc * dw)))
            dc_n = jnp.where(ok, dc, dc_n)
            return ok, dw_n, dc_n, t + 1, A_, B_, fac_, inv_s_

        ok, dw, dc, trials, A, B, fac, inv_s = lax.while_loop(
            cond, body, (jnp.zeros((), bool), jnp.where(skip_zero, dw1, 0.0),
                         jnp.where(jac_degen, o.jacobian_regularization_value * mu ** o.jacobian_regularization_exponent, 0.0),
                         jnp.zeros((), jnp.int32),
                         z3, z3, fac0, jnp.zeros(m)))
        new_dw_last = jnp.where(ok & (dw > 0), dw, dw_last)
        return A, B, fac, inv_s, ok, dw, dc, new_dw_last, trials

    # ---------------------------------------------------------------- least-squares multipliers
    def ls_multipliers(P, it, ev):
        """y minimising ||grad f + J^T y - z||^2 + ||-y - v||^2 (Sec. 3.6), or 0 if too large."""
        ineq_b = P.hsl | P.hsu
        jac_mask = jnp.where(P.free[jr] | P.fixed[jc], 0.0, 1.0)
        diag_c = jnp.where(P.free, -1.0, jnp.where(ineq_b, -1.0, 0.0))
        A, B = kkt.assemble(st, jnp.zeros(hr.size), ev.jac * jac_mask, jnp.ones(n), diag_c)
        fac = kkt.factor(st, A, B, fast=False)
        a = jnp.where(P.fixed, 0.0, ev.grad - it.zl + it.zu)
        b = jnp.where(ineq_b, -it.vl + it.vu, 0.0)
        _, y = kkt.solve(st, fac, A, B, -a, -b, *refinement())
        good = kkt.inertia_ok(st, fac) & jnp.all(jnp.isfinite(y)) & (jnp.max(jnp.abs(y), initial=0.0) <= o.constr_mult_init_max)
        return jnp.where(good & ~P.free, y, 0.0)

    # ---------------------------------------------------------------- filter helpers
    def filter_ok(S, theta, phi):
        blocked = (theta >= S.filt_theta) & (phi >= S.filt_phi)
        return (theta <= S.theta_max) & ~jnp.any(blocked)

    def filter_add(S, theta, phi):
        i = S.filt_n % o.filter_size
        return S._replace(filt_theta=S.filt_theta.at[i].set((1 - o.gamma_theta) * theta),
                          filt_phi=S.filt_phi.at[i].set(phi - o.gamma_phi * theta),
                          filt_n=S.filt_n + 1)

    def filter_reset(S):
        return S._replace(filt_theta=jnp.full(o.filter_size, jnp.inf),
                          filt_phi=jnp.full(o.filter_size, jnp.inf), filt_n=jnp.zeros((), jnp.int32))

    def trial_eval(P, x, s, mu):
        f, g = evaluate(P, x)
        s = jnp.where(P.free, g, s)
        theta = theta_of(P, g, s)
        phi = barrier_phi(P, f, x, s, mu)
        finite = jnp.isfinite(f) & jnp.all(jnp.isfinite(g)) & jnp.isfinite(phi)
        return f, g, s, jnp.where(finite, theta, jnp.inf), jnp.where(finite, phi, jnp.inf)

    # ---------------------------------------------------------------- restoration phase
    def _restoration(P, S, mu, active):
        """Simplified feasibility restoration (replaces Sec. 3.3's restoration NLP).

        Damped Gauss-Newton (Levenberg-Marquardt) steps on psi = 1/2 ||c(x, s)||_2^2 + mu_R B(x, s)
        with B the log barriers of the bounds, fraction to the boundary, and an Armijo
        backtracking on psi. The reduced system has the same block structure as (13) with
        W = 0, delta_w = zeta (damping), delta_c = 1, so it is quasi-definite. Returns when
        theta <= kappa_resto theta_k and the point is acceptable to the filter (success), when
        theta stalls at a non-zero value (local infeasibility) or after max_resto_iter.
        """
        it0 = S.it
        theta0 = theta_of(P, S.ev.g, it0.s)
        # barrier weight starts at max(mu, 0.1 min(1, ||c||_inf)) and is reduced by 5 per iteration
        th_inf0 = jnp.max(jnp.abs(constr_resid(P, S.ev.g, it0.s)), initial=0.0)
        mu_r0 = jnp.maximum(mu, 1e-1 * jnp.minimum(1.0, th_inf0))

        class RS(NamedTuple):
            x: jax.Array
            s: jax.Array
            f: jax.Array
            g: jax.Array
            mu_r: jax.Array
            zeta: jax.Array
            j: jax.Array
            stall: jax.Array
            code: jax.Array     # 0 running, 1 success, 4 infeasible, 5 failed

        def psi(x, s, g, mu_r):
            c = constr_resid(P, g, s)
            zero_f = jnp.zeros(())
            return 0.5 * jnp.sum(c * c) + (barrier_phi(P, zero_f, x, s, mu_r))

        def body(R):
            x, s = R.x, R.s
            _, jac = derivs(P, x)
            c = constr_resid(P, R.g, s)
            dxl, dxu, dsl, dsu = slacks(P, x, s)
            sig_x = jnp.where(P.hxl, R.mu_r / dxl ** 2, 0.0) + jnp.where(P.hxu, R.mu_r / dxu ** 2, 0.0)
            sig_s = jnp.where(P.hsl, R.mu_r / dsl ** 2, 0.0) + jnp.where(P.hsu, R.mu_r / dsu ** 2, 0.0)
            zeta = R.zeta
            gbx, gbs = barrier_grad(P, jnp.zeros(n), x, s, R.mu_r)
            A, B, fac, inv_s = factorize(P, jnp.zeros(hr.size), jac, sig_x, sig_s, zeta, 1.0, fast=False)
            dx, ds, _ = solve_reduced(P, A, B, fac, inv_s, gbx, gbs, c)
            ds = jnp.where(P.eq | P.free, 0.0, ds)
            amax = frac_to_boundary(P, x, s, dx, ds, 0.99)
            psi0 = psi(x, s, R.g, R.mu_r)
            # directional derivative of psi along (dx, ds)
            dpsi = (jnp.dot(jt_mult(jac, c) + gbx, dx) + jnp.dot(jnp.where(P.eq | P.free, 0.0, -c) + gbs, ds))

            def ls_cond(L):
                return (~L[1]) & (L[2] < 30)

            def ls_body(L):
                a, _, t, _ = L
                xt, st_ = x + a * dx, s + a * ds
                ft, gt = evaluate(P, xt)
                pt = psi(xt, st_, gt, R.mu_r)
                ok = jnp.isfinite(pt) & (pt <= psi0 + 1e-4 * a * jnp.minimum(dpsi, 0.0))
                return jnp.where(ok, a, 0.5 * a), ok, t + 1, (ft, gt)

            a, ok, _, (ft, gt) = lax.while_loop(ls_cond, ls_body, (amax, jnp.zeros((), bool), jnp.zeros((), jnp.int32), (R.f, R.g)))
            xn = jnp.where(ok, x + a * dx, x)
            sn = jnp.where(ok, s + a * ds, s)
            fn = jnp.where(ok, ft, R.f)
            gn = jnp.where(ok, gt, R.g)
            sn = jnp.where(P.free, gn, jnp.where(P.eq, P.gl, sn))
            th_new = theta_of(P, gn, sn)
            th_old = theta_of(P, R.g, s)
            phi_new = barrier_phi(P, fn, xn, sn, mu)
            success = (th_new <= o.kappa_resto * theta0) & filter_ok(S, th_new, phi_new)
            progress = th_old - th_new > 1e-6 * jnp.maximum(th_old, EPS)
            stall = jnp.where(progress | (R.mu_r > 10 * o.tol), 0, R.stall + 1)
            # local infeasibility: no progress and a stationary point of 1/2 ||c||^2 over the
            # bounds (projected gradient small relative to ||c||)
            gx = jnp.where(P.fixed, 0.0, jt_mult(jac, c))
            gs = jnp.where(P.hsl | P.hsu, -c, 0.0)

            def near(d, b):
                return d <= 1e-5 * jnp.maximum(1.0, jnp.abs(jnp.where(jnp.isfinite(b), b, 0.0)))

            pgx = jnp.where((P.hxl & near(dxl, P.xl) & (gx > 0)) | (P.hxu & near(dxu, P.xu) & (gx < 0)), 0.0, gx)
            pgs = jnp.where((P.hsl & near(dsl, P.gl) & (gs > 0)) | (P.hsu & near(dsu, P.gu) & (gs < 0)), 0.0, gs)
            pg = jnp.maximum(jnp.max(jnp.abs(pgx), initial=0.0), jnp.max(jnp.abs(pgs), initial=0.0))
            stationary = pg <= 1e-4 * jnp.maximum(jnp.max(jnp.abs(c), initial=0.0), 1e-300)
            infeasible = (stall >= 5) & stationary & (th_new > 0.0)
            # Levenberg-Marquardt update of the damping: relax after full steps, stiffen after cuts
            zeta_n = jnp.clip(jnp.where(ok & (a >= 0.99 * amax), 0.25 * zeta, zeta * jnp.minimum(100.0, 2.0 / a)),
                              1e-10, 1e10)
            j = R.j + 1
            code = jnp.where(success, 1, jnp.where(infeasible, 4, jnp.where(j >= o.max_resto_iter, 5, 0)))
            mu_r = jnp.maximum(0.2 * R.mu_r, o.tol / 10)
            return RS(xn, sn, fn, gn, mu_r, zeta_n, j, stall.astype(jnp.int32), code.astype(jnp.int32))

        R0 = RS(it0.x, it0.s, S.ev.f, S.ev.g, mu_r0, jnp.asarray(1e-4), jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32),
                jnp.where(active, 0, 1).astype(jnp.int32))
        R = lax.while_loop(lambda R: R.code == 0, body, R0)
        return R

    # ---------------------------------------------------------------- one IPM iteration
    def iteration(P, S):
        it, ev = S.it, S.ev
        # barrier parameter update (7), possibly several times
        def mu_cond(c):
            mu, cnt, force = c
            return ((emu_only(P, it, ev, mu) <= o.kappa_eps * mu) | force) & (mu > o.tol / 10 + 1e-300) & (cnt < 20)

        def mu_body(c):
            mu, cnt, _ = c
            return jnp.maximum(o.tol / 10, jnp.minimum(o.kappa_mu * mu, mu ** o.theta_mu)), cnt + 1, jnp.zeros((), bool)

        mu, nupd, _ = lax.while_loop(mu_cond, mu_body, (S.mu, jnp.zeros((), jnp.int32), S.tiny_count > 0))
        S = lax.cond(nupd > 0, filter_reset, lambda s_: s_, S)
        tau = jnp.maximum(o.tau_min, 1.0 - mu)

        # search direction with inertia correction
        Wvals = hessian(P, it.x, it.y)
        sig_x, sig_s = sigmas(P, it)
        skip_zero = S.n_perturbed >= o.degen_iters_max
        jac_degen = S.n_dc >= o.degen_iters_max
        A, B, fac, inv_s, ok_step, dw, dc, dw_last, n_fact = inertia_corrected_factor(
            P, Wvals, ev.jac, sig_x, sig_s, S.dw_last, mu, skip_zero, jac_degen)
        n_perturbed = jnp.where(dw > 0, S.n_perturbed + 1, 0).astype(jnp.int32)
        n_dc = jnp.where(dc > 0, S.n_dc + 1, 0).astype(jnp.int32)
        gx, gs = barrier_grad(P, ev.grad, it.x, it.s, mu)
        rx = gx + jt_mult(ev.jac, it.y)
        rs = jnp.where(P.hsl | P.hsu, gs - it.y, 0.0)
        c = constr_resid(P, ev.g, it.s)
        dx, ds, dy = solve_reduced(P, A, B, fac, inv_s, rx, rs, c)
        ds = jnp.where(P.eq | P.free, 0.0, ds)
        dy = jnp.where(P.free, 0.0, dy)
        finite_step = jnp.all(jnp.isfinite(dx)) & jnp.all(jnp.isfinite(dy))
        ok_step = ok_step & finite_step

        # filter line search
        theta_k = theta_of(P, ev.g, it.s)
        phi_k = barrier_phi(P, ev.f, it.x, it.s, mu)
        gd = jnp.dot(gx, dx) + jnp.dot(gs, ds)
        amax = frac_to_boundary(P, it.x, it.s, dx, ds, tau)
        gd_neg = gd < 0
        mgd = jnp.where(gd_neg, -gd, 1.0)
        a_min = o.alpha_min_frac * jnp.where(
            gd_neg,
            jnp.where(theta_k <= S.theta_min,
                      jnp.minimum(o.gamma_theta, jnp.minimum(o.gamma_phi * theta_k / mgd, o.delta * theta_k ** o.s_theta / mgd ** o.s_phi)),
                      jnp.minimum(o.gamma_theta, o.gamma_phi * theta_k / mgd)),
            o.gamma_theta)

        def switching(a):
            return gd_neg & (a * mgd ** o.s_phi > o.delta * theta_k ** o.s_theta)

        def acceptable(a, theta_t, phi_t):
            ftype = (theta_k <= S.theta_min) & switching(a)
            armijo = phi_t <= phi_k + o.eta_phi * a * gd
            suff = (theta_t <= (1 - o.gamma_theta) * theta_k) | (phi_t <= phi_k - o.gamma_phi * theta_k)
            return filter_ok(S, theta_t, phi_t) & jnp.where(ftype, armijo, suff), ftype & armijo

        tiny = jnp.max(jnp.abs(dx) / (1.0 + jnp.abs(it.x)), initial=0.0) < 10 * EPS
        tiny = tiny & (jnp.max(jnp.abs(ds) / (1.0 + jnp.abs(it.s)), initial=0.0) < 10 * EPS) & ok_step

        # first trial at alpha_max
        f1, g1, s1, th1, ph1 = trial_eval(P, it.x + amax * dx, it.s + amax * ds, mu)
        acc1, ft1 = acceptable(amax, th1, ph1)
        acc1 = acc1 | tiny

        # second-order corrections (Sec. 2.4), only if the first trial did not reduce theta
        class SOC(NamedTuple):
            p: jax.Array
            csoc: jax.Array
            theta_old: jax.Array
            active: jax.Array
            acc: jax.Array
            ftype: jax.Array
            a: jax.Array
            dx: jax.Array
            ds: jax.Array
            dy: jax.Array
            f: jax.Array
            g: jax.Array
            s: jax.Array

        c1 = constr_resid(P, g1, s1)
        soc0 = SOC(jnp.zeros((), jnp.int32), amax * c + c1, th1, (~acc1) & (th1 >= theta_k) & ok_step & (o.max_soc > 0),
                   jnp.zeros((), bool), jnp.zeros((), bool), amax, dx, ds, dy, f1, g1, s1)

        def soc_body(Q):
            dxs, dss, dys = solve_reduced(P, A, B, fac, inv_s, rx, rs, Q.csoc)
            dss = jnp.where(P.eq | P.free, 0.0, dss)
            a_s = frac_to_boundary(P, it.x, it.s, dxs, dss, tau)
            ft, gt, stt, tht, pht = trial_eval(P, it.x + a_s * dxs, it.s + a_s * dss, mu)
            acc, ftype = acceptable(amax, tht, pht)
            p = Q.p + 1
            cont = (~acc) & (p < o.max_soc) & (tht <= o.kappa_soc * Q.theta_old)
            csoc = a_s * Q.csoc + constr_resid(P, gt, stt)
            return SOC(p, csoc, tht, cont, acc, ftype, a_s, dxs, dss, dys, ft, gt, stt)

        soc = lax.while_loop(lambda Q: Q.active, soc_body, soc0)

        # backtracking (Armijo / filter), alpha halved
        class LS(NamedTuple):
            a: jax.Array
            t: jax.Array
            acc: jax.Array
            ftype: jax.Array
            f: jax.Array
            g: jax.Array
            s: jax.Array
            fail: jax.Array

        start_bt = (~acc1) & (~soc.acc) & ok_step
        ls0 = LS(0.5 * amax, jnp.ones((), jnp.int32), jnp.zeros((), bool), jnp.zeros((), bool), f1, g1, s1,
                 (0.5 * amax < a_min) & start_bt)

        def ls_cond(L):
            return start_bt & (~L.acc) & (~L.fail)

        def ls_body(L):
            ft, gt, stt, tht, pht = trial_eval(P, it.x + L.a * dx, it.s + L.a * ds, mu)
            acc, ftype = acceptable(L.a, tht, pht)
            a_next = 0.5 * L.a
            fail = (~acc) & ((a_next < a_min) | (L.t + 1 >= o.max_ls_trials))
            return LS(jnp.where(acc, L.a, a_next), L.t + 1, acc, ftype, ft, gt, stt, fail)

        ls = lax.while_loop(ls_cond, ls_body, ls0)

        # choose the accepted trial
        use_soc = (~acc1) & soc.acc
        use_bt = (~acc1) & (~soc.acc) & ls.acc
        accepted = ok_step & (acc1 | soc.acc | ls.acc)
        a_pr = jnp.where(acc1, amax, jnp.where(use_soc, soc.a, ls.a))
        ftype = jnp.where(acc1, ft1, jnp.where(use_soc, soc.ftype, ls.ftype)) | tiny
        DX = jnp.where(use_soc, soc.dx, dx)
        DS = jnp.where(use_soc, soc.ds, ds)
        DY = jnp.where(use_soc, soc.dy, dy)
        f_new = jnp.where(acc1, f1, jnp.where(use_soc, soc.f, ls.f))
        g_new = jnp.where(acc1, g1, jnp.where(use_soc, soc.g, ls.g))
        n_trials = 1 + soc.p + jnp.where(use_bt | (~accepted), ls.t - 1, 0)

        dzl, dzu, dvl, dvu = dual_steps(P, it, DX, DS, mu)
        a_du = jnp.minimum(jnp.minimum(frac_dual(it.zl, dzl, P.hxl, tau), frac_dual(it.zu, dzu, P.hxu, tau)),
                           jnp.minimum(frac_dual(it.vl, dvl, P.hsl, tau), frac_dual(it.vu, dvu, P.hsu, tau)))
        x_n = it.x + a_pr * DX
        s_n = it.s + a_pr * DS
        s_n = jnp.where(P.free, g_new, jnp.where(P.eq, P.gl, s_n))
        y_n = it.y + a_pr * DY
        zl, zu, vl, vu = kappa_sigma_reset(P, x_n, s_n, it.zl + a_du * dzl, it.zu + a_du * dzu,
                                           it.vl + a_du * dvl, it.vu + a_du * dvu, mu)
        S_acc = S
        S_acc = lax.cond(ftype, lambda s_: s_, lambda s_: filter_add(s_, theta_k, phi_k), S_acc)
        it_acc = Iterate(x_n, s_n, y_n, zl, zu, vl, vu)

        # restoration when the line search failed; as IPOPT, a failed line search at
        # an acceptable point stops there instead ("Solved_To_Acceptable_Level")
        ls_failed = ~accepted      # includes a failed inertia correction (IC-6)
        stop_acceptable = ls_failed & S.cur_acc
        need_resto = ls_failed & ~S.cur_acc
        S_r = filter_add(S, theta_k, phi_k)

        def do_resto(_):
            R = _restoration(P, S_r, mu, need_resto)
            return R.x, R.s, R.f, R.g, R.code, R.j

        def no_resto(_):
            return it.x, it.s, ev.f, ev.g, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32)

        rx_, rs_, rf_, rg_, rcode, rj = lax.cond(need_resto, do_resto, no_resto, None)
        resto_ok = need_resto & (rcode == 1)

        # assemble the next iterate
        x_next = jnp.where(resto_ok, rx_, jnp.where(accepted, x_n, it.x))
        s_next = jnp.where(resto_ok, rs_, jnp.where(accepted, s_n, it.s))
        f_next = jnp.where(resto_ok, rf_, jnp.where(accepted, f_new, ev.f))
        g_next = jnp.where(resto_ok, rg_, jnp.where(accepted, g_new, ev.g))
        grad_n, jac_n = derivs(P, x_next)
        ev_next = Evals(f_next, g_next, grad_n, jac_n)
        # after restoration: bound multipliers central, y by least squares (Sec. 3.6)
        dxl, dxu, dsl, dsu = slacks(P, x_next, s_next)
        zc = (jnp.where(P.hxl, mu / dxl, 0.0), jnp.where(P.hxu, mu / dxu, 0.0),
              jnp.where(P.hsl, mu / dsl, 0.0), jnp.where(P.hsu, mu / dsu, 0.0))
        it_r = Iterate(x_next, s_next, jnp.zeros(m), *zc)
        it_r = it_r._replace(y=lax.cond(resto_ok, lambda: ls_multipliers(P, it_r, ev_next), lambda: jnp.zeros(m)))
        it_next = jax.tree.map(lambda a_, b_: jnp.where(resto_ok, a_, b_), it_r, it_acc)

        # a failed restoration (not local infeasibility) falls back to the last acceptable iterate
        rollback = need_resto & ~resto_ok & (rcode != 4) & S.has_acc
        it_next = jax.tree.map(lambda a_, b_: jnp.where(rollback, a_, b_), S.acc_it, it_next)
        ev_next = jax.tree.map(lambda a_, b_: jnp.where(rollback, a_, b_), S.acc_ev, ev_next)
        S_next = jax.tree.map(lambda a_, b_: jnp.where(resto_ok, a_, b_), S_r, S_acc)
        status = jnp.where(stop_acceptable | rollback, 2,
                           jnp.where(need_resto & ~resto_ok,
                                     jnp.where(rcode == 4, 4, jnp.where(ok_step, 5, 6)), 0)).astype(jnp.int32)
        kind = jnp.where(resto_ok | need_resto, ord("r"),
                         jnp.where(tiny, ord("s"),
                                   jnp.where(use_soc, jnp.where(ftype, ord("F"), ord("H")),
                                             jnp.where(ftype, ord("f"), ord("h")))))
        tiny_count = jnp.where(tiny, S.tiny_count + 1, 0).astype(jnp.int32)
        step_info = dict(mu=mu, d_norm=jnp.max(jnp.abs(DX), initial=0.0), reg=dw,
                         alpha_du=jnp.where(accepted, a_du, 0.0), alpha_pr=jnp.where(accepted, a_pr, 0.0),
                         ls=n_trials, kind=kind, resto_iters=S.resto_iters + rj, n_fact=n_fact)
        S_next = S_next._replace(it=it_next, ev=ev_next, mu=mu, dw_last=dw_last, tiny_count=tiny_count,
                                 n_perturbed=n_perturbed, n_dc=n_dc,
                                 resto_iters=S.resto_iters + rj, k=S.k + 1)
        return S_next, status, step_info

    # ---------------------------------------------------------------- termination + history
    def record_and_check(P, S, step_info, status):
        err = errors(P, S.it, S.ev, S.mu)
        k = S.k
        conv = ((err["E0"] <= o.tol) & (err["pr_u"] <= o.constr_viol_tol) & (err["du_u"] <= o.dual_inf_tol)
                & (err["co_u"] <= o.compl_inf_tol))
        acc_pt = ((err["E0"] <= o.acceptable_tol) & (err["pr_u"] <= o.acceptable_constr_viol_tol)
                  & (err["du_u"] <= o.acceptable_dual_inf_tol) & (err["co_u"] <= o.acceptable_compl_inf_tol))
        n_acc = jnp.where(acc_pt, S.n_acceptable + 1, 0).astype(jnp.int32)
        finite = jnp.isfinite(S.ev.f) & jnp.all(jnp.isfinite(S.ev.g)) & jnp.all(jnp.isfinite(S.ev.grad)) & jnp.all(jnp.isfinite(S.ev.jac))
        tiny_stop = (S.tiny_count >= 2) & (S.mu <= o.tol / 10 * 1.0000001)
        new_status = jnp.where(
            status != 0, status,
            jnp.where(~finite, 7,
                      jnp.where(conv, 1,
                                jnp.where((n_acc >= o.acceptable_iter) & (o.acceptable_iter > 0), 2,
                                          jnp.where(tiny_stop, jnp.where(acc_pt, 2, 8),
                                                    jnp.where(k >= o.max_iter, 3, 0))))))
        hist = S.hist
        if o.keep_history:
            row = dict(obj=S.ev.f / P.sf, inf_pr=err["pr_u"], inf_du=err["dual"], compl=err["compl"], **step_info)
            hist = {key: hist[key].at[k].set(jnp.asarray(row[key]).astype(hist[key].dtype)) for key in HIST_FIELDS}
        new_status = new_status.astype(jnp.int32)
        keep = acc_pt & finite
        acc_it = jax.tree.map(lambda a_, b_: jnp.where(keep, a_, b_), S.it, S.acc_it)
        acc_ev = jax.tree.map(lambda a_, b_: jnp.where(keep, a_, b_), S.ev, S.acc_ev)
        return S._replace(done=new_status != 0, status=new_status, n_acceptable=n_acc, hist=hist,
                          cur_acc=keep, acc_it=acc_it, acc_ev=acc_ev, has_acc=S.has_acc | keep)

    # ---------------------------------------------------------------- driver
    def run(x0, xl, xu, gl, gu, p, fopts=None):
        nonlocal o
        vals = jnp.asarray(float_vector(o_static) if fopts is None else fopts, dtype=float)
        o = TracedOptions(o_static, vals)
        try:
            return _run(x0, xl, xu, gl, gu, p)
        finally:
            o = o_static

    def _run(x0, xl, xu, gl, gu, p):
        x0, xl, xu, gl, gu = (jnp.asarray(a, dtype=float) for a in (x0, xl, xu, gl, gu))
        fixed = xl == xu
        eq = gl == gu
        hxl = jnp.isfinite(xl) & ~fixed
        hxu = jnp.isfinite(xu) & ~fixed
        hsl = jnp.isfinite(gl) & ~eq
        hsu = jnp.isfinite(gu) & ~eq
        free = ~eq & ~hsl & ~hsu
        x0 = jnp.where(fixed, xl, x0)
        # gradient-based scaling at the user's starting point (Sec. 3.8)
        if o.nlp_scaling_method == "gradient-based":
            g0 = nlp.grad(x0, p)
            j0 = nlp.jac_values(x0, p)
            gmax = jnp.max(jnp.abs(jnp.where(fixed, 0.0, g0)), initial=0.0)
            sf = jnp.maximum(o.nlp_scaling_min_value, jnp.minimum(1.0, o.nlp_scaling_max_gradient / jnp.maximum(gmax, 1e-300)))
            rmax = jnp.zeros(m).at[jr].max(jnp.abs(j0))
            sg = jnp.maximum(o.nlp_scaling_min_value, jnp.minimum(1.0, o.nlp_scaling_max_gradient / jnp.maximum(rmax, 1e-300)))
            sf = jnp.where(jnp.isfinite(sf), sf, 1.0) * o.obj_scaling_factor
            sg = jnp.where(jnp.isfinite(sg), sg, 1.0)
        else:
            sf = jnp.asarray(o.obj_scaling_factor, float)
            sg = jnp.ones(m)
        P = Prob(p, xl, xu, gl * sg, gu * sg, hxl, hxu, fixed, eq, hsl, hsu, free, sf, sg)
        # initial point pushed into the bounds (Sec. 3.6)
        x = _push(x0, xl, xu, hxl, hxu, o.bound_push, o.bound_frac)
        f, g = evaluate(P, x)
        s = _push(g, P.gl, P.gu, hsl, hsu, o.slack_bound_push, o.slack_bound_frac)
        s = jnp.where(eq, P.gl, jnp.where(free, g, s))
        grad, jac = derivs(P, x)
        ev = Evals(f, g, grad, jac)
        bm = o.bound_mult_init_val
        it = Iterate(x, s, jnp.zeros(m), jnp.where(hxl, bm, 0.0), jnp.where(hxu, bm, 0.0),
                     jnp.where(hsl, bm, 0.0), jnp.where(hsu, bm, 0.0))
        it = it._replace(y=ls_multipliers(P, it, ev))
        theta0 = theta_of(P, g, s)
        hist = {key: jnp.zeros(H if o.keep_history else 1, dtype=jnp.int32 if key in INT_FIELDS else float)
                for key in HIST_FIELDS}
        S = State(it=it, ev=ev, mu=jnp.asarray(o.mu_init, float), k=jnp.zeros((), jnp.int32),
                  done=jnp.zeros((), bool), status=jnp.zeros((), jnp.int32),
                  filt_theta=jnp.full(o.filter_size, jnp.inf), filt_phi=jnp.full(o.filter_size, jnp.inf),
                  filt_n=jnp.zeros((), jnp.int32),
                  theta_min=o.theta_min_fact * jnp.maximum(1.0, theta0),
                  theta_max=o.theta_max_fact * jnp.maximum(1.0, theta0),
                  dw_last=jnp.zeros(()), n_perturbed=jnp.zeros((), jnp.int32), n_dc=jnp.zeros((), jnp.int32), n_acceptable=jnp.zeros((), jnp.int32), tiny_count=jnp.zeros((), jnp.int32),
                  resto_iters=jnp.zeros((), jnp.int32), hist=hist,
                  cur_acc=jnp.zeros((), bool), acc_it=it, acc_ev=ev, has_acc=jnp.zeros((), bool))
        info0 = dict(mu=S.mu, d_norm=jnp.zeros(()), reg=jnp.zeros(()), alpha_du=jnp.zeros(()),
                     alpha_pr=jnp.zeros(()), ls=jnp.zeros((), jnp.int32), kind=jnp.zeros((), jnp.int32),
                     resto_iters=jnp.zeros((), jnp.int32), n_fact=jnp.zeros((), jnp.int32))
        S = record_and_check(P, S, info0, jnp.zeros((), jnp.int32))

        def body(S):
            S2, status, info = iteration(P, S)
            return record_and_check(P, S2, info, status)

        S = lax.while_loop(lambda S: ~S.done, body, S)
        return S, P

    return run


def _push(x, lo, hi, hlo, hhi, push, frac):
    """Project x strictly inside [lo, hi] (Sec. 3.6, bound_push / bound_frac)."""
    width = jnp.where(hlo & hhi, hi - lo, jnp.inf)
    pl = jnp.minimum(push * jnp.maximum(1.0, jnp.abs(lo)), frac * width)
    pu = jnp.minimum(push * jnp.maximum(1.0, jnp.abs(hi)), frac * width)
    x = jnp.where(hlo, jnp.maximum(x, lo + pl), x)
    x = jnp.where(hhi, jnp.minimum(x, hi - pu), x)
    return x


def unscale(S: State, P: Prob):
    """(x, lam_g, z_l, z_u, f) in the user's units from a final state."""
    it = S.it
    lam = it.y * P.sg / P.sf
    return it.x, lam, it.zl / P.sf, it.zu / P.sf, S.ev.f / P.sf
