"""The numpy evaluation of jaxprs that sparsity detection uses: the same values as XLA's on every
primitive the transcription's derivatives use, and on the rest it implements."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.derivatives import jaxpr_numpy
from jaxhumanoid.derivatives.stagewise import _local_functions
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.strategy.problem import pattern_params

X = np.linspace(-0.9, 1.3, 12)


def _functions():
    idx = np.array([3, 0, 7, 7, 11])

    def gather_scatter(x):
        y = x[idx] * x[:5]  # gather; its transpose in a gradient is a scatter-add
        return jnp.zeros(12).at[idx].add(y) + x.at[2].set(1.0)

    def windows(x):
        m = x.reshape(3, 4)
        return jnp.concatenate(
            [
                jnp.cumsum(m, axis=1).ravel(),
                jnp.cumprod(m[::-1], axis=0).ravel(),
                jax.lax.pad(x, 0.5, [(2, -1, 1)]),
                jax.lax.dynamic_slice(x, (3,), (4,)),
                jnp.flip(m, axis=1)[:, ::2].ravel(),
            ]
        )

    def algebra(x):
        a, b = x.reshape(3, 4), x[:8].reshape(4, 2)
        batched = jnp.einsum("kij,kjl->kil", x[:8].reshape(2, 2, 2), x[4:].reshape(2, 2, 2))
        return jnp.concatenate([(a @ b).ravel(), batched.ravel(), jnp.max(a, axis=0), jnp.linalg.norm(a, axis=1)])

    def elementwise(x):
        soft = jnp.logaddexp2(x, -x) + jnp.tanh(3 * x) * jnp.sin(x) ** 3 - jnp.exp(-(x**2)) / (1 + jnp.cos(x) ** 2)
        return jnp.where(x > 0.1, soft, jnp.abs(x) ** 1.5) + jnp.clip(x, -0.5, 0.5) + jnp.arctan2(x, 1.3)

    def control(x):
        total = jax.lax.fori_loop(0, 3, lambda i, c: c * 0.5 + jnp.sum(x) * i, 0.0)
        carry, ys = jax.lax.scan(lambda c, xi: (c + xi, c * xi), 0.0, x)
        return jnp.concatenate([ys, jnp.stack([total, carry, jax.lax.cond(x[0] > 0, jnp.sin, jnp.cos, x[1])])])

    return {f.__name__: f for f in (gather_scatter, windows, algebra, elementwise, control)}


@pytest.mark.parametrize("name", list(_functions()))
@pytest.mark.parametrize("transform", ["value", "jacfwd", "hessian"])
def test_values_equal_xla_s(name, transform):
    fun = _functions()[name]
    if transform == "jacfwd":
        fun = jax.jacfwd(fun)
    elif transform == "hessian":
        fun = jax.hessian(lambda x, f=fun: jnp.sum(jnp.sin(f(x))))
    expected = np.asarray(jax.jit(fun)(X))
    got = jaxpr_numpy.evaluator(fun, X)(X)
    np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("pseudo_static", [False, True])
def test_interval_derivatives_equal_xla_s(pseudo_static):
    # the dense derivatives sparsity detection takes of one interval (derivatives/stagewise.py)
    layout = tr.Layout(N=10, active=(2, 5), augmented=True, clearance=True, pseudo_static=pseudo_static, n_links=5)
    con_r, cost = _local_functions(layout)
    p = pattern_params(5)
    nr = tr.midpoint_map(layout).shape[0]
    r = np.random.default_rng(0).normal(size=nr) * 0.3
    lam = np.random.default_rng(1).normal(size=layout.n_con)
    for fun, args in (
        (jax.jacfwd(con_r), (r, p)),
        (jax.hessian(lambda r, lam, p: jnp.dot(lam, con_r(r, p))), (r, lam, p)),
    ):
        expected = np.asarray(jax.jit(fun)(*args))
        got = jaxpr_numpy.evaluator(fun, *args)(*args)
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())


def test_an_unsupported_primitive_falls_back_or_raises():
    fun = jnp.sort  # sort is not interpreted
    with pytest.raises(jaxpr_numpy.Unsupported, match="sort"):
        jaxpr_numpy.evaluator(fun, X)(X)
    call = jaxpr_numpy.cached_evaluator(fun, fallback=jax.jit)
    np.testing.assert_array_equal(np.asarray(call(X)), np.sort(X))
