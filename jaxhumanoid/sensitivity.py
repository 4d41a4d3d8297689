"""Parametric sensitivities of an optimal solution x*(p) by implicit differentiation of the KKT
conditions at a converged IPOPT point (issue 7).

IPOPT's conventions (cyipopt): the Lagrangian is

    L(x, lam, z; p) = f(x, p) + lam . g(x, p) - z_l . (x - xl) + z_u . (x - xu),   z_l, z_u >= 0

and stationarity reads grad f + J^T lam - z_l + z_u = 0. A constraint with only a lower bound
(g_j >= gl_j) that is active has lam_j <= 0; one at its upper bound has lam_j >= 0.

Active set. A bound or inequality is *active* when its multiplier exceeds its slack (at an
interior-point solution with barrier mu, multiplier * slack ~ mu, so exactly one of the two is
O(mu) when strict complementarity holds). Active variable bounds fix the variable (index set B;
the rest is F); active inequalities join the equalities (row set C). Strict complementarity is
checked: every active multiplier must be above ``sc_tol`` and every inactive slack above
``sc_tol`` (a pair with both small is *weakly active*: x*(p) is then only directionally
differentiable and the sensitivities below are those of the fixed active set). A warning is
issued when it fails.

Two degeneracies of this transcription are handled explicitly. (i) Under scheme A the bounds of
the contact-force variables are implied by the contact-law equalities (``implied_bounds``) and are
never taken as active (for a contact in the air IPOPT reports barrier artefacts z_l = mu/1e-8
there). (ii) LICQ fails at foot lift-off (all five steady-foot constraints active with a vanishing
foot reaction): active inequality rows whose gradients depend on the others are dropped
(``_dependent_active_rows``: a sparse projection onto the null space of the equality rows, then a
small dense pivoted QR) and their first-order consistency is reported
(``KKTSensitivity.dropped_residual``).

Reduced KKT system (second-order sufficiency + LICQ make it nonsingular):

    [ H_FF   J_CF^T ] [ dx_F   ]     [ d_p(grad_x L)_F dp + H_FB dx_B ]
    [ J_CF   0      ] [ dlam_C ] = - [ d_p g_C dp       + J_CB dx_B   ]

with H the Hessian of the Lagrangian (``nlp.hess_values``, sigma = 1), J = dg/dx
(``nlp.jac_values``) and dx_B the motion of the active bounds (non-zero only for the goal box,
see below). The right-hand side is a forward-over-reverse JVP of grad_x (f + lam . g) with
respect to p at fixed (x, lam). The adjoint (VJP) solves the same symmetric system with
right-hand side (ct_F, 0) and pulls the solution back through p by one reverse-mode gradient.

Goal posture: the goal enters the *bounds* (the terminal box goal +- GOAL_TOLERANCE), not p.
``goal`` tangents are handled as bound tangents: an active goal-box bound moves with the goal
(dx_B = dgoal for those entries), inactive ones do not matter. The horizon T and the start
posture q_start are ordinary leaves of p.

Optimal value: by the envelope theorem dV/dp = d_p L(x*, lam*; p) (no solve needed) and
dV/dgoal = z_l . dxl/dgoal - z_u . dxu/dgoal; ``objective_gradient`` gives it, and the chain
rule through the JVP (``objective_jvp``) is an independent check.

JAX: ``make_solve(problem)`` returns ``solve(p) -> x*`` wrapped in ``jax.custom_vjp`` around an
IPOPT solve called with ``jax.pure_callback``, so ``jax.grad(lambda p: loss(solve(p)))`` works for
every differentiable leaf of p (weights, contact, model, T, q_start).

Checks: ``check_against_fd`` compares, per parameter group, dx* and dV* with central differences
of warm-started re-solves (2-norm relative error below ``FD_TOL`` = 1e-4) and records how far a
wrong sign, a missed active set and flipped multipliers miss the same differences;
``sensitivity_table`` gives the rows of ``jaxhumanoid check --sensitivities``.

Inverse optimal control: ``WeightFit`` recovers the cost-weight ratios from an optimal trajectory
by Gauss-Newton (JVPs) or L-BFGS (``jax.grad`` through ``make_solve``), every solve continued
along the data's branch of local optima (``continuation_solve``).
"""

from __future__ import annotations

import dataclasses
import functools
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from jaxhumanoid.ocp import tasks as tasks_mod
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.nlp import Bounds


class StrictComplementarityWarning(UserWarning):
    """A bound or inequality is weakly active: multiplier and slack are both (near) zero."""


# ----------------------------------------------------------------------------------------------
# Active set


@dataclasses.dataclass(frozen=True)
class ActiveSet:
    """Active constraints at a KKT point.

    lower/upper: (n,) variables at their lower/upper bound (fixed in the reduced system);
    rows: (m,) constraint rows in the reduced system (equalities + active inequalities);
    ineq_active: (m,) active inequalities (subset of rows); weak_x, weak_g: weakly active pairs;
    min_active_multiplier: smallest multiplier among active bounds/inequalities;
    min_inactive_slack: smallest slack among inactive bounds/inequalities;
    sc_tol: the threshold used.
    """

    lower: np.ndarray
    upper: np.ndarray
    rows: np.ndarray
    ineq_active: np.ndarray
    weak_x: np.ndarray
    weak_g: np.ndarray
    min_active_multiplier: float
    min_inactive_slack: float
    sc_tol: float

    @property
    def fixed(self) -> np.ndarray:
        return self.lower | self.upper

    @property
    def free(self) -> np.ndarray:
        return ~self.fixed

    @property
    def strict(self) -> bool:
        return not (self.weak_x.any() or self.weak_g.any())

    def summary(self) -> dict:
        return {
            "n_lower": int(self.lower.sum()),
            "n_upper": int(self.upper.sum()),
            "n_rows": int(self.rows.sum()),
            "n_active_ineq": int(self.ineq_active.sum()),
            "n_weak": int(self.weak_x.sum() + self.weak_g.sum()),
            "strict_complementarity": bool(self.strict),
            "min_active_multiplier": self.min_active_multiplier,
            "min_inactive_slack": self.min_inactive_slack,
            "sc_tol": self.sc_tol,
        }


def implied_bounds(problem) -> np.ndarray:
    """(n,) variables whose box bounds are implied by equality constraints and never active.

    Under scheme A the contact-force variables equal the contact law (f = f_law(q, qd)), whose
    normal force is > 0 and whose friction force is bounded by mu f_n: the bounds f_n >= 0 and
    |f| <= CONTACT_FORCE_LIMIT are redundant. For a contact in the air f_law is ~1e-40, i.e. at
    the bound f_n >= 0 within IPOPT's bound relaxation, and IPOPT reports z_l = mu / 1e-8 there
    (a barrier artefact that vanishes as mu -> 0, not an active bound); treating such a bound
    as active makes the reduced KKT matrix singular (the law row loses all free entries).
    """
    layout = problem.layout
    mask = np.zeros((layout.N + 1, layout.s), dtype=bool)
    if layout.augmented:
        mask[:, 15:] = True
    return mask[layout.free_mask()]


def identify_active_set(bounds: Bounds, x, g_val, lam_g, z_l, z_u, sc_tol: float = 1e-6, warn: bool = True, ignore_bounds=None) -> ActiveSet:
    """Active bounds and inequalities from IPOPT's multipliers and slacks (see module doc).

    ``ignore_bounds``: (n,) mask of variables whose bounds are known to be redundant
    (``implied_bounds``); they are never active.
    """
    x, g_val, lam_g = np.asarray(x), np.asarray(g_val), np.asarray(lam_g)
    z_l, z_u = np.asarray(z_l), np.asarray(z_u)
    inf = np.inf
    keep = np.ones(x.shape, dtype=bool) if ignore_bounds is None else ~np.asarray(ignore_bounds, dtype=bool)

    def side(finite, mult, slack):
        mult = np.where(finite, np.maximum(mult, 0.0), 0.0)
        slack = np.where(finite, np.maximum(slack, 0.0), inf)
        active = finite & (mult > slack)
        weak = finite & (np.maximum(mult, slack) < sc_tol)
        return active, weak, mult, slack

    lo_a, lo_w, lo_m, lo_s = side(np.isfinite(bounds.xl) & keep, z_l, x - bounds.xl)
    up_a, up_w, up_m, up_s = side(np.isfinite(bounds.xu) & keep, z_u, bounds.xu - x)
    eq = np.isfinite(bounds.gl) & (bounds.gl == bounds.gu)
    gl_fin = np.isfinite(bounds.gl) & ~eq
    gu_fin = np.isfinite(bounds.gu) & ~eq
    gl_a, gl_w, gl_m, gl_s = side(gl_fin, -lam_g, g_val - bounds.gl)
    gu_a, gu_w, gu_m, gu_s = side(gu_fin, lam_g, bounds.gu - g_val)
    ineq = gl_a | gu_a
    mults = np.concatenate([lo_m[lo_a], up_m[up_a], gl_m[gl_a], gu_m[gu_a]])
    lo_fin, up_fin = np.isfinite(bounds.xl) & keep, np.isfinite(bounds.xu) & keep
    slacks = np.concatenate([lo_s[lo_fin & ~lo_a], up_s[up_fin & ~up_a], gl_s[gl_fin & ~gl_a], gu_s[gu_fin & ~gu_a]])
    act = ActiveSet(
        lower=lo_a,
        upper=up_a,
        rows=eq | ineq,
        ineq_active=ineq,
        weak_x=lo_w | up_w,
        weak_g=gl_w | gu_w,
        min_active_multiplier=float(mults.min()) if mults.size else inf,
        min_inactive_slack=float(slacks.min()) if slacks.size else inf,
        sc_tol=float(sc_tol),
    )
    if warn and not act.strict:
        warnings.warn(
            f"strict complementarity fails: {int(act.weak_x.sum())} bounds and {int(act.weak_g.sum())} inequalities "
            f"are weakly active (multiplier and slack both < {sc_tol:g}; variables {np.flatnonzero(act.weak_x)[:10]}, "
            f"constraints {np.flatnonzero(act.weak_g)[:10]}): x*(p) is only directionally differentiable there and "
            "the sensitivities are those of the identified active set",
            StrictComplementarityWarning,
            stacklevel=3,
        )
    return act


# ----------------------------------------------------------------------------------------------
# JAX pieces: jitted once per NLP (a static argument, hashed by identity), as in solvers.ipopt


def _grad_lag(nlp, x, lam, p):
    return jax.grad(lambda xx: nlp.f(xx, p) + jnp.dot(lam, nlp.g(xx, p)))(x)


_grad_lag_jit = jax.jit(_grad_lag, static_argnums=0)


@functools.partial(jax.jit, static_argnums=0)
def _rhs_jvp(nlp, x, lam, p, dp):
    """(d_p grad_x L . dp, d_p g . dp) at fixed x, lam."""
    _, (dgl, dg) = jax.jvp(lambda pp: (_grad_lag(nlp, x, lam, pp), nlp.g(x, pp)), (p,), (dp,))
    return dgl, dg


@functools.partial(jax.jit, static_argnums=0)
def _pullback(nlp, x, lam, p, v_x, v_lam):
    """grad_p [v_x . grad_x L + v_lam . g] at fixed x, lam (a pytree like p)."""
    return jax.grad(lambda pp: jnp.dot(v_x, _grad_lag(nlp, x, lam, pp)) + jnp.dot(v_lam, nlp.g(x, pp)))(p)


@functools.partial(jax.jit, static_argnums=0)
def _lag_grad_p(nlp, x, lam, p):
    """Envelope: grad_p L = grad_p f + lam . grad_p g at fixed x, lam."""
    return jax.grad(lambda pp: nlp.f(x, pp) + jnp.dot(lam, nlp.g(x, pp)))(p)


@functools.partial(jax.jit, static_argnums=0)
def _f_jvp(nlp, x, p, dx, dp):
    return jax.jvp(nlp.f, (x, p), (dx, dp))[1]


@functools.partial(jax.jit, static_argnums=(0, 1))
def _call(nlp, name, *args):
    return getattr(nlp, name)(*args)


def _jax_fns(nlp):
    return dict(
        rhs_jvp=functools.partial(_rhs_jvp, nlp),
        pullback=functools.partial(_pullback, nlp),
        lag_grad_p=functools.partial(_lag_grad_p, nlp),
        f_jvp=functools.partial(_f_jvp, nlp),
        grad_lag=functools.partial(_grad_lag_jit, nlp),
        g=functools.partial(_call, nlp, "g"),
        f=functools.partial(_call, nlp, "f"),
        jac=functools.partial(_call, nlp, "jac_values"),
        hess=functools.partial(_call, nlp, "hess_values"),
    )


def _as_float_tree(p):
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.float64), p)


def tree_vdot(a, b) -> float:
    """<a, b> summed over the leaves of two pytrees of the same structure."""
    return float(sum(np.vdot(np.asarray(u), np.asarray(v)) for u, v in zip(jax.tree.leaves(a), jax.tree.leaves(b))))


def zeros_like_params(p):
    return jax.tree.map(lambda a: jnp.zeros_like(jnp.asarray(a, dtype=jnp.float64)), p)


# ----------------------------------------------------------------------------------------------
# Goal as bounds


def goal_bound_jacobians(problem) -> tuple[np.ndarray, np.ndarray]:
    """(n, 5) derivatives dxl/dgoal, dxu/dgoal of the NLP bounds w.r.t. the goal posture.

    The terminal box is max(Q_MIN, goal - tol) .. min(Q_MAX, goal + tol) (``bounds_full``): a
    bound moves with the goal unless it is clipped by the joint range.
    """
    layout, goal = problem.layout, np.asarray(problem.task.goal, dtype=float)
    tol = tasks_mod.GOAL_TOLERANCE
    free = layout.free_mask()
    idx = np.full(free.shape, -1)
    idx[free] = np.arange(free.sum())
    Dl, Du = np.zeros((problem.nlp.n, 5)), np.zeros((problem.nlp.n, 5))
    for j in range(5):
        i = idx[layout.N, j]
        if i >= 0:
            Dl[i, j] = float(goal[j] - tol > tasks_mod.Q_MIN[j])
            Du[i, j] = float(goal[j] + tol < tasks_mod.Q_MAX[j])
    return Dl, Du


def bounds_for_goal(problem, goal) -> Bounds:
    """The problem's bounds with the terminal goal box moved to ``goal``."""
    lo, hi = tr.bounds_full(problem.layout, np.asarray(goal, dtype=float))
    free = problem.layout.free_mask()
    b = problem.bounds
    return Bounds(x0=np.clip(b.x0, lo[free], hi[free]), xl=lo[free], xu=hi[free], gl=b.gl, gu=b.gu)


def _unit_rows(A):
    """Rows of the sparse matrix ``A`` scaled to unit 2-norm (zero rows left as they are)."""
    norms = np.sqrt(np.asarray(A.multiply(A).sum(axis=1)).ravel())
    return sp.diags(1.0 / np.maximum(norms, 1e-300)) @ A


def _dependent_active_rows(J, F, active: ActiveSet, tol: float = 1e-9) -> np.ndarray:
    """Active inequality rows whose gradients (on the free variables) depend linearly on the
    equality rows and on the other active inequalities (LICQ failure), to be dropped.

    Seen at foot lift-off: the five steady-foot constraints (5) are all active when the foot
    reaction vanishes (f_n0 = f_t0 = u_1 = 0) and their gradients span only three directions.
    The dropped rows hold to first order automatically when the linearisation is consistent
    (``KKTSensitivity.dropped_residual`` reports it); their multiplier sensitivities are set to 0.

    The (unit) inequality rows a_i are projected onto the null space of the equality rows A_e by
    one sparse solve, [I A_e^T; A_e 0] [r; y] = [a; 0] (r = a - A_e^T y, A_e r = 0), and the few
    projections r_i go through a dense pivoted QR; rows with a pivot below ``tol`` are dropped.
    Should the equality rows themselves be dependent (a singular sparse system), a dense QR of
    all active rows does the projection instead.
    """
    import scipy.linalg as sla

    ineq = np.flatnonzero(active.ineq_active)
    if ineq.size == 0:
        return np.array([], dtype=np.int64)
    eq = np.flatnonzero(active.rows & ~active.ineq_active)
    JF = J[:, F].tocsr()
    A_i = _unit_rows(JF[ineq])
    if eq.size:
        A_e = _unit_rows(JF[eq])
        try:
            aug = sp.bmat([[sp.identity(F.size), A_e.T], [A_e, None]], format="csc")
            rhs = np.vstack([A_i.toarray().T, np.zeros((eq.size, ineq.size))])
            P = spla.splu(aug).solve(rhs)[: F.size]
        except RuntimeError:  # dependent equality rows
            Q, _ = np.linalg.qr(A_e.toarray().T)
            A_d = A_i.toarray().T
            P = A_d - Q @ (Q.T @ A_d)
    else:
        P = A_i.toarray().T
    _, R, piv = sla.qr(P, mode="economic", pivoting=True)
    d = np.abs(np.diag(R))
    rank = int(np.sum(d > tol * max(1.0, d.max(initial=0.0)))) if d.size else 0
    return np.sort(ineq[piv[rank:]]).astype(np.int64)


# ----------------------------------------------------------------------------------------------
# The factorised reduced KKT system


class KKTSensitivity:
    """Reduced KKT system at a converged point, factorised once; JVPs/VJPs reuse the factors.

    ``KKTSensitivity(problem, result)`` or with explicit ``x, lam_g, z_l, z_u, p, bounds``.
    """

    def __init__(self, problem, result=None, *, x=None, lam_g=None, z_l=None, z_u=None, p=None, bounds=None, sc_tol: float = 1e-6, warn: bool = True, active: ActiveSet | None = None, dep_tol: float = 1e-9):
        t0 = time.perf_counter()
        self.problem = problem
        nlp = problem.nlp
        self.nlp = nlp
        self.p = _as_float_tree(problem.p if p is None else p)
        self.bounds = problem.bounds if bounds is None else bounds
        self.x = np.asarray(result.x if x is None else x, dtype=float)
        self.lam = np.asarray(result.lam_g if lam_g is None else lam_g, dtype=float)
        self.z_l = np.asarray(result.z_l if z_l is None else z_l, dtype=float)
        self.z_u = np.asarray(result.z_u if z_u is None else z_u, dtype=float)
        fns = self.fns = _jax_fns(nlp)
        self.g_val = np.asarray(fns["g"](self.x, self.p))
        self.active = active if active is not None else identify_active_set(self.bounds, self.x, self.g_val, self.lam, self.z_l, self.z_u, sc_tol=sc_tol, warn=warn, ignore_bounds=implied_bounds(problem))
        n, m = nlp.n, nlp.m
        J = sp.csr_matrix((np.asarray(fns["jac"](self.x, self.p)), (nlp.jac_rows, nlp.jac_cols)), shape=(m, n))
        Hl = sp.csr_matrix((np.asarray(fns["hess"](self.x, self.lam, 1.0, self.p)), (nlp.hess_rows, nlp.hess_cols)), shape=(n, n))
        H = (Hl + Hl.T - sp.diags(Hl.diagonal())).tocsr()
        self.J, self.H = J, H
        self.F = np.flatnonzero(self.active.free)
        self.B = np.flatnonzero(self.active.fixed)
        self.dropped = _dependent_active_rows(J, self.F, self.active, dep_tol)
        rows = self.active.rows.copy()
        rows[self.dropped] = False
        self.C = np.flatnonzero(rows)
        JCF = J[self.C][:, self.F]
        self.K = sp.bmat([[H[self.F][:, self.F], JCF.T], [JCF, None]], format="csc")
        self._HFB = H[self.F][:, self.B]
        self._JCB = J[self.C][:, self.B]
        nF, nC = self.F.size, self.C.size
        if nC > nF:
            raise np.linalg.LinAlgError(f"reduced KKT system: {nC} active constraints for {nF} free variables (LICQ fails)")
        try:
            self.lu = spla.splu(self.K)
        except RuntimeError as err:
            raise np.linalg.LinAlgError(
                f"reduced KKT matrix ({self.K.shape[0]}x{self.K.shape[0]}, {nF} free variables, {nC} active constraints) is singular: "
                f"LICQ or second-order sufficiency fails at the identified active set ({err}); redundant bounds may need "
                "to go into ignore_bounds (see implied_bounds)"
            ) from err
        self.factor_time_s = time.perf_counter() - t0
        # Stationarity residual of the KKT point (a check of the multiplier convention).
        gl = np.asarray(fns["grad_lag"](self.x, self.lam, self.p))
        self.dropped_residual = 0.0
        self.stationarity = float(np.max(np.abs(gl - self.z_l + self.z_u))) if n else 0.0

    # -- linear algebra -----------------------------------------------------------------------

    def _solve(self, rhs):
        sol = self.lu.solve(rhs)
        return sol[: self.F.size], sol[self.F.size :]

    def kkt_residual(self, rhs, sol) -> float:
        """Relative residual of a reduced-KKT solve (conditioning check)."""
        r = self.K @ sol - rhs
        return float(np.linalg.norm(r) / max(np.linalg.norm(rhs), 1e-300))

    # -- forward ------------------------------------------------------------------------------

    def jvp(self, dp=None, dgoal=None, return_all: bool = False):
        """dx* for a parameter tangent ``dp`` (pytree like p) and/or goal tangent ``dgoal`` (5,)."""
        n, m = self.nlp.n, self.nlp.m
        if dp is None:
            r_x, r_g = np.zeros(n), np.zeros(m)
        else:
            dgl, dg = self.fns["rhs_jvp"](self.x, self.lam, self.p, _as_float_tree(dp))
            r_x, r_g = np.asarray(dgl), np.asarray(dg)
        dxB = np.zeros(self.B.size)
        if dgoal is not None:
            Dl, Du = goal_bound_jacobians(self.problem)
            dxl, dxu = Dl @ np.asarray(dgoal, float), Du @ np.asarray(dgoal, float)
            dxB = np.where(self.active.lower[self.B], dxl[self.B], dxu[self.B])
        rhs = -np.concatenate([r_x[self.F] + self._HFB @ dxB, r_g[self.C] + self._JCB @ dxB])
        dxF, dlamC = self._solve(rhs)
        dx = np.zeros(n)
        dx[self.F], dx[self.B] = dxF, dxB
        if self.dropped.size:
            # the dropped (dependent) active rows must hold to first order as well
            lin = self.J[self.dropped] @ dx + r_g[self.dropped]
            self.dropped_residual = float(np.max(np.abs(lin)) / max(np.max(np.abs(dx)), 1e-300))
        if return_all:
            dlam = np.zeros(m)
            dlam[self.C] = dlamC
            return dx, dlam
        return dx

    # -- reverse ------------------------------------------------------------------------------

    def adjoint(self, ct_x):
        """(v_x, v_lam) in full length (zeros off F / C): K [v_F; v_C] = [ct_F; 0]."""
        ct_x = np.asarray(ct_x, dtype=float)
        rhs = np.concatenate([ct_x[self.F], np.zeros(self.C.size)])
        vF, vC = self._solve(rhs)
        v_x, v_lam = np.zeros(self.nlp.n), np.zeros(self.nlp.m)
        v_x[self.F], v_lam[self.C] = vF, vC
        return v_x, v_lam

    def vjp(self, ct_x, goal: bool = False):
        """Cotangent of p (pytree like p) for a cotangent ``ct_x`` of x*; with ``goal=True`` also
        the (5,) cotangent of the goal posture."""
        ct_x = np.asarray(ct_x, dtype=float)
        v_x, v_lam = self.adjoint(ct_x)
        dp = jax.tree.map(lambda a: -np.asarray(a), self.fns["pullback"](self.x, self.lam, self.p, v_x, v_lam))
        if not goal:
            return dp
        # total d loss / d x_B: direct + through the reduced system
        ctB = ct_x[self.B] - (self._HFB.T @ v_x[self.F] + self._JCB.T @ v_lam[self.C])
        Dl, Du = goal_bound_jacobians(self.problem)
        D = np.where(self.active.lower[self.B][:, None], Dl[self.B], Du[self.B])
        return dp, D.T @ ctB

    # -- optimal value ------------------------------------------------------------------------

    def objective_gradient(self, goal: bool = False):
        """Envelope theorem: dV/dp = grad_p L(x*, lam*; p) (and dV/dgoal with ``goal=True``)."""
        dp = jax.tree.map(np.asarray, self.fns["lag_grad_p"](self.x, self.lam, self.p))
        if not goal:
            return dp
        Dl, Du = goal_bound_jacobians(self.problem)
        return dp, Dl.T @ self.z_l - Du.T @ self.z_u

    def objective_jvp(self, dp=None, dgoal=None, dx=None) -> float:
        """dV along (dp, dgoal) by the chain rule d_x f . dx* + d_p f . dp (independent of the envelope)."""
        if dx is None:
            dx = self.jvp(dp, dgoal)
        dpp = zeros_like_params(self.p) if dp is None else _as_float_tree(dp)
        return float(self.fns["f_jvp"](self.x, self.p, jnp.asarray(dx), dpp))

    def report(self) -> dict:
        return {**self.active.summary(), "n_dependent_dropped": int(self.dropped.size), "n_free": int(self.F.size), "kkt_size": int(self.K.shape[0]), "stationarity": self.stationarity, "factor_time_s": self.factor_time_s}


# ----------------------------------------------------------------------------------------------
# Functional API


def solution_jvp(problem, result, dp, dgoal=None, **kw) -> np.ndarray:
    """dx* = (dx*/dp) dp (+ dx*/dgoal dgoal) at a converged ``result`` of ``problem``."""
    return KKTSensitivity(problem, result, **kw).jvp(dp, dgoal)


def solution_vjp(problem, result, ct_x, goal: bool = False, **kw):
    """ct_x^T dx*/dp as a pytree like p (and the goal cotangent with ``goal=True``)."""
    return KKTSensitivity(problem, result, **kw).vjp(ct_x, goal=goal)


def objective_gradient(problem, result, goal: bool = False, **kw):
    """dV/dp of the optimal value by the envelope theorem."""
    return KKTSensitivity(problem, result, **kw).objective_gradient(goal=goal)


# ----------------------------------------------------------------------------------------------
# IPOPT with a full primal-dual warm start


WARM_OPTIONS = {
    "warm_start_init_point": "yes",
    "warm_start_bound_push": 1e-12,
    "warm_start_bound_frac": 1e-12,
    "warm_start_slack_bound_push": 1e-12,
    "warm_start_slack_bound_frac": 1e-12,
    "warm_start_mult_bound_push": 1e-12,
    "mu_init": 1e-9,
}


def resolve(problem, p=None, bounds=None, warm=None, options: dict | None = None):
    """IPOPT solve of ``problem`` at parameters ``p`` (default problem.p) and ``bounds``; ``warm`` an
    NLPResult whose x and multipliers warm-start the solve (``WARM_OPTIONS``)."""
    from jaxhumanoid.solvers.ipopt import solve_ipopt

    p = problem.p if p is None else p
    bounds = problem.bounds if bounds is None else bounds
    opts = {**(WARM_OPTIONS if warm is not None else {}), **(options or {})}
    x0 = np.clip(np.asarray(bounds.x0 if warm is None else warm.x, dtype=float), bounds.xl, bounds.xu)
    return solve_ipopt(problem.nlp, p, bounds, x0=x0, options=opts, warm=warm)


def resolve_robust(problem, p=None, bounds=None, warm=None, options: dict | None = None):
    """``resolve`` with fall-backs: primal-dual warm start at mu 1e-9, then at mu 1e-4 (for large
    parameter changes), then a cold start. Returns the first successful result (or the last)."""
    tries = [dict(options or {})]
    if warm is not None:
        tries.append({**(options or {}), "mu_init": 1e-4, "warm_start_bound_push": 1e-6, "warm_start_mult_bound_push": 1e-6})
    res = None
    for opts in tries:
        res = resolve(problem, p=p, bounds=bounds, warm=warm, options=opts)
        if res.success:
            return res
    if warm is not None:
        res = resolve(problem, p=p, bounds=bounds, warm=None, options=options)
    return res


REFERENCE_FALLBACKS = (
    {},
    {"mu_strategy": "adaptive"},
    {"mu_init": 1e-2},
    {"bound_push": 1e-4, "bound_frac": 1e-4},
    {"mu_strategy": "adaptive", "mu_init": 1e-3},
)


def reference_solve(problem, tol: float = 1e-10, max_iter: int = 3000, verbose: bool = False):
    """A tightly converged cold solve for sensitivity work, with option fall-backs.

    Observed: the cold 1S solve of small problems (T1, N = 15) is reproducible within a process
    but not across processes (the same options gave Solve_Succeeded in 99 or 220 iterations, or
    Infeasible_Problem_Detected); the fall-backs make the reference solve robust to that.
    Returns the first successful NLPResult with ``history['attempt']`` set.
    """
    from jaxhumanoid.solvers.ipopt import solve_ipopt

    res = None
    for k, extra in enumerate(REFERENCE_FALLBACKS):
        res = solve_ipopt(problem.nlp, problem.p, problem.bounds, options={"tol": tol, "max_iter": max_iter, **extra})
        if verbose:
            print(f"reference solve attempt {k} {extra}: {res.status}, {res.iterations} its, f = {res.objective:.6g}")
        if res.success:
            res.history = {**(res.history or {}), "attempt": k}
            return res
    raise RuntimeError(f"reference_solve: every attempt failed (last: {res.status})")


def _interpolate(a, b, t: float):
    """Point t in [0, 1] of the path from leaf a to leaf b: geometric where both ends have the
    same strict sign (weights, masses: equal relative changes per sub-step), else linear."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    same = (a * b) > 0
    geo = np.sign(a) * np.abs(a) ** (1 - t) * np.abs(np.where(same, b, a)) ** t
    return np.where(same, geo, a + t * (b - a))


def continuation_solve(problem, p_from, res_from, p_to, max_rel_step: float = 0.25, bounds=None, options: dict | None = None):
    """Follow the branch of local optima through ``res_from`` (at ``p_from``) to ``p_to``.

    The OCP has several local optima; a warm start after a long parameter step can land on
    another branch. The path (``_interpolate``) is cut into k sub-steps so that no leaf of p
    changes by more than a factor ``1 + max_rel_step`` (or, for leaves through zero, by more
    than ``max_rel_step`` of its size) per sub-step, each warm-started from the previous one.
    """
    leaves_a = [np.asarray(a, dtype=float) for a in jax.tree.leaves(p_from)]
    leaves_b = [np.asarray(b, dtype=float) for b in jax.tree.leaves(p_to)]
    if not max_rel_step > 0:
        raise ValueError(f"max_rel_step: expected > 0, got {max_rel_step!r}")

    def steps(a, b):
        same = (a * b) > 0
        geo = np.abs(np.log(np.where(same, b, 1.0) / np.where(same, a, 1.0))) / np.log1p(max_rel_step)
        lin = np.abs(b - a) / (max_rel_step * np.maximum(np.abs(a), np.abs(b)) + 1e-12)
        return float(np.max(np.where(same, geo, lin), initial=0.0))

    k = max(1, int(np.ceil(max(steps(a, b) for a, b in zip(leaves_a, leaves_b)) - 1e-9)))
    treedef = jax.tree.structure(p_from)
    res = res_from
    for i in range(1, k + 1):
        p_i = p_to if i == k else jax.tree.unflatten(treedef, [_interpolate(a, b, i / k) for a, b in zip(leaves_a, leaves_b)])
        res = resolve_robust(problem, p=p_i, bounds=bounds, warm=res, options=options)
        if not res.success:
            break
    return res


# ----------------------------------------------------------------------------------------------
# JAX wrapper


def make_solve(problem, result=None, options: dict | None = None, sc_tol: float = 1e-6, strict: bool = False, warm_from: str = "last", max_rel_step: float | None = None, p_result=None):
    """``solve(p) -> x*(p)``: an IPOPT solve inside ``jax.pure_callback``, differentiable by
    ``jax.custom_vjp`` (reverse mode: ``jax.grad``/``jax.vjp`` of scalar losses of x*).

    Every solve is warm-started (primal and dual) from the previous one (``warm_from="last"``,
    initially ``result``) or always from ``result`` (``warm_from="initial"``: keeps the solves on
    the branch of local optima through ``result``; the OCP has several local optima and a long
    step can make a warm start jump to another one). ``max_rel_step``: follow the branch from the
    warm start's parameters by ``continuation_solve`` (sub-steps of at most this relative change);
    ``p_result``: the parameters ``result`` was solved at (default ``problem.p``). A caller may
    re-anchor the warm start by setting ``solve.state["warm"]`` and ``solve.state["p_warm"]``.
    ``strict=True`` raises when a solve fails; otherwise a failed solve warns.
    ``solve.last`` holds the latest NLPResult, ``solve.stats`` counts solves and adjoints.
    """
    nlp = problem.nlp
    fns = _jax_fns(nlp)
    n, m = nlp.n, nlp.m
    if warm_from not in ("last", "initial"):
        raise ValueError(f"warm_from: {warm_from!r} not in ('last', 'initial')")
    state = {"warm": result, "p_warm": (problem.p if p_result is None else p_result) if result is not None else None, "last": None}
    stats = {"solves": 0, "adjoints": 0, "solve_time_s": 0.0, "adjoint_time_s": 0.0}
    p_struct = jax.tree.structure(problem.p)
    f64 = jnp.float64

    def _solve_cb(p_np):
        if max_rel_step is not None and state["warm"] is not None:
            res = continuation_solve(problem, state["p_warm"], state["warm"], p_np, max_rel_step=max_rel_step, options=options)
        else:
            res = resolve_robust(problem, p=p_np, warm=state["warm"], options=options)
        if not res.success:
            msg = f"make_solve: IPOPT returned {res.status}"
            if strict:
                raise RuntimeError(msg)
            warnings.warn(msg, RuntimeWarning, stacklevel=2)
        stats["solves"] += 1
        stats["solve_time_s"] += res.solve_time_s
        state["last"] = res
        if (warm_from == "last" or state["warm"] is None) and res.success:
            state["warm"], state["p_warm"] = res, p_np
        return res.x, res.lam_g, res.z_l, res.z_u

    def _adjoint_cb(x, lam, zl, zu, p_np, ct):
        t0 = time.perf_counter()
        kkt = KKTSensitivity(problem, x=x, lam_g=lam, z_l=zl, z_u=zu, p=p_np, sc_tol=sc_tol)
        v_x, v_lam = kkt.adjoint(ct)
        stats["adjoints"] += 1
        stats["adjoint_time_s"] += time.perf_counter() - t0
        return v_x, v_lam

    shapes4 = (jax.ShapeDtypeStruct((n,), f64), jax.ShapeDtypeStruct((m,), f64), jax.ShapeDtypeStruct((n,), f64), jax.ShapeDtypeStruct((n,), f64))
    shapes2 = shapes4[:2]

    def _primal(p):
        return jax.pure_callback(_solve_cb, shapes4, p, vmap_method="sequential")

    @jax.custom_vjp
    def solve(p):
        return _primal(p)[0]

    def fwd(p):
        x, lam, zl, zu = _primal(p)
        return x, (x, lam, zl, zu, p)

    def bwd(res, ct):
        x, lam, zl, zu, p = res
        v_x, v_lam = jax.pure_callback(_adjoint_cb, shapes2, x, lam, zl, zu, p, ct, vmap_method="sequential")
        dp = fns["pullback"](x, lam, p, v_x, v_lam)
        return (jax.tree.map(lambda a: -a, dp),)

    solve.defvjp(fwd, bwd)

    def wrapped(p):
        if jax.tree.structure(p) != p_struct:
            raise ValueError("solve: p must have the structure of problem.p (an OCPParams)")
        return solve(_as_float_tree(p))

    wrapped.state = state
    wrapped.stats = stats
    return wrapped


# ----------------------------------------------------------------------------------------------
# Directions and finite-difference checks

GROUPS = ("weights", "contact", "model", "horizon", "start")


def param_direction(p, group: str, seed: int = 0):
    """A tangent of p that moves one parameter group by relative amounts in [-1, 1] (random,
    reproducible): weights (8), contact (kappa, f0, xhat, mu), model (a, c, m, inertia),
    horizon (T), start (q_start, absolute radians). Everything else zero."""
    rng = np.random.default_rng(seed)
    dp = jax.tree.map(np.zeros_like, jax.tree.map(lambda a: np.asarray(a, dtype=float), p))

    def rel(a):
        a = np.asarray(a, dtype=float)
        return a * rng.uniform(-1.0, 1.0, size=a.shape)

    if group == "weights":
        return dataclasses.replace(dp, weights=rel(p.weights))
    if group == "contact":
        c = p.contact
        new = jax.tree.unflatten(jax.tree.structure(c), [rel(v) for v in jax.tree.leaves(c)])
        return dataclasses.replace(dp, contact=new)
    if group == "model":
        mdl = p.model
        d = jax.tree.unflatten(jax.tree.structure(mdl), [np.zeros_like(np.asarray(v, dtype=float)) for v in jax.tree.leaves(mdl)])
        for name in ("a", "c", "m", "inertia"):
            object.__setattr__(d, name, rel(getattr(mdl, name)))
        return dataclasses.replace(dp, model=d)
    if group == "horizon":
        return dataclasses.replace(dp, T=rel(p.T))
    if group == "start":
        return dataclasses.replace(dp, q_start=rng.uniform(-1.0, 1.0, size=np.shape(p.q_start)))
    raise ValueError(f"group: {group!r} not in {GROUPS}")


def perturb(p, dp, t: float):
    """p + t dp leaf by leaf (numpy leaves; validation bypassed as for any pytree map)."""
    return jax.tree.map(lambda a, d: np.asarray(a, dtype=float) + t * np.asarray(d, dtype=float), p, dp)


def fd_directional(problem, result, dp=None, dgoal=None, eps: float = 1e-5, options: dict | None = None):
    """Central differences of warm-started IPOPT re-solves along (dp, dgoal).

    Returns (dx_fd, dV_fd, (res_plus, res_minus)). ``options`` default to tol 1e-10.
    """
    opts = {"tol": 1e-10, "acceptable_iter": 0, "max_iter": 500, **(options or {})}
    out = []
    for t in (eps, -eps):
        p = problem.p if dp is None else perturb(problem.p, dp, t)
        b = problem.bounds if dgoal is None else bounds_for_goal(problem, np.asarray(problem.task.goal) + t * np.asarray(dgoal))
        res = resolve(problem, p=p, bounds=b, warm=result, options=opts)
        if not res.success:
            raise RuntimeError(f"fd_directional: re-solve at t={t:g} returned {res.status}")
        out.append(res)
    dx = (out[0].x - out[1].x) / (2 * eps)
    dV = (out[0].objective - out[1].objective) / (2 * eps)
    return dx, dV, tuple(out)


def rel_err(a, b) -> float:
    """||a - b||_2 / max(||b||_2, tiny)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.linalg.norm(a - b) / max(np.linalg.norm(b), 1e-300))


# ----------------------------------------------------------------------------------------------
# Command line: agreement table and cost


FD_TOL = 1e-4  # relative agreement required of every directional derivative (issue 7)


def missed_active_set(active: ActiveSet) -> ActiveSet:
    """``active`` with every active bound and inequality forgotten (equalities only): the
    mutation that a finite-difference check must catch."""
    return dataclasses.replace(active, rows=active.rows & ~active.ineq_active, ineq_active=np.zeros_like(active.ineq_active), lower=np.zeros_like(active.lower), upper=np.zeros_like(active.upper))


def _mutation_errors(problem, result, kkt, dp, dx_fd) -> dict:
    """Relative errors of deliberately wrong sensitivities against the same finite differences:
    the check's tolerance must reject them (a wrong sign, a missed active set, multipliers read
    with the opposite sign convention)."""
    out = {"wrong_sign": rel_err(-kkt.jvp(dp), dx_fd)}
    for name, kw in (("missed_active_set", {"active": missed_active_set(kkt.active)}), ("flipped_multipliers", {"lam_g": -np.asarray(result.lam_g)})):
        try:
            out[name] = rel_err(KKTSensitivity(problem, result, warn=False, **kw).jvp(dp), dx_fd)
        except np.linalg.LinAlgError:
            out[name] = np.inf  # singular reduced KKT matrix: no sensitivity at all
    return out


def check_against_fd(task="T1", scheme="A,F+C,1S", N=15, T=5.0, eps=1e-5, seed=1, groups=GROUPS + ("goal",), verbose=True, problem=None, result=None) -> dict:
    """Directional derivatives of x* and V* against central differences of warm re-solves, and
    the cost of a sensitivity relative to a solve. Returns a JSON-able dict.

    ``problem``/``result``: reuse a built problem and its converged solution (default: build
    ``task``/``scheme``/``N``/``T`` and ``reference_solve`` it). The cost of one JVP/VJP
    (factorisation included) is reported against the cold solve and in units of its average
    IPOPT iteration (the issue's goal: under a few iterations).
    """
    from jaxhumanoid.strategy.problem import build_problem

    prob = build_problem(task, scheme, N=N, T=T) if problem is None else problem
    res = reference_solve(prob, verbose=verbose) if result is None else result
    KKTSensitivity(prob, res)  # compile
    t0 = time.perf_counter()
    kkt = KKTSensitivity(prob, res)
    t_factor = time.perf_counter() - t0
    rows, mutations = [], None
    for group in groups:
        if group == "goal":
            dp, dgoal = None, np.random.default_rng(seed).uniform(-1, 1, 5)
        else:
            dp, dgoal = param_direction(prob.p, group, seed=seed), None
        kkt.jvp(dp, dgoal)  # compile
        t0 = time.perf_counter()
        dx = kkt.jvp(dp, dgoal)
        t_jvp = time.perf_counter() - t0
        dx_fd, dV_fd, rr = fd_directional(prob, res, dp, dgoal, eps=eps)
        g_env = kkt.objective_gradient(goal=True)
        dV_env = (tree_vdot(g_env[0], dp) if dp is not None else 0.0) + (float(g_env[1] @ dgoal) if dgoal is not None else 0.0)
        dV_chain = kkt.objective_jvp(dp, dgoal, dx=dx)
        row = {
            "group": group,
            "norm_dx": float(np.linalg.norm(dx)),
            "rel_err_dx_2norm": rel_err(dx, dx_fd),
            "rel_err_dx_maxnorm": float(np.max(np.abs(dx - dx_fd)) / np.max(np.abs(dx_fd))),
            "dropped_residual": kkt.dropped_residual,
            "dV_envelope": dV_env,
            "dV_chain": dV_chain,
            "dV_fd": dV_fd,
            "rel_err_dV_env_fd": abs(dV_env - dV_fd) / abs(dV_fd),
            "rel_err_dV_env_chain": abs(dV_env - dV_chain) / abs(dV_env),
            "jvp_time_s": t_jvp,
            "warm_resolve_iters": [r.iterations for r in rr],
            "warm_resolve_time_s": float(np.mean([r.solve_time_s for r in rr])),
        }
        rows.append(row)
        if group == "weights":
            mutations = _mutation_errors(prob, res, kkt, dp, dx_fd)
    ct = np.random.default_rng(seed).normal(size=prob.nlp.n)
    kkt.vjp(ct)
    t0 = time.perf_counter()
    kkt.vjp(ct)
    t_vjp = time.perf_counter() - t0
    t0 = time.perf_counter()
    kkt.objective_gradient()
    t_env = time.perf_counter() - t0
    t_iter = res.solve_time_s / max(res.iterations, 1)
    t_jvp = float(np.median([r["jvp_time_s"] for r in rows]))
    out = {
        "task": prob.task.key, "scheme": str(prob.scheme),
        "N": prob.layout.N, "n": prob.nlp.n, "m": prob.nlp.m, "eps": eps, "tol": FD_TOL,
        "objective": res.objective,
        "active_set": kkt.report(),
        "rows": rows,
        "mutations_weights_rel_err_dx": mutations,
        "cost": {
            "cold_solve_time_s": res.solve_time_s, "cold_solve_iters": res.iterations,
            "time_per_solver_iteration_s": t_iter,
            "factorisation_time_s": t_factor,
            "jvp_time_s (after factorisation)": t_jvp,
            "vjp_time_s (after factorisation)": t_vjp,
            "envelope_gradient_time_s": t_env,
            "warm_resolve_time_s": float(np.mean([r["warm_resolve_time_s"] for r in rows])),
            "ratio_(factor+jvp)/cold_solve": (t_factor + t_jvp) / res.solve_time_s,
            "ratio_(factor+vjp)/cold_solve": (t_factor + t_vjp) / res.solve_time_s,
            "(factor+jvp)_in_solver_iterations": (t_factor + t_jvp) / t_iter,
            "(factor+vjp)_in_solver_iterations": (t_factor + t_vjp) / t_iter,
            "extra_jvp_in_solver_iterations": t_jvp / t_iter,
        },
    }
    c = out["cost"]
    c["ratio_(factor+jvp)/warm_resolve"] = (t_factor + t_jvp) / c["warm_resolve_time_s"]
    if verbose:
        print(f"{out['task']} {out['scheme']} N={out['N']}: n={prob.nlp.n} m={prob.nlp.m}; active set {kkt.report()}")
        print(f"{'group':>8} {'|dx|':>10} {'err dx 2n':>10} {'err dx inf':>10} {'dV env':>14} {'dV chain':>14} {'dV fd':>14} {'err env/fd':>10}")
        for r in rows:
            print(f"{r['group']:>8} {r['norm_dx']:10.3e} {r['rel_err_dx_2norm']:10.2e} {r['rel_err_dx_maxnorm']:10.2e} {r['dV_envelope']:14.8e} {r['dV_chain']:14.8e} {r['dV_fd']:14.8e} {r['rel_err_dV_env_fd']:10.2e}")
        print(f"  mutations (weights, must exceed {FD_TOL:g}): {mutations}")
        for k, v in c.items():
            print(f"  {k}: {v:.4g}")
    return out


def table_rows(out: dict, tol: float = FD_TOL) -> list[dict]:
    """``check_against_fd`` result as rows of ``jaxhumanoid.checks.format_table``: per parameter
    group the 2-norm relative error of dx* and of dV* (envelope theorem) against the finite
    differences."""
    case = f"{out['task']} {out['scheme']} N={out['N']}"
    rows = []
    for r in out["rows"]:
        for quantity, value in ((f"dx* {r['group']}", r["rel_err_dx_2norm"]), (f"dV* {r['group']}", r["rel_err_dV_env_fd"])):
            rows.append({"case": case, "check": "sensitivity vs FD", "quantity": quantity, "value": float(value), "tol": tol, "ok": bool(np.isfinite(value) and value <= tol)})
    return rows


def sensitivity_table(tasks=("T1", "T2", "T3", "T4"), scheme="A,F+C,1S", N=15, T=5.0, eps=1e-5, seed=1, verbose=False) -> tuple[list[dict], list[dict]]:
    """``check_against_fd`` on each task: (table rows, full results) for ``jaxhumanoid check
    --sensitivities``. A task whose solves fail, or whose reduced KKT matrix is singular, gives
    one failing row (the message under ``"error"``)."""
    rows, outs = [], []
    for task in tasks:
        try:
            out = check_against_fd(task, scheme, N, T=T, eps=eps, seed=seed, verbose=verbose)
        except (RuntimeError, np.linalg.LinAlgError) as err:  # a failed solve or a singular reduced KKT matrix
            rows.append({"case": f"{task} {scheme} N={N}", "check": "sensitivity vs FD", "quantity": f"failed ({type(err).__name__})", "value": float("inf"), "tol": FD_TOL, "ok": False, "error": str(err)})
            continue
        outs.append(out)
        rows += table_rows(out)
    return rows, outs


# ----------------------------------------------------------------------------------------------
# Inverse optimal control of the cost weights

WEIGHT_NAMES = ("w_u1", "w_u2", "w_u3", "w_u4", "w_u5", "w_qd", "w_dqd", "w_du")
FREE_WEIGHTS = (0, 1, 2, 3, 4, 6, 7)  # w_qd fixes the scale: x*(c w) = x*(w) for every c > 0


def perturbed_weights(w, seed: int = 0, lo: float = 2.0, hi: float = 5.0, free=FREE_WEIGHTS) -> np.ndarray:
    """``w`` with each free weight multiplied or divided (at random, reproducibly) by a factor
    drawn uniformly from [lo, hi]: the start of the inverse problems of issue 7."""
    if not 0 < lo <= hi:
        raise ValueError(f"lo, hi: expected 0 < lo <= hi, got {lo!r}, {hi!r}")
    rng = np.random.default_rng(seed)
    free = np.asarray(free, dtype=np.int64)
    out = np.asarray(w, dtype=float).copy()
    out[free] *= rng.uniform(lo, hi, size=free.size) ** rng.choice([-1.0, 1.0], size=free.size)
    return out


def trajectory_scale(problem, x) -> np.ndarray:
    """(n,) per-variable scale of the trajectory mismatch: RMS over the nodes of each column of
    the full layout (q, qd, u, f) of ``x``, floored at 1e-3 of the largest column."""
    Z = problem.full(x)
    col = np.sqrt(np.mean(Z**2, axis=0))
    col = np.maximum(col, 1e-3 * col.max() + 1e-12)
    return np.broadcast_to(col, Z.shape)[problem.layout.free_mask()]


class WeightFit:
    """Fit the cost weights so that the optimal trajectory matches ``x_data`` (issue 7).

    Unknowns theta = log w[free] (``free`` defaults to the seven weights other than w_qd, which
    stays at ``w_init[5]``: only ratios of weights are identifiable). The loss is the scaled
    mismatch ``1/2 ||(x*(w(theta)) - x_data) / s||^2`` (s: ``trajectory_scale`` of x_data).

    Every solve follows one branch of local optima: the first is warm-started from ``x_data``
    (primal only, the multipliers are unknown in an inverse problem) at ``w_init``, and each
    later one by ``continuation_solve`` from the previous solve (sub-steps of at most a factor
    1 + ``max_rel_step`` per weight). Without it, a warm start after a long step can land on
    another local optimum, where the mismatch is large and flat.

    Methods: ``gauss_newton`` (residual Jacobian from one KKT factorisation and one JVP per
    unknown) and ``lbfgs`` (scipy L-BFGS-B on ``jax.value_and_grad`` of the loss through
    ``make_solve``: one solve and one adjoint per evaluation).

    Both are local. From ``perturbed_weights(w, seed=0)`` they recover the weights on T1-T4
    (N = 15). From ``seed=1`` (factors 0.28, 0.21, 2.4, 4.9, 0.34, 0.31, 4.5) Gauss-Newton
    fails on all four: it lowers the loss (T1 19.9 -> 8.2, T2 71 -> 46, T3 8.1 -> 4.8, T4
    28 -> 6.5) by driving one weight towards 0 (w_u5 on T1-T3, w_dqd on T4), and on T3 its
    trial steps jump from loss 6.5 to 16 where the followed branch ends. The first solve is
    not the cause: on T2 and T3 it equals the data's branch continued from the true weights.
    """

    def __init__(self, problem, x_data, w_init, free=FREE_WEIGHTS, max_rel_step: float = 0.25, options: dict | None = None, verbose: bool = False):
        self.problem = problem
        self.x_data = np.asarray(x_data, dtype=float)
        if self.x_data.shape != (problem.nlp.n,):
            raise ValueError(f"x_data: expected shape ({problem.nlp.n},), got {self.x_data.shape}")
        self.w_init = np.asarray(w_init, dtype=float)
        if self.w_init.shape != (8,) or not np.all(self.w_init > 0):
            raise ValueError(f"w_init: expected 8 positive weights, got {w_init!r}")
        self.free = np.asarray(free, dtype=np.int64)
        self.scale = trajectory_scale(problem, self.x_data)
        self.options = {"tol": 1e-10, "max_iter": 3000, **(options or {})}
        self.max_rel_step = max_rel_step
        self.verbose = verbose
        self.stats = {"solves": 0, "solve_wall_s": 0.0, "sensitivities": 0, "sensitivity_wall_s": 0.0}
        self.history: list[dict] = []
        self._last = None  # (theta, p, result) of the latest solve
        self._best = None  # (loss, theta, p, result) of the solve with the smallest loss: the anchor
        p0 = self.params(self.theta_init)
        b = problem.bounds
        start = Bounds(x0=np.clip(self.x_data, b.xl, b.xu), xl=b.xl, xu=b.xu, gl=b.gl, gu=b.gu)
        t0 = time.perf_counter()
        res = resolve(problem, p=p0, bounds=start, options=self.options)
        if not res.success:
            raise RuntimeError(f"WeightFit: the first solve (at w_init, from x_data) returned {res.status}")
        self._record(self.theta_init, p0, res, time.perf_counter() - t0)

    @property
    def theta_init(self) -> np.ndarray:
        return np.log(self.w_init[self.free])

    def weights(self, theta) -> np.ndarray:
        w = self.w_init.copy()
        w[self.free] = np.exp(np.asarray(theta, dtype=float))
        return w

    def params(self, theta):
        return dataclasses.replace(self.problem.p, weights=self.weights(theta))

    def residual_of(self, x) -> np.ndarray:
        return (np.asarray(x) - self.x_data) / self.scale

    def _record(self, theta, p, res, wall):
        self.stats["solves"] += 1
        self.stats["solve_wall_s"] += wall
        theta = np.array(theta, dtype=float)
        self._last = (theta, p, res)
        r = self.residual_of(res.x)
        loss = float(0.5 * r @ r)
        if self._best is None or loss < self._best[0]:
            self._best = (loss, theta, p, res)
        self.history.append({"theta": theta.tolist(), "loss": loss, "ipopt_iterations": res.iterations})
        if self.verbose:
            print(f"  solve {self.stats['solves']:3d}: loss {loss:.6e}  ipopt its {res.iterations}")

    def solve(self, theta):
        """(p, NLPResult) at ``theta``, continued from the solve with the smallest loss so far.

        Not from the latest: a rejected trial step can land on another branch of local optima,
        and continuing from there would carry the following solves onto it.
        """
        theta = np.asarray(theta, dtype=float)
        for th, p_done, res_done in (self._last, self._best[1:]):
            if np.array_equal(theta, th):
                return p_done, res_done
        _, _, p_from, res_from = self._best
        p = self.params(theta)
        t0 = time.perf_counter()
        res = continuation_solve(self.problem, p_from, res_from, p, max_rel_step=self.max_rel_step, options=self.options)
        if not res.success:
            raise RuntimeError(f"WeightFit: solve at w = {self.weights(theta)} returned {res.status}")
        self._record(theta, p, res, time.perf_counter() - t0)
        return p, res

    def residual(self, theta) -> np.ndarray:
        return self.residual_of(self.solve(theta)[1].x)

    def jacobian(self, theta) -> np.ndarray:
        """(n, k) d residual / d theta: one KKT factorisation, one JVP per unknown."""
        p, res = self.solve(theta)
        t0 = time.perf_counter()
        kkt = KKTSensitivity(self.problem, res, p=p)
        w = self.weights(theta)
        cols = []
        for j, i in enumerate(self.free):
            dw = np.zeros(8)
            dw[i] = w[i]  # d w_i / d theta_j
            cols.append(kkt.jvp(dataclasses.replace(zeros_like_params(p), weights=dw)) / self.scale)
        self.stats["sensitivities"] += 1
        self.stats["sensitivity_wall_s"] += time.perf_counter() - t0
        return np.stack(cols, axis=1)

    def gauss_newton(self, theta0=None, max_evals: int = 30, max_step: float = 1.0, tol: float = 1e-12, xtol: float = 1e-9):
        """Levenberg-Marquardt-damped Gauss-Newton, steps clipped to ||dtheta||_inf <= max_step
        (a factor e per weight: long steps make the continuation expensive). Stops when the
        step falls below ``xtol`` (further steps only chase IPOPT's tolerance), when an accepted
        step reduces the loss by less than ``tol`` relative, or after ``max_evals`` solves.
        Returns theta."""
        theta = self.theta_init if theta0 is None else np.asarray(theta0, dtype=float)
        r = self.residual(theta)
        loss, evals, damping = 0.5 * r @ r, 1, 1e-6
        converged = False
        while evals < max_evals and not converged:
            Jm = self.jacobian(theta)
            g, A = Jm.T @ r, Jm.T @ Jm
            if np.max(np.abs(g)) <= tol * max(1.0, loss):
                break
            accepted = False
            while evals < max_evals:
                step = -np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-12), g)
                step *= min(1.0, max_step / max(np.max(np.abs(step)), 1e-300))
                if np.max(np.abs(step)) < xtol:
                    break
                r_new = self.residual(theta + step)
                evals += 1
                loss_new = 0.5 * r_new @ r_new
                if loss_new < loss:
                    converged = loss - loss_new <= tol * loss
                    theta, r, loss, accepted = theta + step, r_new, loss_new, True
                    damping = max(damping / 10, 1e-12)
                    break
                damping *= 10
            if not accepted:
                break
        return theta

    def lbfgs(self, theta0=None, max_evals: int = 80, max_step: float = 0.5):
        """scipy L-BFGS-B on ``jax.value_and_grad`` of the loss through ``make_solve`` (reverse
        mode: one adjoint solve per gradient). Returns theta.

        The unknowns are preconditioned once, v = R (theta - theta0) with R^T R = J0^T J0 + I /
        max_step^2, J0 the residual Jacobian at theta0 (one KKT factorisation): a unit step in
        v then moves theta by at most ``max_step`` (2-norm), and by about a Gauss-Newton step
        in the well-determined directions. Unscaled, the loss is ill-conditioned in theta and
        L-BFGS-B stalled (T3: loss 9.7 -> 7.4 in 30 evaluations, against 1e-22 in 9 for
        Gauss-Newton), and its first unit step in theta, up to a factor e per weight, landed on
        another branch of local optima. As in ``solve``, every solve continues from the best
        one so far.
        """
        from scipy import optimize

        theta0 = self.theta_init if theta0 is None else np.asarray(theta0, dtype=float)
        J0 = self.jacobian(theta0)
        R = np.linalg.cholesky(J0.T @ J0 + np.eye(J0.shape[1]) / max_step**2).T
        R_inv = np.linalg.inv(R)
        _, _, p_best, res_best = self._best
        solve = make_solve(self.problem, result=res_best, p_result=p_best, options=self.options, max_rel_step=self.max_rel_step, strict=True, warm_from="initial")
        w_fixed, free = jnp.asarray(self.w_init), jnp.asarray(self.free)
        x_data, scale = jnp.asarray(self.x_data), jnp.asarray(self.scale)
        theta_of = lambda v: theta0 + R_inv @ v  # noqa: E731

        def loss(v):
            w = w_fixed.at[free].set(jnp.exp(theta0 + jnp.asarray(R_inv) @ v))
            r = (solve(dataclasses.replace(self.problem.p, weights=w)) - x_data) / scale
            return 0.5 * jnp.dot(r, r)

        value_and_grad = jax.value_and_grad(loss)

        def fg(v):
            t0, t_adj = time.perf_counter(), solve.stats["adjoint_time_s"]
            val, g = value_and_grad(jnp.asarray(v))
            t_adj = solve.stats["adjoint_time_s"] - t_adj
            self.stats["sensitivities"] += 1
            self.stats["sensitivity_wall_s"] += t_adj
            theta = theta_of(np.asarray(v))
            self._record(theta, self.params(theta), solve.state["last"], time.perf_counter() - t0 - t_adj)
            _, _, solve.state["p_warm"], solve.state["warm"] = self._best  # continue from the best solve
            return float(val), np.asarray(g, dtype=float)

        sol = optimize.minimize(fg, np.zeros_like(theta0), jac=True, method="L-BFGS-B", options={"maxfun": max_evals, "ftol": 1e-15, "gtol": 1e-12})
        self.stats["lbfgs_message"] = str(sol.message)
        return theta_of(np.asarray(sol.x, dtype=float))

    def summary(self, theta, w_true=None) -> dict:
        """Recovered weights and the trajectory mismatch at ``theta`` (JSON-able)."""
        _, res = self.solve(theta)
        Zd, Zh = self.problem.full(self.x_data), self.problem.full(res.x)
        r = self.residual_of(res.x)
        out = {
            "weight_names": list(WEIGHT_NAMES),
            "free": [WEIGHT_NAMES[i] for i in self.free],
            "w_initial": self.w_init.tolist(),
            "w_recovered": self.weights(theta).tolist(),
            "loss_initial": self.history[0]["loss"],
            "loss_final": float(0.5 * r @ r),
            "max_abs_q_error_rad": float(np.max(np.abs(Zh[:, 0:5] - Zd[:, 0:5]))),
            "max_abs_u_error_Nm": float(np.max(np.abs(Zh[:-1, 10:15] - Zd[:-1, 10:15]))),
            "rel_err_x": rel_err(res.x, self.x_data),
            **self.stats,
        }
        if w_true is not None:
            w_true = np.asarray(w_true, dtype=float)
            out["w_true"] = w_true.tolist()
            out["initial_factors"] = (self.w_init[self.free] / w_true[self.free]).tolist()
            out["recovered_factors"] = (self.weights(theta)[self.free] / w_true[self.free]).tolist()
            out["max_rel_weight_error"] = float(np.max(np.abs(self.weights(theta)[self.free] / w_true[self.free] - 1)))
        return out


def main(argv=None):
    import argparse
    import json

    ap = argparse.ArgumentParser(description="KKT sensitivities vs finite differences of re-solves")
    ap.add_argument("--task", nargs="+", default=["T1"], help="one or more of T1..T4")
    ap.add_argument("--scheme", default="A,F+C,1S")
    ap.add_argument("--N", type=int, default=15)
    ap.add_argument("--eps", type=float, default=1e-5)
    ap.add_argument("--json", default=None, help="write the results (a list, one entry per task)")
    a = ap.parse_args(argv)
    from jaxhumanoid.runtime import enable_compilation_cache

    enable_compilation_cache()  # every IPOPT re-solve jits its callbacks: the disk cache saves the compile
    outs = []
    for task in a.task:
        outs.append(check_against_fd(task, a.scheme, a.N, eps=a.eps))
        if a.json:  # after every task: a long run leaves what it has
            with open(a.json, "w") as fh:
                json.dump(outs, fh, indent=1)
    return outs


if __name__ == "__main__":
    main()
