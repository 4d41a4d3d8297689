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
corrections (Sec. 2.4) and IPOPT's feasibility-restoration phase (Sec. 3.3): the l1 problem

    min  rho sum(p + n) + eta/2 ||D_R (x - x_R)||^2   s.t.  c(x, s) - p + n = 0,  p, n >= 0

(eta = sqrt(mu), D_R = diag(1/max(1, |x_R|))), solved by the same iteration in a restoration mode:
its p and n steps are eliminated into the same block system, so one traced factorisation serves
both, and restoration iterations count as iterations, as in IPOPT's log. All of it runs under
one ``lax.while_loop``: ``make_ipm`` returns a pure function that can be jitted and
``vmap``-ped over a batch (converged members freeze).
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


class Globalization(NamedTuple):
    """The filter (Sec. 2.3) and the inertia correction's memory (Sec. 3.1) of the problem being
    solved; the restoration phase starts its own and stashes the original problem's."""
    filt_theta: jax.Array
    filt_phi: jax.Array
    filt_n: jax.Array
    theta_min: jax.Array
    theta_max: jax.Array
    dw_last: jax.Array
    pert: jax.Array         # (3,) IPOPT's degeneracy test state, see finalize_test


def fresh_globalization(size: int, theta_min, theta_max) -> Globalization:
    inf = jnp.full(size, jnp.inf)
    return Globalization(inf, inf, jnp.zeros((), jnp.int32), jnp.asarray(theta_min, float),
                         jnp.asarray(theta_max, float), jnp.zeros(()), jnp.zeros(3, jnp.int32))


class Resto(NamedTuple):
    """Restoration-phase variables and what the return to the original problem needs."""
    on: jax.Array           # the iteration is solving the restoration problem
    fresh: jax.Array        # its first iteration (no barrier update then, as IPOPT)
    p: jax.Array            # (m,) positive / negative parts of c(x, s), rows with p, n: ~free
    n: jax.Array
    zp: jax.Array           # (m,) their bound multipliers
    zn: jax.Array
    xR: jax.Array           # (n,) reference point of the proximity term
    dr: jax.Array           # (n,) diagonal of D_R^2 = 1/max(1, |x_R|)^2 (0 when not in restoration)
    s0: jax.Array           # slacks and bound multipliers where the restoration started
    z0: tuple
    mu_orig: jax.Array      # the original problem's mu, reference point, filter and
    theta_ref: jax.Array    # regularisation, stashed for the return
    phi_ref: jax.Array
    inf_ref: jax.Array
    outer: "Globalization"


def resto_off(R: Resto) -> Resto:
    """The inactive restoration state (p = n = 1 keep the masked logarithms finite)."""
    return R._replace(on=jnp.zeros((), bool), fresh=jnp.zeros((), bool), p=jnp.ones_like(R.p), n=jnp.ones_like(R.n),
                      zp=jnp.zeros_like(R.zp), zn=jnp.zeros_like(R.zn), dr=jnp.zeros_like(R.dr))


class Watchdog(NamedTuple):
    """IPOPT's watchdog (Chamberlain et al.): after ``watchdog_shortened_iter_trigger``
    consecutive shortened steps, full steps are taken tentatively (up to
    ``watchdog_trial_iter_max``) and judged against the point where the watchdog started; if
    none is acceptable, the iterate goes back there and backtracks from half the step."""
    count: jax.Array        # consecutive shortened steps
    on: jax.Array
    trials: jax.Array
    it: Iterate
    ev: Evals
    theta: jax.Array        # merit and directional derivative at the watchdog's start
    phi: jax.Array
    gd: jax.Array
    skip_first: jax.Array   # backtrack without trying the full step (after a watchdog reset)


class State(NamedTuple):
    it: Iterate
    ev: Evals
    mu: jax.Array
    k: jax.Array
    done: jax.Array
    status: jax.Array
    gl: Globalization
    n_acceptable: jax.Array
    tiny_count: jax.Array
    cur_acc: jax.Array      # the current iterate passes the acceptable-level tests
    acc_it: Iterate         # the last acceptable iterate (IPOPT's fallback when the line search
    acc_ev: Evals           # and restoration fail, Sec. 3.3) and its evaluations
    has_acc: jax.Array
    resto_iters: jax.Array
    rs: Resto
    wd: Watchdog
    hist: dict


HIST_FIELDS = ("obj", "inf_pr", "inf_du", "mu", "d_norm", "reg", "alpha_du", "alpha_pr", "ls",
               "kind", "compl", "resto_iters", "n_fact", "mode", "res_ratio")
INT_FIELDS = ("ls", "kind", "resto_iters", "n_fact", "mode")


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

    def hessian(P, x, y, resto):
        """Hessian of the Lagrangian; the restoration problem's objective has none in x besides
        the proximity term, which enters the diagonal (``prox_weight``)."""
        return nlp.hess_values(x, P.sg * y, jnp.where(resto, 0.0, P.sf), P.p)

    def jt_mult(jac, y):
        return _segsum(jac * y[jr], jc, n)


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

    def mu_floor(P):
        """IPOPT's smallest barrier parameter, min(tol, compl_inf_tol) / (kappa_eps + 1)."""
        return jnp.minimum(o.tol, o.compl_inf_tol * P.sf) / (o.kappa_eps + 1.0)

    def prox_weight(R, mu):
        """eta D_R^2 of the restoration objective (0 outside the restoration phase: dr = 0)."""
        return o.resto_proximity_weight * jnp.sqrt(mu) * R.dr

    def resto_resid(P, R, g, s, pv, nv):
        """c(x, s) - p + n in the restoration phase (p, n on the non-free rows), else c(x, s)."""
        return constr_resid(P, g, s) + jnp.where(R.on & ~P.free, nv - pv, 0.0)

    def theta_of(P, g, s):
        return jnp.sum(jnp.abs(constr_resid(P, g, s)))

    # ---------------------------------------------------------------- optimality error (5)
    def errors(P, it, ev, mu, R):
        """Optimality errors (5) of the problem being solved (in the restoration phase, of the
        restoration problem); ``pr_s``/``pr_u``: the original constraint violation, scaled and not."""
        x, s, y = it.x, it.s, it.y
        rr = R.on & ~P.free
        rho = o.resto_penalty_parameter
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        gf = jnp.where(R.on, prox_weight(R, mu) * (x - R.xR), ev.grad)
        gLx = jnp.where(P.fixed, 0.0, gf + jt_mult(ev.jac, y) - it.zl + it.zu)
        gLs = jnp.where(P.hsl | P.hsu, -y - it.vl + it.vu, 0.0)
        gLpn = jnp.where(rr, jnp.maximum(jnp.abs(rho - y - R.zp), jnp.abs(rho + y - R.zn)), 0.0)
        dual = jnp.maximum(jnp.maximum(jnp.max(jnp.abs(gLx), initial=0.0), jnp.max(jnp.abs(gLs), initial=0.0)),
                           jnp.max(gLpn, initial=0.0))
        c_orig = constr_resid(P, ev.g, s)
        primal = jnp.max(jnp.abs(resto_resid(P, R, ev.g, s, R.p, R.n)), initial=0.0)

        def cmax(v, mask):
            return jnp.max(jnp.where(mask, jnp.abs(v), 0.0), initial=0.0)

        def compl(m_):
            return jnp.max(jnp.stack([cmax(dxl * it.zl - m_, P.hxl), cmax(dxu * it.zu - m_, P.hxu),
                                      cmax(dsl * it.vl - m_, P.hsl), cmax(dsu * it.vu - m_, P.hsu),
                                      cmax(R.p * R.zp - m_, rr), cmax(R.n * R.zn - m_, rr)]))

        nz = (jnp.sum(P.hxl) + jnp.sum(P.hxu) + jnp.sum(P.hsl) + jnp.sum(P.hsu) + 2 * jnp.sum(rr)).astype(float)
        z1 = (jnp.sum(jnp.abs(it.zl)) + jnp.sum(jnp.abs(it.zu)) + jnp.sum(jnp.abs(it.vl)) + jnp.sum(jnp.abs(it.vu))
              + jnp.sum(jnp.where(rr, R.zp + R.zn, 0.0)))
        sd = jnp.maximum(o.s_max, (jnp.sum(jnp.abs(y)) + z1) / jnp.maximum(1.0, m + nz)) / o.s_max
        sc = jnp.maximum(o.s_max, z1 / jnp.maximum(1.0, nz)) / o.s_max
        c0 = compl(0.0)
        E0 = jnp.maximum(jnp.maximum(dual / sd, primal), c0 / sc)
        Emu = jnp.maximum(jnp.maximum(dual / sd, primal), compl(mu) / sc)
        pr_s = jnp.max(jnp.abs(c_orig), initial=0.0)
        # unscaled quantities for IPOPT's absolute tests
        return dict(E0=E0, Emu=Emu, dual=dual, primal=primal, compl=c0, pr_s=pr_s,
                    pr_u=jnp.max(jnp.abs(c_orig) / P.sg, initial=0.0), du_u=dual / P.sf, co_u=c0 / P.sf)

    # ---------------------------------------------------------------- Newton step (13)
    def masks(P):
        """Hessian and Jacobian entries that enter K (fixed variables and free rows drop out)."""
        return (jnp.where(P.fixed[hr] | P.fixed[hc], 0.0, 1.0),
                jnp.where(P.free[jr] | P.fixed[jc], 0.0, 1.0))

    def kkt_parts(P, rr, sig_x, sig_s, sig_p, sig_n, dw, dc):
        """Diagonals of the reduced system for given regularisation. The slack step and, in the
        restoration phase, the p and n steps are eliminated: each adds 1/(Sigma + delta_w) to
        minus the constraint diagonal of its row (a positive pivot, so the inertia is unchanged)."""
        ineq_b = P.hsl | P.hsu
        inv_s = jnp.where(ineq_b, 1.0 / (sig_s + dw), 0.0)
        inv_p = jnp.where(rr, 1.0 / (sig_p + dw), 0.0)
        inv_n = jnp.where(rr, 1.0 / (sig_n + dw), 0.0)
        diag_x = jnp.where(P.fixed, 1.0, sig_x + dw)
        diag_c = jnp.where(P.free, -1.0, -(dc + inv_s + inv_p + inv_n))
        return (inv_s, inv_p, inv_n), diag_x, diag_c

    def factorize(P, rr, base, sigs, dw, dc):
        """Factor K = ``base`` (blocks assembled once with a zero diagonal, ``assemble_base``)
        plus the diagonal of the given regularisation (IC trials only change the diagonal)."""
        invs, diag_x, diag_c = kkt_parts(P, rr, *sigs, dw, dc)
        A, B = kkt.add_diagonal(st, base[0], diag_x, diag_c), base[1]
        return A, B, kkt.factor(st, A, B, early_exit=True), invs

    def assemble_base(P, Wvals, jac):
        h_mask, jac_mask = masks(P)
        return kkt.assemble(st, Wvals * h_mask, jac * jac_mask, jnp.zeros(n), jnp.zeros(m))

    def solve_reduced(P, A, B, fac, invs, rx, rs, rp, rn, c):
        """Solve (13) given residuals r_x (grad_x phi + J^T y), r_s (grad_s phi - y), r_p, r_n
        (restoration only: grad phi -/+ y) and the constraint residual c; the eliminated steps
        are recovered from their rows: ds = (dy - r_s)/Sigma_s, dp = (dy - r_p)/Sigma_p,
        dn = -(dy + r_n)/Sigma_n (each Sigma including delta_w)."""
        inv_s, inv_p, inv_n = invs
        bx = jnp.where(P.fixed, 0.0, -rx)
        bc = jnp.where(P.free, 0.0, -c - inv_s * rs - inv_p * rp + inv_n * rn)
        dx, dy, res = kkt.solve(st, fac, A, B, bx, bc, *refinement(), with_residual=True)
        # IPOPT's residual ratio of the solve (on the reduced system), from the refinement's
        # last residual
        nsol = jnp.maximum(jnp.max(jnp.abs(dx), initial=0.0), jnp.max(jnp.abs(dy), initial=0.0))
        nrhs = jnp.maximum(jnp.max(jnp.abs(bx), initial=0.0), jnp.max(jnp.abs(bc), initial=0.0))
        ratio = res / jnp.maximum(jnp.minimum(nsol, 1e6 * nrhs) + nrhs, 1e-300)
        ds = jnp.where(P.eq | P.free, 0.0, inv_s * (dy - rs))
        dy = jnp.where(P.free, 0.0, dy)
        return dx, ds, dy, inv_p * (dy - rp), -inv_n * (dy + rn), ratio

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
        """Fraction to the boundary (15) for a vector bounded below by 0."""
        return jnp.min(jnp.where(mask & (dz < 0), -tau * z / jnp.where(dz < 0, dz, -1.0), 1.0), initial=1.0)

    def kappa_sigma_reset(P, x, s, zl, zu, vl, vu, mu):
        """Safeguard (16): keep z_i (x_i - xl_i) within [mu/kappa_sigma, kappa_sigma mu]."""
        dxl, dxu, dsl, dsu = slacks(P, x, s)
        return (clip_mult(zl, dxl, P.hxl, mu), clip_mult(zu, dxu, P.hxu, mu),
                clip_mult(vl, dsl, P.hsl, mu), clip_mult(vu, dsu, P.hsu, mu))

    def clip_mult(z, d, mask, mu):
        ks = o.kappa_sigma
        return jnp.where(mask, jnp.clip(z, mu / (ks * d), ks * mu / d), 0.0)

    # ---------------------------------------------------------------- inertia correction (IC)
    # IPOPT's degeneracy test (PDPerturbationHandler): while it is undetermined whether the
    # Hessian (h) or the Jacobian (j) is structurally degenerate, the trial (delta_c, delta_w)
    # pattern that first succeeds decides it; a degenerate part is perturbed from the start of
    # every later iteration. pert = (h, j, degen_iters), h/j: 0 undetermined, 1 no, 2 yes.
    T_NONE, T_00, T_C0, T_0X, T_CX = 0, 1, 2, 3, 4

    def finalize_test(test, pert):
        h, j, d = pert[0], pert[1], pert[2]
        t00 = test == T_00
        tc0 = test == T_C0
        t0x = test == T_0X
        tcx = test == T_CX
        d = d + jnp.where((tc0 & (j == 0)) | (t0x & (h == 0)) | tcx, 1, 0)
        h_n = jnp.where((t00 | tc0) & (h == 0), 1, jnp.where((t0x | tcx) & (h == 0) & (d >= o.degen_iters_max), 2, h))
        j_n = jnp.where((t00 | t0x) & (j == 0), 1, jnp.where((tc0 | tcx) & (j == 0) & (d >= o.degen_iters_max), 2, j))
        # IPOPT decides both at once on the plain trial when both are undetermined
        j_n = jnp.where(t00 & (h == 0) & (j == 0), 1, j_n)
        return jnp.stack([h_n, j_n, d]).astype(jnp.int32)

    def inertia_corrected_factor(P, rr, Wvals, jac, sig_x, sig_s, sig_p, sig_n, dw_last, mu, pert):
        """Algorithm IC (Sec. 3.1) with IPOPT's rules: the smallest delta_w giving inertia (n, m, 0),
        delta_c = jacobian_regularization_value mu^kappa_c when K is singular; all trial
        factorisations share one traced factorisation inside a while_loop."""
        delta_cd = o.jacobian_regularization_value * mu ** o.jacobian_regularization_exponent

        def wrong_inertia_dw(dw):
            first = jnp.where(dw_last == 0.0, o.first_hessian_perturbation,
                              jnp.maximum(o.min_hessian_perturbation, o.perturb_dec_fact * dw_last))
            big = (dw_last == 0.0) | (1e5 * dw_last < dw)
            return jnp.where(dw == 0.0, first, jnp.where(big, o.perturb_inc_fact_first, o.perturb_inc_fact) * dw)

        S_, nb = st.S, st.nb
        base = assemble_base(P, Wvals, jac)
        z3 = jnp.zeros((S_, nb, nb))
        i0 = jnp.zeros((), jnp.int64)
        fac0 = kkt.Factor(z3, jnp.ones((S_, nb)), jnp.zeros((S_, st.b_rows.size, nb)), i0, i0, i0, jnp.ones((S_, nb)))
        sigs = (sig_x, sig_s, sig_p, sig_n)
        undetermined0 = (pert[0] == 0) | (pert[1] == 0)
        test0 = jnp.where(undetermined0, T_00, T_NONE)
        dc0 = jnp.where(pert[1] == 2, delta_cd, 0.0)
        dw0 = jnp.where(pert[0] == 2, wrong_inertia_dw(0.0), 0.0)

        def cond(c):
            ok, dw, dc, t = c[:4]
            return (~ok) & (dw <= o.max_hessian_perturbation) & (t < o.max_inertia_trials)

        def body(c):
            _, dw, dc, t, test, pert_ = c[:6]
            A_, B_, fac_, invs_ = factorize(P, rr, base, sigs, dw, dc)
            fac_ = fac_._replace(npos=fac_.npos.astype(jnp.int64), nneg=fac_.nneg.astype(jnp.int64),
                                 nzero=fac_.nzero.astype(jnp.int64))
            ok = kkt.inertia_ok(st, fac_)
            singular = (~ok) & (fac_.nzero > 0)
            wrong = (~ok) & ~singular
            # wrong inertia: the test is decided (PerturbForWrongInertia), delta_w grows
            pert_ = jnp.where(wrong, finalize_test(test, pert_), pert_)
            undetermined = (pert_[0] == 0) | (pert_[1] == 0)
            # singular K (PerturbForSingularity): walk the test pattern while undetermined,
            # otherwise delta_c first, then delta_w
            s_dc = jnp.where(undetermined,
                             jnp.where(test == T_00, jnp.where(pert_[1] == 0, delta_cd, dc),
                                       jnp.where(test == T_C0, 0.0, jnp.where(test == T_0X, delta_cd, dc))),
                             jnp.where(dc > 0, dc, delta_cd))
            s_dw_grow = jnp.where(undetermined, ~((test == T_00) & (pert_[1] == 0)), dc > 0)
            s_test = jnp.where(undetermined,
                               jnp.where(test == T_00, jnp.where(pert_[1] == 0, T_C0, T_0X),
                                         jnp.where(test == T_C0, T_0X, T_CX)), T_NONE)
            dw_n = jnp.where(ok, dw, jnp.where(wrong | (singular & s_dw_grow), wrong_inertia_dw(dw), dw))
            dc_n = jnp.where(singular, s_dc, dc)
            test_n = jnp.where(ok, test, jnp.where(singular, s_test, T_NONE))
            return ok, dw_n, dc_n, t + 1, test_n, pert_, A_, B_, fac_, invs_

        zm = jnp.zeros(m)
        ok, dw, dc, trials, test, pert, A, B, fac, invs = lax.while_loop(
            cond, body, (jnp.zeros((), bool), dw0, dc0, jnp.zeros((), jnp.int32), jnp.asarray(test0, jnp.int32),
                         pert, z3, z3, fac0, (zm, zm, zm)))
        pert = jnp.where(ok, finalize_test(test, pert), pert)
        new_dw_last = jnp.where(ok & (dw > 0), dw, dw_last)
        return A, B, fac, invs, ok, dw, dc, new_dw_last, trials, pert

    # ---------------------------------------------------------------- least-squares multipliers
    def ls_multipliers(P, it, ev):
        """y minimising ||grad f + J^T y - z||^2 + ||-y - v||^2 (Sec. 3.6), or 0 if too large."""
        ineq_b = P.hsl | P.hsu
        jac_mask = masks(P)[1]
        diag_c = jnp.where(P.free, -1.0, jnp.where(ineq_b, -1.0, 0.0))
        A, B = kkt.assemble(st, jnp.zeros(hr.size), ev.jac * jac_mask, jnp.ones(n), diag_c)
        fac = kkt.factor(st, A, B, fast=False)
        a = jnp.where(P.fixed, 0.0, ev.grad - it.zl + it.zu)
        b = jnp.where(ineq_b, -it.vl + it.vu, 0.0)
        _, y = kkt.solve(st, fac, A, B, -a, -b, *refinement())
        good = kkt.inertia_ok(st, fac) & jnp.all(jnp.isfinite(y)) & (jnp.max(jnp.abs(y), initial=0.0) <= o.constr_mult_init_max)
        return jnp.where(good & ~P.free, y, 0.0)

    # ---------------------------------------------------------------- filter helpers
    def filter_ok(G, theta, phi):
        blocked = (theta >= G.filt_theta) & (phi >= G.filt_phi)
        return (theta <= G.theta_max) & ~jnp.any(blocked)

    def filter_add(S, theta, phi):
        G = S.gl
        i = G.filt_n % o.filter_size
        return S._replace(gl=G._replace(filt_theta=G.filt_theta.at[i].set((1 - o.gamma_theta) * theta),
                                        filt_phi=G.filt_phi.at[i].set(phi - o.gamma_phi * theta),
                                        filt_n=G.filt_n + 1))

    def filter_reset(S):
        return S._replace(gl=S.gl._replace(filt_theta=jnp.full(o.filter_size, jnp.inf),
                                           filt_phi=jnp.full(o.filter_size, jnp.inf),
                                           filt_n=jnp.zeros((), jnp.int32)))

    # ---------------------------------------------------------------- merit of the current mode
    def merit(P, R, f, g, x, s, pv, nv, mu):
        """(theta, phi) of the problem being solved: the barrier problem (3), or in the
        restoration phase theta = ||c(x, s) - p + n||_1 and phi = the barrier function of
        rho sum(p + n) + eta/2 ||D_R (x - x_R)||^2 (bounds of x, s, p, n)."""
        rr = R.on & ~P.free
        theta = jnp.sum(jnp.abs(resto_resid(P, R, g, s, pv, nv)))
        f_r = (o.resto_penalty_parameter * jnp.sum(jnp.where(rr, pv + nv, 0.0))
               + 0.5 * jnp.sum(prox_weight(R, mu) * (x - R.xR) ** 2))
        pn = jnp.where(rr, pv, 1.0), jnp.where(rr, nv, 1.0)
        bar_pn = jnp.sum(jnp.where(rr, -mu * (jnp.log(pn[0]) + jnp.log(pn[1])) + KAPPA_D * mu * (pn[0] + pn[1]), 0.0))
        phi = barrier_phi(P, jnp.where(R.on, f_r, f), x, s, mu) + bar_pn
        return theta, phi

    def trial_eval(P, R, x, s, pv, nv, mu):
        f, g = evaluate(P, x)
        s = jnp.where(P.free, g, s)
        theta, phi = merit(P, R, f, g, x, s, pv, nv, mu)
        finite = jnp.isfinite(f) & jnp.all(jnp.isfinite(g)) & jnp.isfinite(phi)
        return f, g, s, jnp.where(finite, theta, jnp.inf), jnp.where(finite, phi, jnp.inf)

    # ---------------------------------------------------------------- restoration phase (Sec. 3.3)
    def enter_restoration(P, S, mu, theta_k, phi_k):
        """Start the l1 restoration problem at the current x, s (IPOPT's initialisation: p, n
        from (33) so that c - p + n = 0, their multipliers mu_R/p, mu_R/n, y = 0, bound
        multipliers min(rho, z), mu_R = max(mu, ||c||_inf), a fresh filter). The outer filter
        (already holding the current iterate) and regularisation are stashed for the return."""
        it = S.it
        rows = ~P.free
        rho = o.resto_penalty_parameter
        c0 = jnp.where(rows, constr_resid(P, S.ev.g, it.s), 0.0)
        inf0 = jnp.max(jnp.abs(c0), initial=0.0)
        mu_r = jnp.maximum(mu, inf0)
        a = mu_r / (2.0 * rho) - 0.5 * c0
        nv = a + jnp.sqrt(a * a + c0 * mu_r / (2.0 * rho))
        pv = c0 + nv
        nv, pv = jnp.where(rows, nv, 1.0), jnp.where(rows, pv, 1.0)
        R = Resto(on=jnp.ones((), bool), fresh=jnp.ones((), bool), p=pv, n=nv, zp=jnp.where(rows, mu_r / pv, 0.0),
                  zn=jnp.where(rows, mu_r / nv, 0.0), xR=it.x,
                  dr=jnp.where(P.fixed, 0.0, 1.0 / jnp.maximum(1.0, jnp.abs(it.x)) ** 2),
                  s0=it.s, z0=(it.zl, it.zu, it.vl, it.vu), mu_orig=mu, theta_ref=theta_k, phi_ref=phi_k,
                  inf_ref=inf0, outer=S.gl)
        it_r = Iterate(it.x, it.s, jnp.zeros(m), jnp.minimum(rho, it.zl), jnp.minimum(rho, it.zu),
                       jnp.minimum(rho, it.vl), jnp.minimum(rho, it.vu))
        return S._replace(it=it_r, rs=R, mu=mu_r, n_acceptable=jnp.zeros((), jnp.int32),
                          gl=fresh_globalization(o.filter_size, o.theta_min_fact, o.resto_theta_max_fact))

    def restoration_done(P, R, f, g, x, s):
        """IPOPT's return test: the original infeasibility reduced by kappa_resto and the point
        acceptable to the outer filter and to the iterate where the restoration started."""
        c = constr_resid(P, g, s)
        inf = jnp.max(jnp.abs(c), initial=0.0)
        theta = jnp.sum(jnp.abs(c))
        phi = barrier_phi(P, f, x, s, R.mu_orig)
        in_filter = filter_ok(R.outer, theta, phi) & jnp.isfinite(phi)
        progress = (theta <= (1 - o.gamma_theta) * R.theta_ref) | (phi <= R.phi_ref - o.gamma_phi * R.theta_ref)
        enough = inf <= jnp.maximum(o.kappa_resto * R.inf_ref, jnp.minimum(o.tol, o.constr_viol_tol))
        return enough & in_filter & progress

    def leave_restoration(P, S):
        """Back to the original problem at the restoration's x, s: the bound multipliers take one
        Newton step for complementarity, as if the whole restoration had been one primal step
        (reset to 1 if any exceeds bound_mult_reset_threshold), and y = 0 (IPOPT's defaults)."""
        R, it = S.rs, S.it
        mu = R.mu_orig
        tau = jnp.maximum(o.tau_min, 1.0 - mu)
        old = slacks(P, R.xR, R.s0)
        new = slacks(P, it.x, it.s)
        masks = (P.hxl, P.hxu, P.hsl, P.hsu)
        dz = [jnp.where(msk, ((a - b) * z + mu) / a - z, 0.0) for z, a, b, msk in zip(R.z0, old, new, masks)]
        a_du = jnp.min(jnp.stack([frac_dual(z, d, msk, tau) for z, d, msk in zip(R.z0, dz, masks)]))
        z = [z0 + a_du * d for z0, d in zip(R.z0, dz)]
        too_big = jnp.max(jnp.stack([jnp.max(jnp.abs(v), initial=0.0) for v in z])) > o.bound_mult_reset_threshold
        z = [jnp.where(too_big, jnp.where(msk, 1.0, 0.0), v) for v, msk in zip(z, masks)]
        it_o = Iterate(it.x, it.s, jnp.zeros(m), *z)
        return S._replace(it=it_o, rs=resto_off(R), mu=mu, gl=R.outer, n_acceptable=jnp.zeros((), jnp.int32))

    # ---------------------------------------------------------------- one IPM iteration
    def iteration(P, S):
        it, ev, R = S.it, S.ev, S.rs
        resto = R.on
        rr = resto & ~P.free
        rho = o.resto_penalty_parameter

        # barrier parameter update (7), possibly several times; not in the first iteration
        # of a restoration phase (IPOPT)
        mu_min = mu_floor(P)

        def mu_cond(c):
            mu, cnt, force = c
            return (((errors(P, it, ev, mu, R)["Emu"] <= o.kappa_eps * mu) | force) & (mu > mu_min * (1 + 1e-12))
                    & (cnt < 20) & ~R.fresh)

        def mu_body(c):
            mu, cnt, _ = c
            return jnp.maximum(mu_min, jnp.minimum(o.kappa_mu * mu, mu ** o.theta_mu)), cnt + 1, jnp.zeros((), bool)

        mu, nupd, _ = lax.while_loop(mu_cond, mu_body, (S.mu, jnp.zeros((), jnp.int32), (S.tiny_count > 0) & ~resto))
        S = lax.cond(nupd > 0, filter_reset, lambda s_: s_, S)
        tau = jnp.maximum(o.tau_min, 1.0 - mu)

        # search direction with inertia correction; in the restoration phase the Hessian
        # is the constraints' part plus the proximity term eta * diag(dr)
        Wvals = hessian(P, it.x, it.y, resto)
        sig_x, sig_s = sigmas(P, it)
        prox = prox_weight(R, mu)
        sig_p = jnp.where(rr, R.zp / R.p, 0.0)
        sig_n = jnp.where(rr, R.zn / R.n, 0.0)
        A, B, fac, invs, ok_step, dw, dc, dw_last, n_fact, pert = inertia_corrected_factor(
            P, rr, Wvals, ev.jac, sig_x + prox, sig_s, sig_p, sig_n, S.gl.dw_last, mu, S.gl.pert)
        gx, gs = barrier_grad(P, jnp.where(resto, prox * (it.x - R.xR), ev.grad), it.x, it.s, mu)
        gp = jnp.where(rr, rho - mu / R.p + KAPPA_D * mu, 0.0)
        gn = jnp.where(rr, rho - mu / R.n + KAPPA_D * mu, 0.0)
        rx = gx + jt_mult(ev.jac, it.y)
        rs = jnp.where(P.hsl | P.hsu, gs - it.y, 0.0)
        rp = jnp.where(rr, gp - it.y, 0.0)
        rn = jnp.where(rr, gn + it.y, 0.0)
        c = resto_resid(P, R, ev.g, it.s, R.p, R.n)
        dx, ds, dy, dp, dn, res_ratio = solve_reduced(P, A, B, fac, invs, rx, rs, rp, rn, c)
        finite_step = jnp.all(jnp.isfinite(dx)) & jnp.all(jnp.isfinite(dy))
        ok_step = ok_step & finite_step

        # filter line search
        theta_k, phi_k = merit(P, R, ev.f, ev.g, it.x, it.s, R.p, R.n, mu)
        gd = jnp.dot(gx, dx) + jnp.dot(gs, ds) + jnp.dot(gp, dp) + jnp.dot(gn, dn)
        def step_max(dx_, ds_, dp_, dn_):
            """Fraction to the boundary (15) for x, s and, in the restoration phase, p, n."""
            return jnp.minimum(frac_to_boundary(P, it.x, it.s, dx_, ds_, tau),
                               jnp.minimum(frac_dual(R.p, dp_, rr, tau), frac_dual(R.n, dn_, rr, tau)))

        amax = step_max(dx, ds, dp, dn)
        gd_neg = gd < 0
        mgd = jnp.where(gd_neg, -gd, 1.0)
        a_min = o.alpha_min_frac * jnp.where(
            gd_neg,
            jnp.where(theta_k <= S.gl.theta_min,
                      jnp.minimum(o.gamma_theta, jnp.minimum(o.gamma_phi * theta_k / mgd, o.delta * theta_k ** o.s_theta / mgd ** o.s_phi)),
                      jnp.minimum(o.gamma_theta, o.gamma_phi * theta_k / mgd)),
            o.gamma_theta)

        # the watchdog: starts after enough shortened steps; while it is on, trial points are
        # judged against the point where it started
        W = S.wd
        W = W._replace(count=jnp.where(nupd > 0, 0, W.count), on=W.on & (nupd == 0))
        start_wd = ((~W.on) & (~resto) & (W.count >= o.watchdog_shortened_iter_trigger)
                    & (o.watchdog_shortened_iter_trigger > 0) & (~W.skip_first))
        in_wd = W.on | start_wd
        theta_ref = jnp.where(W.on, W.theta, theta_k)
        phi_ref = jnp.where(W.on, W.phi, phi_k)
        gd_ref = jnp.where(W.on, W.gd, gd)
        gd_ref_neg = gd_ref < 0
        mgd_ref = jnp.where(gd_ref_neg, -gd_ref, 1.0)

        def switching(a):
            return gd_ref_neg & (a * mgd_ref ** o.s_phi > o.delta * theta_ref ** o.s_theta)

        def acceptable(a, theta_t, phi_t):
            """(accepted, filter not augmented): the Armijo test applies when theta_ref <= theta_min
            and the switching condition (19) holds; as in IPOPT's implementation, the filter is
            left alone whenever the switching condition and Armijo hold, whatever theta_ref."""
            sw = switching(a)
            armijo = phi_t <= phi_ref + o.eta_phi * a * gd_ref
            suff = (theta_t <= (1 - o.gamma_theta) * theta_ref) | (phi_t <= phi_ref - o.gamma_phi * theta_ref)
            return filter_ok(S.gl, theta_t, phi_t) & jnp.where((theta_ref <= S.gl.theta_min) & sw, armijo, suff), sw & armijo

        tiny = jnp.max(jnp.abs(dx) / (1.0 + jnp.abs(it.x)), initial=0.0) < 10 * EPS
        tiny = tiny & (jnp.max(jnp.abs(ds) / (1.0 + jnp.abs(it.s)), initial=0.0) < 10 * EPS) & ok_step & ~resto

        def trial(a, dx_, ds_, dp_, dn_):
            return trial_eval(P, R, it.x + a * dx_, it.s + a * ds_, R.p + a * dp_, R.n + a * dn_, mu)

        # first trial at alpha_max
        f1, g1, s1, th1, ph1 = trial(amax, dx, ds, dp, dn)
        acc1, ft1 = acceptable(amax, th1, ph1)
        acc1 = (acc1 | tiny) & ~W.skip_first

        # second-order corrections (Sec. 2.4), only if the first trial did not reduce theta
        class SOC(NamedTuple):
            p: jax.Array
            csoc: jax.Array
            theta_old: jax.Array
            active: jax.Array
            acc: jax.Array
            ftype: jax.Array
            a: jax.Array
            d: tuple
            f: jax.Array
            g: jax.Array
            s: jax.Array

        soc0 = SOC(jnp.zeros((), jnp.int32), amax * c + resto_resid(P, R, g1, s1, R.p + amax * dp, R.n + amax * dn), th1,
                   (~acc1) & (th1 >= theta_k) & ok_step & (o.max_soc > 0) & ~in_wd & ~W.skip_first,
                   jnp.zeros((), bool), jnp.zeros((), bool), amax, (dx, ds, dy, dp, dn), f1, g1, s1)

        def soc_body(Q):
            d_s = solve_reduced(P, A, B, fac, invs, rx, rs, rp, rn, Q.csoc)[:5]
            a_s = step_max(d_s[0], d_s[1], d_s[3], d_s[4])
            ft, gt, stt, tht, pht = trial(a_s, d_s[0], d_s[1], d_s[3], d_s[4])
            acc, ftype = acceptable(amax, tht, pht)
            p = Q.p + 1
            cont = (~acc) & (p < o.max_soc) & (tht <= o.kappa_soc * Q.theta_old)
            csoc = a_s * Q.csoc + resto_resid(P, R, gt, stt, R.p + a_s * d_s[3], R.n + a_s * d_s[4])
            return SOC(p, csoc, tht, cont, acc, ftype, a_s, d_s, ft, gt, stt)

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

        start_bt = (~acc1) & (~soc.acc) & ok_step & ~in_wd
        ls0 = LS(0.5 * amax, jnp.ones((), jnp.int32), jnp.zeros((), bool), jnp.zeros((), bool), f1, g1, s1,
                 (0.5 * amax < a_min) & start_bt)

        def ls_cond(L):
            return start_bt & (~L.acc) & (~L.fail)

        def ls_body(L):
            ft, gt, stt, tht, pht = trial(L.a, dx, ds, dp, dn)
            acc, ftype = acceptable(L.a, tht, pht)
            a_next = 0.5 * L.a
            fail = (~acc) & ((a_next < a_min) | (L.t + 1 >= o.max_ls_trials))
            return LS(jnp.where(acc, L.a, a_next), L.t + 1, acc, ftype, ft, gt, stt, fail)

        ls = lax.while_loop(ls_cond, ls_body, ls0)

        # watchdog outcome: an acceptable full step ends it; otherwise the full step is taken
        # tentatively, or, after watchdog_trial_iter_max of them, the iterate goes back
        wd_fail = in_wd & ok_step & ~acc1
        wd_trials = W.trials + 1
        wd_reset = wd_fail & (wd_trials > o.watchdog_trial_iter_max)
        wd_tentative = wd_fail & ~wd_reset

        # choose the accepted trial
        use_soc = (~acc1) & soc.acc
        use_bt = (~acc1) & (~soc.acc) & ls.acc
        accepted = ok_step & (acc1 | soc.acc | ls.acc | wd_tentative)
        a_pr = jnp.where(acc1 | wd_tentative, amax, jnp.where(use_soc, soc.a, ls.a))
        ftype = jnp.where(acc1, ft1, jnp.where(use_soc, soc.ftype, ls.ftype)) | tiny | wd_tentative
        DX, DS, DY, DP, DN = (jnp.where(use_soc, a_, b_) for a_, b_ in zip(soc.d, (dx, ds, dy, dp, dn)))
        f_new = jnp.where(acc1, f1, jnp.where(use_soc, soc.f, ls.f))
        g_new = jnp.where(acc1, g1, jnp.where(use_soc, soc.g, ls.g))
        n_trials = 1 + soc.p + jnp.where(use_bt | (~accepted), ls.t - 1, 0)

        dzl, dzu, dvl, dvu = dual_steps(P, it, DX, DS, mu)
        dzp = jnp.where(rr, (mu - R.zp * R.p - R.zp * DP) / R.p, 0.0)
        dzn = jnp.where(rr, (mu - R.zn * R.n - R.zn * DN) / R.n, 0.0)
        a_du = jnp.min(jnp.stack([frac_dual(it.zl, dzl, P.hxl, tau), frac_dual(it.zu, dzu, P.hxu, tau),
                                  frac_dual(it.vl, dvl, P.hsl, tau), frac_dual(it.vu, dvu, P.hsu, tau),
                                  frac_dual(R.zp, dzp, rr, tau), frac_dual(R.zn, dzn, rr, tau)]))
        x_n = it.x + a_pr * DX
        s_n = it.s + a_pr * DS
        s_n = jnp.where(P.free, g_new, jnp.where(P.eq, P.gl, s_n))
        y_n = it.y + a_pr * DY
        zl, zu, vl, vu = kappa_sigma_reset(P, x_n, s_n, it.zl + a_du * dzl, it.zu + a_du * dzu,
                                           it.vl + a_du * dvl, it.vu + a_du * dvu, mu)
        p_n = jnp.where(rr, R.p + a_pr * DP, R.p)
        n_n = jnp.where(rr, R.n + a_pr * DN, R.n)
        R_acc = R._replace(fresh=jnp.zeros((), bool), p=p_n, n=n_n, zp=clip_mult(R.zp + a_du * dzp, p_n, rr, mu),
                           zn=clip_mult(R.zn + a_du * dzn, n_n, rr, mu))
        S_acc = lax.cond(ftype, lambda s_: s_, lambda s_: filter_add(s_, theta_ref, phi_ref), S)
        S_acc = S_acc._replace(it=Iterate(x_n, s_n, y_n, zl, zu, vl, vu), rs=R_acc)

        # a failed line search at an acceptable point stops there ("Solved_To_Acceptable_Level",
        # as IPOPT); otherwise it starts the restoration phase, which counts its
        # iterations as IPOPT does. A failed line search inside the restoration phase ends it.
        ls_failed = ~accepted & ~wd_reset      # includes a failed inertia correction (IC-6)
        stop_acceptable = ls_failed & S.cur_acc & ~resto
        start_resto = ls_failed & ~S.cur_acc & ~resto
        resto_failed = ls_failed & resto
        # an accepted step changes the iterate, the restoration variables and the filter only
        S_next = S._replace(**{f: jax.tree.map(lambda a_, b_: jnp.where(accepted, a_, b_), getattr(S_acc, f), getattr(S, f))
                               for f in ("it", "rs", "gl")})
        S_next = lax.cond(start_resto, lambda s_: enter_restoration(P, filter_add(s_, theta_k, phi_k), mu, theta_k, phi_k),
                          lambda s_: s_._replace(mu=mu), S_next)
        back = accepted & resto & restoration_done(P, R, f_new, g_new, x_n, s_n)
        S_next = lax.cond(back, lambda s_: leave_restoration(P, s_), lambda s_: s_, S_next)
        x_next = S_next.it.x
        f_next = jnp.where(accepted, f_new, ev.f)
        g_next = jnp.where(accepted, g_new, ev.g)
        grad_n, jac_n = derivs(P, x_next)
        ev_next = Evals(f_next, g_next, grad_n, jac_n)

        # a failed restoration falls back to the last acceptable iterate; a failed watchdog to
        # the point where it started
        rollback = resto_failed & S.has_acc
        it_next = jax.tree.map(lambda a_, b_: jnp.where(rollback, a_, b_), S.acc_it, S_next.it)
        ev_next = jax.tree.map(lambda a_, b_: jnp.where(rollback, a_, b_), S.acc_ev, ev_next)
        it_next = jax.tree.map(lambda a_, b_: jnp.where(wd_reset, a_, b_), W.it, it_next)
        ev_next = jax.tree.map(lambda a_, b_: jnp.where(wd_reset, a_, b_), W.ev, ev_next)
        shortened = accepted & ~in_wd & ~resto & (a_pr < amax)
        W_next = Watchdog(
            count=jnp.where(shortened, W.count + 1, 0).astype(jnp.int32),
            on=wd_tentative & ~start_resto,
            trials=jnp.where(wd_tentative, wd_trials, 0).astype(jnp.int32),
            it=jax.tree.map(lambda a_, b_: jnp.where(start_wd, a_, b_), it, W.it),
            ev=jax.tree.map(lambda a_, b_: jnp.where(start_wd, a_, b_), ev, W.ev),
            theta=jnp.where(start_wd, theta_k, W.theta), phi=jnp.where(start_wd, phi_k, W.phi),
            gd=jnp.where(start_wd, gd, W.gd), skip_first=wd_reset)
        status = jnp.where(stop_acceptable | rollback, 2,
                           jnp.where(resto_failed, jnp.where(ok_step, 5, 6), 0)).astype(jnp.int32)
        kind = jnp.where(start_resto, ord("R"),
                         jnp.where(tiny, ord("s"), jnp.where(wd_tentative, ord("w"), jnp.where(wd_reset, ord("W"),
                                   jnp.where(use_soc, jnp.where(ftype, ord("F"), ord("H")),
                                             jnp.where(ftype, ord("f"), ord("h")))))))
        tiny_count = jnp.where(tiny, S.tiny_count + 1, 0).astype(jnp.int32)
        # ||d|| as IPOPT's log: the primal step (x, s and, in the restoration phase, p and n)
        d_norm = jnp.max(jnp.stack([jnp.max(jnp.abs(v), initial=0.0) for v in (DX, DS, DP, DN)]))
        step_info = dict(mu=mu, d_norm=d_norm,
                         reg=dw, alpha_du=jnp.where(accepted, a_du, 0.0), alpha_pr=jnp.where(accepted, a_pr, 0.0),
                         ls=n_trials, kind=kind, resto_iters=S.resto_iters + resto.astype(jnp.int32),
                         n_fact=n_fact, mode=resto.astype(jnp.int32), res_ratio=res_ratio)
        S_next = S_next._replace(it=it_next, ev=ev_next, tiny_count=tiny_count, wd=W_next,
                                 resto_iters=S.resto_iters + resto.astype(jnp.int32), k=S.k + 1)
        # the regularisation history belongs to the problem being solved (IPOPT's restoration
        # phase has its own); entering and leaving the restoration set it themselves
        upd = (~resto & ~start_resto) | (resto & S_next.rs.on)
        S_next = S_next._replace(gl=S_next.gl._replace(dw_last=jnp.where(upd, dw_last, S_next.gl.dw_last),
                                                       pert=jnp.where(upd, pert, S_next.gl.pert)))
        return S_next, status, step_info

    # ---------------------------------------------------------------- termination + history
    def record_and_check(P, S, step_info, status):
        err = errors(P, S.it, S.ev, S.mu, S.rs)
        k = S.k
        resto = S.rs.on
        conv = ((err["E0"] <= o.tol) & (err["pr_u"] <= o.constr_viol_tol) & (err["du_u"] <= o.dual_inf_tol)
                & (err["co_u"] <= o.compl_inf_tol)) & ~resto
        acc_pt = ((err["E0"] <= o.acceptable_tol) & (err["pr_u"] <= o.acceptable_constr_viol_tol)
                  & (err["du_u"] <= o.acceptable_dual_inf_tol) & (err["co_u"] <= o.acceptable_compl_inf_tol))
        n_acc = jnp.where(acc_pt, S.n_acceptable + 1, 0).astype(jnp.int32)
        # the restoration problem itself converged (or stalled at an acceptable point) without
        # reaching a point the outer filter accepts: local infeasibility, unless it is feasible
        resto_conv = resto & ((err["E0"] <= o.tol) | ((n_acc >= o.acceptable_iter) & (o.acceptable_iter > 0)))
        resto_code = jnp.where(err["pr_s"] > 1e2 * o.tol, 4, 5)
        finite = jnp.isfinite(S.ev.f) & jnp.all(jnp.isfinite(S.ev.g)) & jnp.all(jnp.isfinite(S.ev.grad)) & jnp.all(jnp.isfinite(S.ev.jac))
        tiny_stop = (S.tiny_count >= 2) & (S.mu <= mu_floor(P) * 1.0000001)
        new_status = jnp.where(
            status != 0, status,
            jnp.where(~finite, 7,
                      jnp.where(conv, 1,
                                jnp.where(resto_conv, resto_code,
                                          jnp.where((n_acc >= o.acceptable_iter) & (o.acceptable_iter > 0) & ~resto, 2,
                                                    jnp.where(tiny_stop, jnp.where(acc_pt, 2, 8),
                                                              jnp.where((k >= o.max_iter) | (S.resto_iters > o.max_resto_iter), 3, 0)))))))
        hist = S.hist
        if o.keep_history:
            row = dict(obj=S.ev.f / P.sf, inf_pr=err["pr_u"], inf_du=err["dual"], compl=err["compl"], **step_info)
            hist = {key: hist[key].at[k].set(jnp.asarray(row[key]).astype(hist[key].dtype)) for key in HIST_FIELDS}
        new_status = new_status.astype(jnp.int32)
        keep = acc_pt & finite & ~resto
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
        # IPOPT's bound_relax_factor: finite variable and inequality bounds are relaxed by
        # factor * max(1, |bound|); like IPOPT 3.14 (honor_original_bounds = no) the final x is
        # not projected back, which would break the stationarity of the returned multipliers
        rf = o.bound_relax_factor

        def relax(b, mask, sign):
            return jnp.where(mask, b + sign * rf * jnp.maximum(1.0, jnp.abs(b)), b)

        xl, xu = relax(xl, hxl, -1.0), relax(xu, hxu, 1.0)
        gl, gu = relax(gl, hsl, -1.0), relax(gu, hsu, 1.0)
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
        zm, zn_ = jnp.zeros(m), jnp.zeros(n)
        z0 = jnp.zeros(())
        resto0 = resto_off(Resto(z0 > 0, z0 > 0, zm, zm, zm, zm, zn_, zn_, zm, (zn_, zn_, zm, zm), z0, z0, z0, z0,
                                 fresh_globalization(o.filter_size, 0.0, 0.0)))
        hist = {key: jnp.zeros(H if o.keep_history else 1, dtype=jnp.int32 if key in INT_FIELDS else float)
                for key in HIST_FIELDS}
        S = State(it=it, ev=ev, mu=jnp.asarray(o.mu_init, float), k=jnp.zeros((), jnp.int32),
                  done=jnp.zeros((), bool), status=jnp.zeros((), jnp.int32),
                  gl=fresh_globalization(o.filter_size, o.theta_min_fact * jnp.maximum(1.0, theta0),
                                         o.theta_max_fact * jnp.maximum(1.0, theta0)),
                  n_acceptable=jnp.zeros((), jnp.int32), tiny_count=jnp.zeros((), jnp.int32),
                  resto_iters=jnp.zeros((), jnp.int32), hist=hist, rs=resto0,
                  wd=Watchdog(jnp.zeros((), jnp.int32), z0 > 0, jnp.zeros((), jnp.int32), it, ev, z0, z0, z0, z0 > 0),
                  cur_acc=jnp.zeros((), bool), acc_it=it, acc_ev=ev, has_acc=jnp.zeros((), bool))
        info0 = dict(mu=S.mu, d_norm=jnp.zeros(()), reg=jnp.zeros(()), alpha_du=jnp.zeros(()),
                     alpha_pr=jnp.zeros(()), ls=jnp.zeros((), jnp.int32), kind=jnp.zeros((), jnp.int32),
                     resto_iters=jnp.zeros((), jnp.int32), n_fact=jnp.zeros((), jnp.int32),
                     mode=jnp.zeros((), jnp.int32), res_ratio=jnp.zeros(()))
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
