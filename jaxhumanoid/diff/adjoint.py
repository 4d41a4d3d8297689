"""``make_solve``: the optimal trajectory x*(p) as a JAX function with a ``jax.custom_vjp``.

The forward pass solves the NLP at p, with IPOPT (``solver="ipopt"``: a ``jax.pure_callback``
around a warm-started re-solve, ``resolve``) or with the own interior-point method
(``solver="ipm"``: the jitted IPM core itself, traced like any JAX function). The backward pass
is the adjoint of the reduced KKT system at the solution (``KKTSensitivity.adjoint``, a
``jax.pure_callback``) followed by one reverse-mode pullback through p:

    p_bar = -grad_p [v_x . grad_x L + v_lam . g](x*, lam*; p),   K [v_F; v_C] = [x_bar_F; 0].

Both callbacks are pure: their results depend only on their arguments. The warm start is an
argument, ``solve(p, warm)``, and every solve returns the KKT point it found, which the caller
may pass as the next warm start; nothing is kept between calls. The adjoint's callback makes no
JAX call (the NLP's values are evaluated before it, ``kkt_values``): a JAX dispatch from inside
a callback can deadlock JAX's CPU client with asynchronous dispatch. IPOPT's forward callback
cannot avoid one (IPOPT evaluates the NLP's jitted functions).
"""

from __future__ import annotations

import warnings
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.diff.kkt import KKTSensitivity, kkt_values
from jaxhumanoid.diff.lagrangian import lagrangian_fns
from jaxhumanoid.diff.resolve import continuation_solve, resolve_robust
from jaxhumanoid.diff.trees import as_float_tree
from jaxhumanoid.solvers.ipm.algorithm import solve as ipm_solve
from jaxhumanoid.solvers.ipm.options import as_float64, make_options
from jaxhumanoid.solvers.status import SUCCESS

SOLVERS = ("ipopt", "ipm")


class KKTPoint(NamedTuple):
    """A solution of the NLP with its multipliers (IPOPT's conventions) at the parameters p.

    x, z_l, z_u: (n,); lam_g: (m,); p: a pytree like problem.p; iterations: () solver
    iterations; success: () whether the solver converged. It serves as the warm start of the
    next solve (x and the multipliers; ``p`` is where a continuation starts).
    """

    x: Any
    lam_g: Any
    z_l: Any
    z_u: Any
    p: Any
    iterations: Any
    success: Any


def warm_start(result, p) -> KKTPoint:
    """The ``KKTPoint`` of an ``NLPResult`` solved at parameters ``p``."""
    return KKTPoint(
        x=np.asarray(result.x),
        lam_g=np.asarray(result.lam_g),
        z_l=np.asarray(result.z_l),
        z_u=np.asarray(result.z_u),
        p=p,
        iterations=np.int64(result.iterations),
        success=np.bool_(result.success),
    )


def _ipm_core(nlp, options):
    """jit of the IPM core returning (x, lam_g, z_l, z_u, iterations, success), kept in nlp.cache,
    and the options pytree it takes (float leaves traced; the static ones select the program)."""
    if "diff.ipm_forward" not in nlp.cache:
        codes = jnp.asarray(sorted(int(s) for s in SUCCESS), jnp.int32)

        def fn(x0, xl, xu, gl, gu, p, o):
            sol = ipm_solve(nlp, o, x0, xl, xu, gl, gu, p)
            return sol.x, sol.lam, sol.zl, sol.zu, sol.k.astype(jnp.int64), jnp.isin(sol.status, codes)

        nlp.cache["diff.ipm_forward"] = jax.jit(fn)
    return nlp.cache["diff.ipm_forward"], as_float64(make_options(options))


def _ipopt_forward(problem, options, strict: bool, max_rel_step):
    """Host function (p, warm) -> (x, lam_g, z_l, z_u, iterations, success) for pure_callback."""

    def forward(p, warm):
        if warm is None:
            res = resolve_robust(problem, p=p, options=options)
        else:
            point = KKTPoint(*warm, iterations=0, success=True)
            if max_rel_step is not None:
                res = continuation_solve(problem, point.p, point, p, max_rel_step=max_rel_step, options=options)
            else:
                res = resolve_robust(problem, p=p, warm=point, options=options)
        if not res.success:
            msg = f"make_solve: IPOPT returned {res.status}"
            if strict:
                raise RuntimeError(msg)
            warnings.warn(msg, RuntimeWarning, stacklevel=2)
        return res.x, res.lam_g, res.z_l, res.z_u, np.int64(res.iterations), np.bool_(res.success)

    return forward


def make_solve(
    problem,
    solver: str = "ipopt",
    options: dict | None = None,
    sc_tol: float = 1e-6,
    strict: bool = False,
    max_rel_step: float | None = None,
):
    """``solve(p, warm=None) -> (x*, KKTPoint)``, differentiable in p by ``jax.custom_vjp``
    (reverse mode: ``jax.grad``/``jax.vjp`` of losses of x*, also as ``KKTPoint.x``; cotangents of
    the multipliers are ignored).

    ``warm``: a ``KKTPoint`` (e.g. ``warm_start(result, p_result)`` or the one a previous solve
    returned) to start from, or None for a cold start from ``problem.bounds.x0``. With IPOPT the
    start is primal-dual (``resolve_robust``), and ``max_rel_step`` follows the branch of local
    optima from ``warm.p`` to p by ``continuation_solve`` (the OCP has several local optima and
    a long step can make a warm start jump to another one); ``strict=True`` raises when a solve
    fails, otherwise a failed solve warns. With the IPM the start is primal (``warm.x``), the
    options are IPM options, and a failed solve shows only in ``KKTPoint.success`` (the solve
    may run under tracing); ``max_rel_step`` and ``strict`` are not available.
    ``sc_tol``: strict-complementarity threshold of the adjoint's active set.
    """
    if solver not in SOLVERS:
        raise ValueError(f"solver: {solver!r} not in {SOLVERS}")
    if solver == "ipm" and (max_rel_step is not None or strict):
        raise ValueError("make_solve: max_rel_step and strict need solver='ipopt'")
    nlp, bounds = problem.nlp, problem.bounds
    if solver == "ipm" and np.any(bounds.xl == bounds.xu):
        raise ValueError("make_solve: the IPM reports no bound multipliers of fixed variables (xl == xu)")
    n, m = nlp.n, nlp.m
    f64 = jnp.float64
    vec = lambda k: jax.ShapeDtypeStruct((k,), f64)  # noqa: E731
    out_shapes = (vec(n), vec(m), vec(n), vec(n), jax.ShapeDtypeStruct((), jnp.int64), jax.ShapeDtypeStruct((), bool))
    p_struct = jax.tree.structure(problem.p)
    if solver == "ipopt":
        host_forward = _ipopt_forward(problem, options, strict, max_rel_step)

        def primal(p, warm):
            return jax.pure_callback(host_forward, out_shapes, p, warm, vmap_method="sequential")
    else:
        core, fopts = _ipm_core(nlp, options)
        xl, xu, gl, gu = (jnp.asarray(a, f64) for a in (bounds.xl, bounds.xu, bounds.gl, bounds.gu))

        def primal(p, warm):
            x0 = jnp.asarray(bounds.x0, f64) if warm is None else jnp.clip(warm[0], xl, xu)
            return core(x0, xl, xu, gl, gu, p, fopts)

    def host_adjoint(x, lam, zl, zu, p, values, ct):
        kkt = KKTSensitivity(problem, x=x, lam_g=lam, z_l=zl, z_u=zu, p=p, sc_tol=sc_tol, values=values)
        return kkt.adjoint(ct)

    pullback = lagrangian_fns(nlp).pullback

    @jax.custom_vjp
    def _solve(p, warm):
        return primal(p, warm)

    def fwd(p, warm):
        out = primal(p, warm)
        return out, (out[:4], p, warm)

    def bwd(saved, cts):
        (x, lam, zl, zu), p, warm = saved
        # the NLP's values are evaluated here, so that the callback itself makes no JAX call
        values = kkt_values(nlp, x, lam, p)
        v_x, v_lam = jax.pure_callback(
            host_adjoint, (vec(n), vec(m)), x, lam, zl, zu, p, values, cts[0], vmap_method="sequential"
        )
        dp = jax.tree.map(lambda a: -a, pullback(x, lam, p, v_x, v_lam))
        return dp, jax.tree.map(jnp.zeros_like, warm)

    _solve.defvjp(fwd, bwd)

    def solve(p, warm: KKTPoint | None = None):
        if jax.tree.structure(p) != p_struct:  # type: ignore[operator]  # PyTreeDef compares
            raise ValueError("solve: p must have the structure of problem.p (an OCPParams)")
        p = as_float_tree(p)
        w = None if warm is None else as_float_tree((warm.x, warm.lam_g, warm.z_l, warm.z_u, warm.p))
        x, lam, zl, zu, its, ok = _solve(p, w)
        return x, KKTPoint(x=x, lam_g=lam, z_l=zl, z_u=zu, p=p, iterations=its, success=ok)

    return solve
