"""The active set of a KKT point: which bounds and inequalities the sensitivities hold fixed.

IPOPT's conventions (cyipopt): the Lagrangian is

    L(x, lam, z; p) = f(x, p) + lam . g(x, p) - z_l . (x - xl) + z_u . (x - xu),   z_l, z_u >= 0

and stationarity reads grad f + J^T lam - z_l + z_u = 0. A constraint with only a lower bound
(g_j >= gl_j) that is active has lam_j <= 0; one at its upper bound has lam_j >= 0.

A bound or inequality is *active* when its multiplier exceeds its slack (at an interior-point
solution with barrier mu, multiplier * slack ~ mu, so exactly one of the two is O(mu) when strict
complementarity holds). Active variable bounds fix the variable (index set B; the rest is F);
active inequalities join the equalities (row set C). Strict complementarity is checked: every
active multiplier must be above ``sc_tol`` and every inactive slack above ``sc_tol`` (a pair with
both small is *weakly active*: x*(p) is then only directionally differentiable and the
sensitivities are those of the fixed active set); a ``StrictComplementarityWarning`` says so.

Two degeneracies of the transcription are handled here. (i) Under scheme A the bounds of the
contact-force variables are implied by the contact-law equalities (``implied_bounds``) and are
never taken as active. (ii) LICQ fails at foot lift-off (all five steady-foot constraints (5)
active with a vanishing foot reaction): active inequality rows whose gradients depend on the
others are dropped (``dependent_active_rows``).
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from jaxhumanoid.ocp.nlp import Bounds


class StrictComplementarityWarning(UserWarning):
    """A bound or inequality is weakly active: multiplier and slack are both (near) zero."""


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
    """(2, n) bounds implied by equality constraints and never active: row 0 the lower bounds,
    row 1 the upper ones.

    Under scheme A the contact-force variables equal the contact law (f = f_law(q, qd)), whose
    normal force is > 0 (f_n has no lower bound: ``transcription.bounds_full``) and whose
    friction force is bounded by mu f_n: the bounds |f_t| <= f_max are redundant, and so is
    f_n <= f_max for the wide box ``CONTACT_FORCE_LIMIT``, but not for a task's
    ``contact_force_limit``, which the optimum may meet.
    """
    layout = problem.layout
    lower = np.zeros((layout.N + 1, layout.s), dtype=bool)
    upper = np.zeros_like(lower)
    if layout.augmented:
        f = layout.stage_slices()["f"]
        lower[:, f] = upper[:, f] = True
        if problem.task.contact_force_limit is not None:
            upper[:, f.start + 1 : f.stop : 2] = False  # f_n <= the task's limit
    free = layout.free_mask()
    return np.stack([lower[free], upper[free]])


def _side(finite, mult, slack, sc_tol):
    """(active, weak, multiplier, slack) of one side of a family of bounds (all (k,))."""
    mult = np.where(finite, np.maximum(mult, 0.0), 0.0)
    slack = np.where(finite, np.maximum(slack, 0.0), np.inf)
    active = finite & (mult > slack)
    weak = finite & (np.maximum(mult, slack) < sc_tol)
    return active, weak, mult, slack


def _warn_weak(act: ActiveSet, sc_tol: float) -> None:
    warnings.warn(
        f"strict complementarity fails: {int(act.weak_x.sum())} bounds and {int(act.weak_g.sum())} inequalities "
        f"are weakly active (multiplier and slack both < {sc_tol:g}; variables {np.flatnonzero(act.weak_x)[:10]}, "
        f"constraints {np.flatnonzero(act.weak_g)[:10]}): x*(p) is only directionally differentiable there and "
        "the sensitivities are those of the identified active set",
        StrictComplementarityWarning,
        stacklevel=4,
    )


def identify_active_set(
    bounds: Bounds, x, g_val, lam_g, z_l, z_u, sc_tol: float = 1e-6, warn: bool = True, ignore_bounds=None
) -> ActiveSet:
    """Active bounds and inequalities from IPOPT's multipliers and slacks (see the module doc).

    x, z_l, z_u: (n,); g_val, lam_g: (m,). ``ignore_bounds``: bounds known to be redundant
    (``implied_bounds``), never active: an (n,) mask of variables (both bounds) or a (2, n) one
    (lower, upper).
    """
    x, g_val, lam_g = np.asarray(x), np.asarray(g_val), np.asarray(lam_g)
    z_l, z_u = np.asarray(z_l), np.asarray(z_u)
    ignore = np.zeros((2,) + x.shape, dtype=bool) if ignore_bounds is None else np.asarray(ignore_bounds, dtype=bool)
    ignore = np.broadcast_to(ignore, (2,) + x.shape)
    lo_fin, up_fin = np.isfinite(bounds.xl) & ~ignore[0], np.isfinite(bounds.xu) & ~ignore[1]
    lo_a, lo_w, lo_m, lo_s = _side(lo_fin, z_l, x - bounds.xl, sc_tol)
    up_a, up_w, up_m, up_s = _side(up_fin, z_u, bounds.xu - x, sc_tol)
    eq = np.isfinite(bounds.gl) & (bounds.gl == bounds.gu)
    gl_fin = np.isfinite(bounds.gl) & ~eq
    gu_fin = np.isfinite(bounds.gu) & ~eq
    gl_a, gl_w, gl_m, gl_s = _side(gl_fin, -lam_g, g_val - bounds.gl, sc_tol)
    gu_a, gu_w, gu_m, gu_s = _side(gu_fin, lam_g, bounds.gu - g_val, sc_tol)
    ineq = gl_a | gu_a
    mults = np.concatenate([lo_m[lo_a], up_m[up_a], gl_m[gl_a], gu_m[gu_a]])
    slacks = np.concatenate([lo_s[lo_fin & ~lo_a], up_s[up_fin & ~up_a], gl_s[gl_fin & ~gl_a], gu_s[gu_fin & ~gu_a]])
    act = ActiveSet(
        lower=lo_a,
        upper=up_a,
        rows=eq | ineq,
        ineq_active=ineq,
        weak_x=lo_w | up_w,
        weak_g=gl_w | gu_w,
        min_active_multiplier=float(mults.min()) if mults.size else np.inf,
        min_inactive_slack=float(slacks.min()) if slacks.size else np.inf,
        sc_tol=float(sc_tol),
    )
    if warn and not act.strict:
        _warn_weak(act, sc_tol)
    return act


def missed_active_set(active: ActiveSet) -> ActiveSet:
    """``active`` with every active bound and inequality forgotten (equalities only): the
    mutation that a finite-difference check must catch."""
    return dataclasses.replace(
        active,
        rows=active.rows & ~active.ineq_active,
        ineq_active=np.zeros_like(active.ineq_active),
        lower=np.zeros_like(active.lower),
        upper=np.zeros_like(active.upper),
    )


def _unit_rows(A):
    """Rows of the sparse matrix ``A`` scaled to unit 2-norm (zero rows left as they are)."""
    norms = np.sqrt(np.asarray(A.multiply(A).sum(axis=1)).ravel())
    return sp.diags(1.0 / np.maximum(norms, 1e-300)) @ A


def dependent_active_rows(J, F, active: ActiveSet, tol: float = 1e-9) -> np.ndarray:
    """Indices of the active inequality rows whose gradients (on the free variables F) depend
    linearly on the equality rows and on the other active inequalities (LICQ failure).

    J: (m, n) sparse Jacobian; F: indices of the free variables. Seen at foot lift-off: the five
    steady-foot constraints (5) are all active when the foot reaction vanishes (f_n0 = f_t0 =
    u_1 = 0) and their gradients span only three directions. The dropped rows hold to first
    order automatically when the linearisation is consistent (``KKTSensitivity.dropped_residual``
    reports it); their multiplier sensitivities are set to 0.

    The (unit) inequality rows a_i are projected onto the null space of the equality rows A_e by
    one sparse solve, [I A_e^T; A_e 0] [r; y] = [a; 0] (r = a - A_e^T y, A_e r = 0), and the few
    projections r_i go through a dense pivoted QR; rows with a pivot below ``tol`` are dropped.
    Should the equality rows themselves be dependent (a singular sparse system), a dense QR of
    the equality rows does the projection instead.
    """
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
