"""Typed state of the interior-point method: the scaled problem's data, the iterate, the filter,
the restoration phase, the watchdog and the loop state (all NamedTuples of arrays, so pytrees
that ``lax.while_loop`` carries and ``vmap`` batches).

Shapes: n variables, m constraints, F = ``filter_size`` filter entries, H = ``max_iter + 1``
history rows (1 without ``keep_history``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

HIST_FIELDS = (
    "obj",
    "inf_pr",
    "inf_du",
    "mu",
    "d_norm",
    "reg",
    "alpha_du",
    "alpha_pr",
    "ls",
    "kind",
    "compl",
    "resto_iters",
    "n_fact",
    "mode",
    "res_ratio",
)
INT_FIELDS = ("ls", "kind", "resto_iters", "n_fact", "mode")


class Prob(NamedTuple):
    """Per-instance numeric data of the scaled problem (everything a batch may vary)."""

    p: Any
    xl: jax.Array  # (n,) relaxed variable bounds
    xu: jax.Array
    gl: jax.Array  # (m,) relaxed, scaled constraint bounds
    gu: jax.Array
    hxl: jax.Array  # (n,) finite lower bound on x (not fixed)
    hxu: jax.Array
    fixed: jax.Array  # (n,) xl == xu
    eq: jax.Array  # (m,) gl == gu
    hsl: jax.Array  # (m,) inequality row with finite lower bound
    hsu: jax.Array
    free: jax.Array  # (m,) inequality row without finite bounds
    sf: jax.Array  # () objective scaling
    sg: jax.Array  # (m,) constraint scaling


class Iterate(NamedTuple):
    """Primal-dual iterate: x (n,), slacks s (m,), multipliers y (m,), bound multipliers of x
    (zl, zu: (n,)) and of s (vl, vu: (m,))."""

    x: jax.Array
    s: jax.Array
    y: jax.Array
    zl: jax.Array
    zu: jax.Array
    vl: jax.Array
    vu: jax.Array


class Evals(NamedTuple):
    f: jax.Array  # () scaled objective
    g: jax.Array  # (m,) scaled constraints
    grad: jax.Array  # (n,) scaled gradient
    jac: jax.Array  # (nnz_jac,) scaled Jacobian values


class Globalization(NamedTuple):
    """The filter (Sec. 2.3) and the inertia correction's memory (Sec. 3.1) of the problem being
    solved; the restoration phase starts its own and stashes the original problem's."""

    filt_theta: jax.Array  # (F,) filter entries (theta, phi), +inf where unused
    filt_phi: jax.Array
    filt_n: jax.Array  # () entries added (the ring buffer's write position mod F)
    theta_min: jax.Array
    theta_max: jax.Array
    dw_last: jax.Array  # () the last nonzero delta_w of Algorithm IC
    pert: jax.Array  # (3,) IPOPT's degeneracy test state, see inertia.finalize_test


def fresh_globalization(size: int, theta_min, theta_max) -> Globalization:
    """An empty filter of ``size`` entries and no perturbation history."""
    inf = jnp.full(size, jnp.inf)
    return Globalization(
        filt_theta=inf,
        filt_phi=inf,
        filt_n=jnp.zeros((), jnp.int32),
        theta_min=jnp.asarray(theta_min, float),
        theta_max=jnp.asarray(theta_max, float),
        dw_last=jnp.zeros(()),
        pert=jnp.zeros(3, jnp.int32),
    )


class Resto(NamedTuple):
    """Restoration-phase variables and what the return to the original problem needs."""

    on: jax.Array  # the iteration is solving the restoration problem
    fresh: jax.Array  # its first iteration (no barrier update then, as IPOPT)
    p: jax.Array  # (m,) positive / negative parts of c(x, s), rows with p, n: ~free
    n: jax.Array
    zp: jax.Array  # (m,) their bound multipliers
    zn: jax.Array
    xR: jax.Array  # (n,) reference point of the proximity term
    dr: jax.Array  # (n,) diagonal of D_R^2 = 1/max(1, |x_R|)^2 (0 when not in restoration)
    s0: jax.Array  # slacks and bound multipliers where the restoration started
    z0: tuple
    mu_orig: jax.Array  # the original problem's mu, reference point, filter and
    theta_ref: jax.Array  # regularisation, stashed for the return
    phi_ref: jax.Array
    inf_ref: jax.Array
    outer: Globalization


def resto_off(R: Resto) -> Resto:
    """The inactive restoration state (p = n = 1 keep the masked logarithms finite)."""
    return R._replace(
        on=jnp.zeros((), bool),
        fresh=jnp.zeros((), bool),
        p=jnp.ones_like(R.p),
        n=jnp.ones_like(R.n),
        zp=jnp.zeros_like(R.zp),
        zn=jnp.zeros_like(R.zn),
        dr=jnp.zeros_like(R.dr),
    )


def inactive_resto(n: int, m: int, filter_size: int) -> Resto:
    """The restoration state of a solve that has not entered the restoration phase."""
    zm, zn = jnp.zeros(m), jnp.zeros(n)
    z0 = jnp.zeros(())
    return resto_off(
        Resto(
            on=z0 > 0,
            fresh=z0 > 0,
            p=zm,
            n=zm,
            zp=zm,
            zn=zm,
            xR=zn,
            dr=zn,
            s0=zm,
            z0=(zn, zn, zm, zm),
            mu_orig=z0,
            theta_ref=z0,
            phi_ref=z0,
            inf_ref=z0,
            outer=fresh_globalization(filter_size, 0.0, 0.0),
        )
    )


class Watchdog(NamedTuple):
    """IPOPT's watchdog (Chamberlain et al.): after ``watchdog_shortened_iter_trigger``
    consecutive shortened steps, full steps are taken tentatively (up to
    ``watchdog_trial_iter_max``) and judged against the point where the watchdog started; if
    none is acceptable, the iterate goes back there and backtracks from half the step."""

    shortened: jax.Array  # consecutive shortened steps
    on: jax.Array
    trials: jax.Array
    it: Iterate
    ev: Evals
    theta: jax.Array  # merit and directional derivative at the watchdog's start
    phi: jax.Array
    gd: jax.Array
    skip_first: jax.Array  # backtrack without trying the full step (after a watchdog reset)


class AdaptiveMu(NamedTuple):
    """State of the adaptive barrier update (``mu_oracle``): the mode and the filter of the
    (f, theta) pairs of the points accepted in free mode, F = ``filter_size`` entries, +inf
    where unused."""

    free: jax.Array  # () free mode (mu from the oracle), else fixed (monotone) mode
    mu_max: jax.Array  # () mu_max_fact times the average complementarity at the start point
    filt_f: jax.Array  # (F,) scaled objective of the entries
    filt_theta: jax.Array  # (F,) their constraint violation ||c||_1
    filt_n: jax.Array  # () entries written (the ring buffer's position when no slot is free)


class State(NamedTuple):
    """Loop state of the IPM; ``status`` holds a ``Status`` code (``Status.Running`` until a
    termination test fires). ``am`` is the adaptive barrier update's state with
    ``mu_strategy="adaptive"`` and None (no leaves) with "monotone"."""

    it: Iterate
    ev: Evals
    mu: jax.Array
    k: jax.Array
    done: jax.Array
    status: jax.Array
    gl: Globalization
    n_acceptable: jax.Array
    tiny_count: jax.Array
    cur_acc: jax.Array  # the current iterate passes the acceptable-level tests
    acc_it: Iterate  # the last acceptable iterate (IPOPT's fallback when the line search
    acc_ev: Evals  # and restoration fail, Sec. 3.3) and its evaluations
    has_acc: jax.Array
    resto_iters: jax.Array
    rs: Resto
    wd: Watchdog
    hist: dict  # HIST_FIELDS -> (H,) arrays, row k = iteration k
    terms: Any  # ``termination.ErrorTerms`` of the iterate (set by the termination check)
    am: AdaptiveMu | None = None


class StepInfo(NamedTuple):
    """What one iteration adds to the history (IPOPT's log columns and the step's internals)."""

    mu: jax.Array
    d_norm: jax.Array
    reg: jax.Array
    alpha_du: jax.Array
    alpha_pr: jax.Array
    ls: jax.Array
    kind: jax.Array
    resto_iters: jax.Array
    n_fact: jax.Array
    mode: jax.Array
    res_ratio: jax.Array


def tree_where(cond, a, b):
    """Leafwise ``jnp.where(cond, a, b)`` of two pytrees of the same structure."""
    return jax.tree.map(lambda a_, b_: jnp.where(cond, a_, b_), a, b)


class Direction(NamedTuple):
    """A primal-dual search direction: dx (n,), ds, dy, and the restoration phase's dp, dn (m,)."""

    dx: jax.Array
    ds: jax.Array
    dy: jax.Array
    dp: jax.Array
    dn: jax.Array


class Solution(NamedTuple):
    """A finished solve in the user's units: x, bound multipliers zl, zu (n,), constraint
    multipliers lam (m,) (IPOPT's sign convention), objective f, constraints g (m,), gradient
    grad (n,) and Jacobian values jac at x, the ``Status`` code, the iteration count k, the
    history arrays, the restoration iterations and the mask of fixed variables."""

    x: jax.Array
    lam: jax.Array
    zl: jax.Array
    zu: jax.Array
    f: jax.Array
    g: jax.Array
    grad: jax.Array
    jac: jax.Array
    status: jax.Array
    k: jax.Array
    hist: dict
    resto_iters: jax.Array
    fixed: jax.Array
