"""The jitted pieces of the Lagrangian that the sensitivities need, compiled once per NLP.

With IPOPT's conventions L(x, lam; p) = f(x, p) + lam . g(x, p) (the bound terms do not depend
on p). Every function is a ``jax.jit`` closure over one NLP, kept in ``nlp.cache`` under
``CACHE_KEY``, so that repeated factorisations and adjoints of one problem skip tracing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

CACHE_KEY = "diff.lagrangian"


class LagrangianFns(NamedTuple):
    """Jitted functions of one NLP (n variables, m constraints; p a pytree like problem.p).

    grad_lag(x, lam, p) -> (n,) grad_x L;
    rhs_jvp(x, lam, p, dp) -> ((n,), (m,)): d_p grad_x L . dp and d_p g . dp at fixed x, lam;
    pullback(x, lam, p, v_x, v_lam) -> pytree like p: grad_p [v_x . grad_x L + v_lam . g];
    lag_grad_p(x, lam, p) -> pytree like p: grad_p L (the envelope theorem);
    f_jvp(x, p, dx, dp) -> (): df along (dx, dp);
    f, g, jac, hess: the NLP's own f(x, p), g(x, p), jac_values(x, p), hess_values(x, lam, sigma, p).
    """

    grad_lag: Callable
    rhs_jvp: Callable
    pullback: Callable
    lag_grad_p: Callable
    f_jvp: Callable
    f: Callable
    g: Callable
    jac: Callable
    hess: Callable


def _grad_lag(nlp, x, lam, p):
    return jax.grad(lambda xx: nlp.f(xx, p) + jnp.dot(lam, nlp.g(xx, p)))(x)


def _build(nlp) -> LagrangianFns:
    def rhs_jvp(x, lam, p, dp):
        _, (dgl, dg) = jax.jvp(lambda pp: (_grad_lag(nlp, x, lam, pp), nlp.g(x, pp)), (p,), (dp,))
        return dgl, dg

    def pullback(x, lam, p, v_x, v_lam):
        return jax.grad(lambda pp: jnp.dot(v_x, _grad_lag(nlp, x, lam, pp)) + jnp.dot(v_lam, nlp.g(x, pp)))(p)

    def lag_grad_p(x, lam, p):
        return jax.grad(lambda pp: nlp.f(x, pp) + jnp.dot(lam, nlp.g(x, pp)))(p)

    def f_jvp(x, p, dx, dp):
        return jax.jvp(nlp.f, (x, p), (dx, dp))[1]

    return LagrangianFns(
        grad_lag=jax.jit(lambda x, lam, p: _grad_lag(nlp, x, lam, p)),
        rhs_jvp=jax.jit(rhs_jvp),
        pullback=jax.jit(pullback),
        lag_grad_p=jax.jit(lag_grad_p),
        f_jvp=jax.jit(f_jvp),
        f=jax.jit(lambda x, p: nlp.f(x, p)),
        g=jax.jit(lambda x, p: nlp.g(x, p)),
        jac=jax.jit(lambda x, p: nlp.jac_values(x, p)),
        hess=jax.jit(lambda x, lam, sigma, p: nlp.hess_values(x, lam, sigma, p)),
    )


def lagrangian_fns(nlp) -> LagrangianFns:
    """The NLP's ``LagrangianFns``, built on first use and kept in ``nlp.cache``."""
    if CACHE_KEY not in nlp.cache:
        nlp.cache[CACHE_KEY] = _build(nlp)
    return nlp.cache[CACHE_KEY]
