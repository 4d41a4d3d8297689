"""Sparse derivative layer: exact patterns, valid colourings, compressed values equal dense ones."""

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid import derivatives as D
from jaxhumanoid.derivatives import colouring as C
from jaxhumanoid.derivatives import local as L


def banded_pattern(n, b):
    i, j = np.nonzero(np.abs(np.arange(n)[:, None] - np.arange(n)[None, :]) <= b)
    return i, j


def banded_fun(b):
    """y_i = sum_{|k| <= b} w_k sin(x_{i+k}) x_i: Jacobian pattern |i - j| <= b."""
    w = np.arange(1.0, 2 * b + 2)

    def f(x):
        xp = jnp.pad(x, b)
        return x * sum(w[k] * jnp.sin(xp[k : k + x.size]) for k in range(2 * b + 1))

    return f


def random_pattern(shape, density, seed):
    mask = np.random.default_rng(seed).random(shape) < density
    return np.nonzero(mask)


def assert_pattern(rows, cols, mask):
    assert rows.dtype == np.int64 and cols.dtype == np.int64
    np.testing.assert_array_equal(D.pattern_to_dense(rows, cols, mask.shape), mask)


# --- sparsity patterns -------------------------------------------------------------------------

IDX = np.array([3, 0, 7, 7, 11])
A_EINSUM = np.array([[1.0, 0.0, 2.0], [0.0, 0.0, 3.0], [4.0, 0.0, 0.0], [0.0, 0.0, 5.0]])


def _stage(z, p):
    return jnp.stack([jnp.sin(z[0]) * z[1] + p, jnp.tanh(z[2]) * z[0], z[1] ** 2])


def _expected(name):
    """Hand-derived patterns of the functions in PATTERN_CASES."""
    m = np.zeros(
        {
            "cumsum": (6, 6),
            "logaddexp2": (6, 12),
            "fancy": (5, 12),
            "einsum": (9, 12),
            "vmap": (12, 12),
            "cancel": (2, 4),
        }[name],
        dtype=bool,
    )
    if name == "cumsum":
        m[np.tril_indices(6)] = True
    elif name == "logaddexp2":
        m[np.arange(6), 2 * np.arange(6)] = m[np.arange(6), 2 * np.arange(6) + 1] = True
    elif name == "fancy":
        m[np.arange(5), IDX] = True
    elif name == "einsum":
        for i in range(3):  # y[i, k] = sum_j X[i, j] A[j, k], X = x.reshape(3, 4)
            for k in range(3):
                m[3 * i + k, 4 * i + np.nonzero(A_EINSUM[:, k])[0]] = True
    elif name == "vmap":
        local = np.array([[1, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=bool)
        for k in range(4):
            m[3 * k : 3 * k + 3, 3 * k : 3 * k + 3] = local
    elif name == "cancel":
        m[0, 2] = True  # cos(theta_3 - theta_2) depends on q_3 only
        m[1, [1, 2, 3]] = True
    return m


PATTERN_CASES = {
    "cumsum": lambda x: jnp.sin(jnp.cumsum(x)),
    "logaddexp2": lambda x: jnp.logaddexp2(x[::2], x[1::2]),
    "fancy": lambda x: x[IDX] ** 2 + jnp.tanh(x[IDX]),
    "einsum": lambda x: jnp.einsum("ij,jk->ik", jnp.sin(x.reshape(3, 4)), A_EINSUM).ravel(),
    "vmap": lambda x: jax.vmap(_stage, in_axes=(0, None))(x.reshape(4, 3), 2.0).ravel(),
    "cancel": lambda x: jnp.stack([jnp.cos(jnp.cumsum(x)[2] - jnp.cumsum(x)[1]), jnp.sin(jnp.cumsum(x)[3] - x[0])]),
}
N_IN = {"cumsum": 6, "logaddexp2": 12, "fancy": 12, "einsum": 12, "vmap": 12, "cancel": 4}


@pytest.mark.parametrize("name", sorted(PATTERN_CASES))
def test_jacobian_sparsity_exact(name):
    rows, cols = D.jacobian_sparsity(PATTERN_CASES[name], N_IN[name])
    assert_pattern(rows, cols, _expected(name))
    assert np.all(np.diff(rows * N_IN[name] + cols) > 0)  # sorted row-major


def test_jacobian_sparsity_banded_with_args():
    f = banded_fun(2)
    rows, cols = D.jacobian_sparsity(lambda x, s: s * f(x), 15, 3.0)
    assert_pattern(rows, cols, D.pattern_to_dense(*banded_pattern(15, 2), (15, 15)))


def test_hessian_sparsity_chain_and_lagrangian():
    def chain(x):
        return jnp.sum(jnp.cos(x[1:] * x[:-1])) + jnp.sum(x[::2] ** 3)

    n = 9
    rows, cols = D.hessian_sparsity(chain, n)
    assert np.all(rows >= cols)
    assert_pattern(rows, cols, np.tril(D.pattern_to_dense(*banded_pattern(n, 1), (n, n))))

    def lagrangian(x, lam, sigma):  # objective x0^2 and constraints x1 x3, logaddexp2(x2, x4)
        g = jnp.stack([x[1] * x[3], jnp.logaddexp2(x[2], x[4])])
        return sigma * x[0] ** 2 + lam @ g

    rows, cols = D.hessian_sparsity(lagrangian, 5, np.array([0.7, -1.3]), 1.0)
    expected = np.zeros((5, 5), dtype=bool)
    expected[0, 0] = expected[3, 1] = expected[2, 2] = expected[4, 2] = expected[4, 4] = True
    assert_pattern(rows, cols, expected)


def test_sparsity_rejects_bad_input():
    with pytest.raises(ValueError, match="fun"):
        D.hessian_sparsity(lambda x: x**2, 3)
    with pytest.raises(ValueError, match="fun"):
        D.jacobian_sparsity(jnp.sqrt, 3)  # derivative at negative samples: not finite
    with pytest.raises(ValueError, match="points"):
        D.jacobian_sparsity(jnp.sin, 3, points=np.ones((2, 4)))
    with pytest.raises(ValueError, match="rows/cols"):
        D.check_pattern([0, 0], [1, 1], (2, 2))
    with pytest.raises(ValueError, match="cols"):
        D.check_pattern([0], [5], (2, 2))
    with pytest.raises(ValueError, match="lower triangle"):
        D.check_pattern([0], [1], (2, 2), lower=True)


# --- colourings --------------------------------------------------------------------------------


@pytest.mark.parametrize("b", [1, 2, 4])
def test_banded_colourings_are_valid_and_small(b):
    n = 40
    rows, cols = banded_pattern(n, b)
    colours = D.colour_columns(rows, cols, (n, n))
    assert D.is_valid_column_colouring(rows, cols, (n, n), colours)
    assert D.num_colours(colours) <= 2 * b + 1
    low = rows >= cols
    star = D.star_colouring(rows[low], cols[low], n)
    assert D.is_valid_star_colouring(rows[low], cols[low], n, star)
    assert D.num_colours(star) <= 2 * b + 1


@pytest.mark.parametrize("order", C.ORDERS + ("best",))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_colourings_are_valid(order, seed):
    rows, cols = random_pattern((50, 60), 0.08, seed)
    colours = D.colour_columns(rows, cols, (50, 60), order=order)
    assert D.is_valid_column_colouring(rows, cols, (50, 60), colours)
    r, c = random_pattern((60, 60), 0.06, seed + 10)
    low = r >= c
    star = D.star_colouring(r[low], c[low], 60, order=order)
    assert D.is_valid_star_colouring(r[low], c[low], 60, star)


def test_invalid_colourings_are_detected():
    rows, cols = banded_pattern(10, 1)
    assert not D.is_valid_column_colouring(rows, cols, (10, 10), np.arange(10) % 2)
    # path 0-1-2-3 coloured 0,1,0,1: a proper colouring but not a star colouring
    r, c = np.array([1, 2, 3]), np.array([0, 1, 2])
    assert not D.is_valid_star_colouring(r, c, 4, np.array([0, 1, 0, 1]))
    assert D.is_valid_star_colouring(r, c, 4, np.array([0, 1, 2, 0]))
    with pytest.raises(ValueError, match="colours"):
        D.sparse_jacobian(jnp.sin, rows, cols, 10, colouring=np.zeros(10, dtype=int))
    with pytest.raises(ValueError, match="colours"):
        D.sparse_hessian(lambda x: jnp.sum(x), r, c, 4, colouring=np.array([0, 1, 0, 1]))
    with pytest.raises(ValueError, match="order"):
        D.colour_columns(rows, cols, (10, 10), order="random")


def test_colouring_is_fast_at_problem_size():
    # 100 stages of 30 variables, block-bidiagonal Jacobian: 3000 columns, ~50k nonzeros
    rng = np.random.default_rng(0)
    blocks = [np.nonzero(rng.random((20, 60)) < 0.45) for _ in range(99)]
    rows = np.concatenate([r + 20 * k for k, (r, c) in enumerate(blocks)])
    cols = np.concatenate([c + 30 * k for k, (r, c) in enumerate(blocks)])
    shape = (1980, 3000)
    start = time.perf_counter()
    colours = D.colour_columns(rows, cols, shape)
    r, c = np.unique(np.concatenate([np.maximum(rows, cols)[:, None], np.minimum(rows, cols)[:, None]], 1), axis=0).T
    star = D.star_colouring(r, c, 3000)
    elapsed = time.perf_counter() - start
    assert rows.size > 40_000
    assert D.is_valid_column_colouring(rows, cols, shape, colours)
    assert D.is_valid_star_colouring(r, c, 3000, star)
    assert elapsed < 20.0


# --- compressed values -------------------------------------------------------------------------


def _close(a, b, tol=1e-12):
    scale = max(1.0, float(np.max(np.abs(b))))
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=0, atol=tol * scale)


def test_sparse_jacobian_matches_dense():
    n = 30

    def g(x, p):
        theta = jnp.cumsum(x[:5])
        head = jnp.einsum("i,i->", jnp.cos(theta), p["w"]) * jnp.tanh(x[5:10])
        return jnp.concatenate([head, p["s"] * banded_fun(2)(x), jnp.logaddexp2(x[IDX], -x[IDX + 1])])

    p = {"w": jnp.arange(1.0, 6.0), "s": 0.5}
    rows, cols = D.jacobian_sparsity(g, n, p)
    jac_values = jax.jit(D.sparse_jacobian(g, rows, cols, n))
    for seed in range(3):
        x = jnp.asarray(np.random.default_rng(seed).standard_normal(n))
        _close(jac_values(x, p), jax.jacfwd(g)(x, p)[rows, cols])


def test_sparse_hessian_matches_dense_for_lagrangian():
    n, m = 20, 19

    def constraints(x, p):
        return p["a"] * jnp.sin(x[1:] * x[:-1]) + jnp.tanh(jnp.cumsum(x)[1:] - jnp.cumsum(x)[:-1])

    def lagrangian(x, lam, sigma, p):
        return sigma * jnp.sum(x**4) + lam @ constraints(x, p)

    p = {"a": 1.7}
    rng = np.random.default_rng(0)
    rows, cols = D.hessian_sparsity(lagrangian, n, rng.standard_normal(m), 1.0, p)
    hess_values = jax.jit(D.sparse_hessian(lagrangian, rows, cols, n))
    for _ in range(3):
        x, lam = jnp.asarray(rng.standard_normal(n)), jnp.asarray(rng.standard_normal(m))
        _close(hess_values(x, lam, 0.3, p), jax.hessian(lagrangian)(x, lam, 0.3, p)[rows, cols])


def test_sparse_values_with_explicit_colouring_and_bad_x():
    rows, cols = banded_pattern(12, 1)
    f = banded_fun(1)
    colours = np.arange(12) % 3
    jac_values = D.sparse_jacobian(f, rows, cols, 12, colouring=colours)
    x = jnp.linspace(-1.0, 1.0, 12)
    _close(jac_values(x), jax.jacfwd(f)(x)[rows, cols])
    with pytest.raises(ValueError, match="x"):
        jac_values(jnp.ones(11))
    with pytest.raises(ValueError, match="fun"):
        D.sparse_hessian(f, rows[rows >= cols], cols[rows >= cols], 12)(x)


def test_stage_helpers_match_dense_vmapped_derivatives():
    K, nz, mc = 6, 4, 3

    def stage_con(z, p):
        theta = jnp.cumsum(z[:3])
        return jnp.stack([jnp.sin(theta[2]) * z[3], p * jnp.logaddexp2(z[0], z[3]), jnp.tanh(z[1] * z[2])])

    def stage_lag(z, lam_k, p):
        return lam_k @ stage_con(z, p) + 0.5 * z[3] ** 2

    rng = np.random.default_rng(3)
    p = 1.3
    jr, jc = D.jacobian_sparsity(stage_con, nz, p)
    hr, hc = D.hessian_sparsity(stage_lag, nz, rng.standard_normal(mc), p)
    jac = jax.jit(D.stage_jacobian(stage_con, jr, jc, nz, args_axes=None))
    hess = jax.jit(D.stage_hessian(stage_lag, hr, hc, nz, args_axes=(0, None)))

    Z = jnp.asarray(rng.standard_normal((K, nz)))
    lam = jnp.asarray(rng.standard_normal((K, mc)))

    def all_con(z_flat):
        return jax.vmap(stage_con, in_axes=(0, None))(z_flat.reshape(K, nz), p).ravel()

    def all_lag(z_flat):
        return jnp.sum(jax.vmap(stage_lag, in_axes=(0, 0, None))(z_flat.reshape(K, nz), lam, p))

    dense_j = jax.jacfwd(all_con)(Z.ravel())
    dense_h = jax.hessian(all_lag)(Z.ravel())
    jv, hv = jac(Z, p), hess(Z, lam, p)
    assert jv.shape == (K, jr.size) and hv.shape == (K, hr.size)
    for k in range(K):
        _close(jv[k], dense_j[mc * k + jr, nz * k + jc])
        _close(hv[k], dense_h[nz * k + hr, nz * k + hc])
    with pytest.raises(ValueError, match="Z"):
        jac(Z.ravel(), p)
    with pytest.raises(ValueError, match="args_axes"):
        hess(Z, lam)


def _grouped_case():
    """An interval-like function of r = (a, b) with a = r[:2] nonlinear and b = r[2:] entering
    through products with terms of a, its groups, and a quadratic cost."""

    def con_ab(a, b, p):
        rows = [a[0] * jnp.sin(a[1]) + b[0], a[1] ** 2 * b[1] + p * b[2], b[3] * a[0], b[0] + b[1], a[0] * a[1]]
        return jnp.stack(rows)

    def con_r(r, p):
        return con_ab(r[:2], r[2:], p)

    groups = L.ColumnGroups((np.array([0, 1]), np.array([2, 3, 4, 5])), lambda zs, p: con_ab(zs[0], zs[1], p))

    def cost(w, p, last):
        return jnp.sum(w**2) * jnp.where(last, 2.0, 1.0)

    return con_r, groups, cost


def test_grouped_sweeps_equal_joint_ones_and_can_fail():
    con_r, groups, cost = _grouped_case()
    M = np.eye(6)
    joint = L.local_derivatives(con_r, M, cost, 0.7)
    grouped = L.local_derivatives(con_r, M, cost, 0.7, groups=groups)
    assert np.array_equal(joint.jac_rows, grouped.jac_rows) and np.array_equal(joint.hess_cols, grouped.hess_cols)
    rng = np.random.default_rng(0)
    W, lam, last = jnp.asarray(rng.normal(size=(3, 6))), jnp.asarray(rng.normal(size=(3, 5))), jnp.array([0, 0, 1]) == 1
    _close(grouped.jacobian(W, 0.7), joint.jacobian(W, 0.7))
    _close(grouped.hessian(W, lam, 0.5, last, 0.7), joint.hessian(W, lam, 0.5, last, 0.7))
    assert grouped.n_hess_colours >= 2 and grouped.n_jac_colours >= joint.n_jac_colours
    # a group function that is not con_r is caught when the derivatives are built
    wrong = L.ColumnGroups(groups.index, lambda zs, p: groups.con(zs, p) * jnp.array([1.0, 1.0, 1.0, 1.0, 1.1]))
    with pytest.raises(ValueError, match="groups.con"):
        L.local_derivatives(con_r, M, cost, 0.7, groups=wrong)


def test_column_groups_must_partition_the_columns():
    with pytest.raises(ValueError, match="partition"):
        L.ColumnGroups((np.array([0, 1]), np.array([1, 2])), lambda zs, p: zs[0])
