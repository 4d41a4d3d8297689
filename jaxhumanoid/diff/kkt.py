"""The factorised reduced KKT system at a converged point: JVPs, VJPs and the optimal value.

Reduced KKT system (second-order sufficiency + LICQ on the active set make it nonsingular):

    [ H_FF   J_CF^T ] [ dx_F   ]     [ d_p(grad_x L)_F dp + H_FB dx_B ]
    [ J_CF   0      ] [ dlam_C ] = - [ d_p g_C dp       + J_CB dx_B   ]

with H the Hessian of the Lagrangian (``nlp.hess_values``, sigma = 1), J = dg/dx
(``nlp.jac_values``), F the free variables, B the variables at an active bound and C the
equalities and active inequalities (``active_set``), and dx_B the motion of the active bounds
(non-zero only for the goal box). The right-hand side is a forward-over-reverse JVP of
grad_x (f + lam . g) with respect to p at fixed (x, lam). The adjoint (VJP) solves the same
symmetric system with right-hand side (ct_F, 0) and pulls the solution back through p by one
reverse-mode gradient.

Goal posture: the goal enters the *bounds* (the terminal box goal +- the task's goal_tolerance), not p. An
active goal-box bound moves with the goal (dx_B = dgoal for those entries), inactive ones do not
matter. Optimal value: by the envelope theorem dV/dp = d_p L(x*, lam*; p) (no solve needed) and
dV/dgoal = z_l . dxl/dgoal - z_u . dxu/dgoal; the chain rule through the JVP
(``objective_jvp``) is an independent check.

Linear algebra: a sparse LU (``scipy.sparse.linalg.splu``) of the reduced matrix, not the IPM's
block LDL^T (``solvers/ipm/kkt.py``). The reduced system keeps only the rows and columns that the
active set selects at run time (and drops the dependent rows found by a pivoted QR), so its
pattern is not the static stage layout that ``structure_of`` compiles; and a singular reduced
matrix (LICQ or second-order sufficiency failing) must be reported as an error, whereas the block
factorisation regularises and counts inertia for the IPM's line search.
"""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from jaxhumanoid.diff.active_set import ActiveSet, dependent_active_rows, identify_active_set, implied_bounds
from jaxhumanoid.diff.lagrangian import lagrangian_fns
from jaxhumanoid.diff.trees import as_float_tree, zeros_like_params
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.nlp import Bounds


def goal_bound_jacobians(problem) -> tuple[np.ndarray, np.ndarray]:
    """(n_x, n) derivatives dxl/dgoal, dxu/dgoal of the NLP bounds w.r.t. the goal posture (n joints).

    The terminal box is max(q_min, goal - tol) .. min(q_max, goal + tol) (``bounds_full``): a
    bound moves with the goal unless it is clipped by the joint range.
    """
    layout, goal = problem.layout, np.asarray(problem.task.goal, dtype=float)
    tol = problem.task.goal_tolerance
    free = layout.free_mask()
    idx = np.full(free.shape, -1)
    idx[free] = np.arange(free.sum())
    q_min, q_max = problem.joint_ranges()
    nq = goal.size
    Dl, Du = np.zeros((problem.nlp.n, nq)), np.zeros((problem.nlp.n, nq))
    for j in range(nq):
        i = idx[layout.N, j]
        if i >= 0:
            Dl[i, j] = float(goal[j] - tol > q_min[j])
            Du[i, j] = float(goal[j] + tol < q_max[j])
    return Dl, Du


def bounds_for_goal(problem, goal) -> Bounds:
    """The problem's bounds with the terminal goal box moved to ``goal`` (n,)."""
    q_min, q_max = problem.joint_ranges()
    goal = np.asarray(goal, dtype=float)
    u_max = np.asarray(problem.model.u_max)
    lo, hi = tr.bounds_full(problem.layout, goal, q_min, q_max, u_max, problem.task.goal_tolerance)
    free = problem.layout.free_mask()
    b = problem.bounds
    return Bounds(x0=np.clip(b.x0, lo[free], hi[free]), xl=lo[free], xu=hi[free], gl=b.gl, gu=b.gu)


class KKTValues(NamedTuple):
    """The NLP's values that the reduced KKT system is built from, at (x, lam, p).

    g: (m,) constraints; jac: (nnz_jac,) Jacobian values; hess: (nnz_hess,) Hessian values of the
    Lagrangian (sigma = 1); grad_lag: (n,) grad_x (f + lam . g).
    """

    g: Any
    jac: Any
    hess: Any
    grad_lag: Any


def kkt_values(nlp, x, lam, p) -> KKTValues:
    """``KKTValues`` by the NLP's jitted functions (traceable: usable inside a JAX transformation)."""
    fns = lagrangian_fns(nlp)
    return KKTValues(g=fns.g(x, p), jac=fns.jac(x, p), hess=fns.hess(x, lam, 1.0, p), grad_lag=fns.grad_lag(x, lam, p))


def _sparse_derivatives(nlp, vals: KKTValues):
    """(J (m, n) CSR, H (n, n) symmetric CSR) from the values, H with sigma = 1."""
    J = sp.csr_matrix((np.asarray(vals.jac), (nlp.jac_rows, nlp.jac_cols)), shape=(nlp.m, nlp.n))
    Hl = sp.csr_matrix((np.asarray(vals.hess), (nlp.hess_rows, nlp.hess_cols)), shape=(nlp.n, nlp.n))
    return J, (Hl + Hl.T - sp.diags(Hl.diagonal())).tocsr()


def _factor(K, nF: int, nC: int):
    """splu of the reduced KKT matrix K ((nF + nC) square); LinAlgError when it is singular."""
    if nC > nF:
        raise np.linalg.LinAlgError(f"reduced KKT system: {nC} active constraints for {nF} free variables (LICQ fails)")
    try:
        return spla.splu(K)
    except RuntimeError as err:
        raise np.linalg.LinAlgError(
            f"reduced KKT matrix ({K.shape[0]}x{K.shape[0]}, {nF} free variables, {nC} active constraints) is "
            f"singular: LICQ or second-order sufficiency fails at the identified active set ({err}); redundant "
            "bounds may need to go into ignore_bounds (see implied_bounds)"
        ) from err


class KKTSensitivity:
    """Reduced KKT system at a converged point, factorised once; JVPs/VJPs reuse the factors.

    ``KKTSensitivity(problem, result)`` or with explicit ``x, lam_g, z_l, z_u, p, bounds``
    (overriding the fields of ``result``). ``active``: use this active set instead of
    identifying it; ``dep_tol``: pivot tolerance of ``dependent_active_rows``. ``values``: the
    ``KKTValues`` at the point, evaluated beforehand; the construction then makes no JAX call
    (as inside a host callback, where a nested JAX dispatch can deadlock the CPU client) and
    keeps p with numpy leaves.
    """

    def __init__(
        self,
        problem,
        result=None,
        *,
        x=None,
        lam_g=None,
        z_l=None,
        z_u=None,
        p=None,
        bounds=None,
        sc_tol: float = 1e-6,
        warn: bool = True,
        active: ActiveSet | None = None,
        dep_tol: float = 1e-9,
        values: KKTValues | None = None,
    ):
        t0 = time.perf_counter()
        self.problem = problem
        nlp = self.nlp = problem.nlp
        p = problem.p if p is None else p
        self.p = as_float_tree(p) if values is None else jax.tree.map(lambda a: np.asarray(a, dtype=float), p)
        self.bounds = problem.bounds if bounds is None else bounds
        self.x = np.asarray(result.x if x is None else x, dtype=float)
        self.lam = np.asarray(result.lam_g if lam_g is None else lam_g, dtype=float)
        self.z_l = np.asarray(result.z_l if z_l is None else z_l, dtype=float)
        self.z_u = np.asarray(result.z_u if z_u is None else z_u, dtype=float)
        self.fns = lagrangian_fns(nlp)
        vals = kkt_values(nlp, self.x, self.lam, self.p) if values is None else values
        self.g_val = np.asarray(vals.g)
        self.active = (
            active
            if active is not None
            else identify_active_set(
                self.bounds,
                self.x,
                self.g_val,
                self.lam,
                self.z_l,
                self.z_u,
                sc_tol=sc_tol,
                warn=warn,
                ignore_bounds=implied_bounds(problem),
            )
        )
        J, H = self.J, self.H = _sparse_derivatives(nlp, vals)
        self.F = np.flatnonzero(self.active.free)
        self.B = np.flatnonzero(self.active.fixed)
        self.dropped = dependent_active_rows(J, self.F, self.active, dep_tol)
        rows = self.active.rows.copy()
        rows[self.dropped] = False
        self.C = np.flatnonzero(rows)
        JCF = J[self.C][:, self.F]
        self.K = sp.bmat([[H[self.F][:, self.F], JCF.T], [JCF, None]], format="csc")
        self._HFB = H[self.F][:, self.B]
        self._JCB = J[self.C][:, self.B]
        self.lu = _factor(self.K, self.F.size, self.C.size)
        self.factor_time_s = time.perf_counter() - t0
        # stationarity residual of the KKT point: a check of the multiplier convention
        gl = np.asarray(vals.grad_lag)
        self.dropped_residual = 0.0
        self.stationarity = float(np.max(np.abs(gl - self.z_l + self.z_u))) if nlp.n else 0.0

    # -- linear algebra -----------------------------------------------------------------------

    def _solve(self, rhs):
        sol = self.lu.solve(rhs)
        return sol[: self.F.size], sol[self.F.size :]

    def kkt_residual(self, rhs, sol) -> float:
        """Relative residual of a reduced-KKT solve (conditioning check)."""
        r = self.K @ sol - rhs
        return float(np.linalg.norm(r) / max(float(np.linalg.norm(rhs)), 1e-300))

    # -- forward ------------------------------------------------------------------------------

    def _goal_motion(self, dgoal) -> np.ndarray:
        """dx_B (|B|,) of the active bounds for a goal tangent (n,) (zeros for None)."""
        if dgoal is None:
            return np.zeros(self.B.size)
        Dl, Du = goal_bound_jacobians(self.problem)
        dxl, dxu = Dl @ np.asarray(dgoal, float), Du @ np.asarray(dgoal, float)
        return np.where(self.active.lower[self.B], dxl[self.B], dxu[self.B])

    def jvp(self, dp=None, dgoal=None, return_all: bool = False):
        """dx* (n,) for a parameter tangent ``dp`` (pytree like p) and/or goal tangent ``dgoal``
        (n,); with ``return_all`` also dlam* (m,). Sets ``dropped_residual``."""
        n, m = self.nlp.n, self.nlp.m
        if dp is None:
            r_x, r_g = np.zeros(n), np.zeros(m)
        else:
            dgl, dg = self.fns.rhs_jvp(self.x, self.lam, self.p, as_float_tree(dp))
            r_x, r_g = np.asarray(dgl), np.asarray(dg)
        dxB = self._goal_motion(dgoal)
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
        """(v_x (n,), v_lam (m,)), zeros off F / C: K [v_F; v_C] = [ct_F; 0]."""
        ct_x = np.asarray(ct_x, dtype=float)
        rhs = np.concatenate([ct_x[self.F], np.zeros(self.C.size)])
        vF, vC = self._solve(rhs)
        v_x, v_lam = np.zeros(self.nlp.n), np.zeros(self.nlp.m)
        v_x[self.F], v_lam[self.C] = vF, vC
        return v_x, v_lam

    def vjp(self, ct_x, goal: bool = False):
        """Cotangent of p (pytree like p) for a cotangent ``ct_x`` (n,) of x*; with ``goal=True``
        also the (5,) cotangent of the goal posture (n,)."""
        ct_x = np.asarray(ct_x, dtype=float)
        v_x, v_lam = self.adjoint(ct_x)
        dp = jax.tree.map(lambda a: -np.asarray(a), self.fns.pullback(self.x, self.lam, self.p, v_x, v_lam))
        if not goal:
            return dp
        # total d loss / d x_B: direct + through the reduced system
        ctB = ct_x[self.B] - (self._HFB.T @ v_x[self.F] + self._JCB.T @ v_lam[self.C])
        Dl, Du = goal_bound_jacobians(self.problem)
        D = np.where(self.active.lower[self.B][:, None], Dl[self.B], Du[self.B])
        return dp, D.T @ ctB

    # -- optimal value ------------------------------------------------------------------------

    def objective_gradient(self, goal: bool = False):
        """Envelope theorem: dV/dp = grad_p L(x*, lam*; p) (and dV/dgoal (n,) with ``goal=True``)."""
        dp = jax.tree.map(np.asarray, self.fns.lag_grad_p(self.x, self.lam, self.p))
        if not goal:
            return dp
        Dl, Du = goal_bound_jacobians(self.problem)
        return dp, Dl.T @ self.z_l - Du.T @ self.z_u

    def objective_jvp(self, dp=None, dgoal=None, dx=None) -> float:
        """dV along (dp, dgoal) by the chain rule d_x f . dx* + d_p f . dp (independent of the envelope)."""
        if dx is None:
            dx = self.jvp(dp, dgoal)
        dpp = zeros_like_params(self.p) if dp is None else as_float_tree(dp)
        return float(self.fns.f_jvp(self.x, self.p, jnp.asarray(dx), dpp))

    def report(self) -> dict:
        return {
            **self.active.summary(),
            "n_dependent_dropped": int(self.dropped.size),
            "n_free": int(self.F.size),
            "kkt_size": int(self.K.shape[0]),
            "stationarity": self.stationarity,
            "factor_time_s": self.factor_time_s,
        }


def solution_jvp(problem, result, dp, dgoal=None, **kw) -> np.ndarray:
    """dx* = (dx*/dp) dp (+ dx*/dgoal dgoal) at a converged ``result`` of ``problem``."""
    return KKTSensitivity(problem, result, **kw).jvp(dp, dgoal)


def solution_vjp(problem, result, ct_x, goal: bool = False, **kw):
    """ct_x^T dx*/dp as a pytree like p (and the goal cotangent with ``goal=True``)."""
    return KKTSensitivity(problem, result, **kw).vjp(ct_x, goal=goal)


def objective_gradient(problem, result, goal: bool = False, **kw):
    """dV/dp of the optimal value by the envelope theorem."""
    return KKTSensitivity(problem, result, **kw).objective_gradient(goal=goal)
