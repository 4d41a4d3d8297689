"""Test problems for the NLP solvers, as ``NLP`` instances with known optima.

* Hock-Schittkowski problems (W. Hock, K. Schittkowski, "Test Examples for Nonlinear Programming
  Codes", 1981): HS001 (Rosenbrock with a bound), HS006, HS010, HS013 (degenerate: LICQ fails at
  the solution), HS035, HS071, HS076, HS100; dense patterns, derivatives by ``jax``.
* ``wachter_biegler``: the example of Waechter & Biegler (2000), "Failure of global convergence
  for a class of interior point methods", on which Newton steps cut by the fraction to the
  boundary stall: it needs the feasibility restoration phase.
* ``infeasible_disk``: a locally infeasible problem (restoration must report infeasibility).
* ``cartpole_swingup``: a staged optimal-control NLP (P parallel cart-poles, implicit midpoint
  rule as in (6) of the paper, box bounds, fixed initial/terminal states, a nonlinear path
  inequality per stage) whose stage-ordered KKT matrix is block-tridiagonal.

Each constructor returns ``(nlp, bounds, p, f_star)`` with ``f_star`` the known optimal value (None
where only a local solution is known).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.ocp.nlp import NLP, Bounds

INF = np.inf


def dense_nlp(name: str, n: int, m: int, f: Callable, g: Callable) -> NLP:
    """NLP with dense Jacobian and dense lower-triangular Hessian patterns; f(x, p), g(x, p).

    Constructors below return one cached NLP instance per problem, so that solvers caching their
    compiled code on the instance compile each problem once per process."""
    jr, jc = np.meshgrid(np.arange(m), np.arange(n), indexing="ij")
    hr, hc = np.tril_indices(n)

    def grad(x, p):
        return jax.grad(f)(x, p)

    def jac_values(x, p):
        return jax.jacfwd(g)(x, p).reshape(-1) if m else jnp.zeros(0)

    def hess_values(x, lam, sigma, p):
        def lag(x_):
            return sigma * f(x_, p) + (jnp.dot(lam, g(x_, p)) if m else 0.0)

        return jax.hessian(lag)(x)[hr, hc]

    return NLP(
        n=n,
        m=m,
        f=f,
        g=g if m else (lambda x, p: jnp.zeros(0)),
        grad=grad,
        jac_values=jac_values,
        hess_values=hess_values,
        jac_rows=jr.reshape(-1),
        jac_cols=jc.reshape(-1),
        hess_rows=hr,
        hess_cols=hc,
        var_stage=np.zeros(n, np.int64),
        con_stage=np.zeros(m, np.int64),
        name=name,
    )


def _cached(name, n, m, f, g):
    key = name
    if key not in _NLP_CACHE:
        _NLP_CACHE[key] = dense_nlp(name, n, m, f, g)
    return _NLP_CACHE[key]


_NLP_CACHE: dict = {}


def _b(x0, xl, xu, gl, gu):
    return Bounds(
        np.asarray(x0, float),
        np.asarray(xl, float),
        np.asarray(xu, float),
        np.asarray(gl, float),
        np.asarray(gu, float),
    )


def hs001():
    """Rosenbrock with x2 >= -1.5; f* = 0 at (1, 1)."""
    f = lambda x, p: 100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2
    nlp = _cached("hs001", 2, 0, f, None)
    return nlp, _b([-2.0, 1.0], [-INF, -1.5], [INF, INF], [], []), None, 0.0


def hs006():
    f = lambda x, p: (1.0 - x[0]) ** 2
    g = lambda x, p: jnp.array([10.0 * (x[1] - x[0] ** 2)])
    return _cached("hs006", 2, 1, f, g), _b([-1.2, 1.0], [-INF] * 2, [INF] * 2, [0.0], [0.0]), None, 0.0


def hs010():
    f = lambda x, p: x[0] - x[1]
    g = lambda x, p: jnp.array([-3.0 * x[0] ** 2 + 2.0 * x[0] * x[1] - x[1] ** 2 + 1.0])
    return _cached("hs010", 2, 1, f, g), _b([-10.0, 10.0], [-INF] * 2, [INF] * 2, [0.0], [INF]), None, -1.0


def hs013():
    """Degenerate (constraint qualification fails at x* = (1, 0)); f* = 1."""
    f = lambda x, p: (x[0] - 2.0) ** 2 + x[1] ** 2
    g = lambda x, p: jnp.array([(1.0 - x[0]) ** 3 - x[1]])
    return _cached("hs013", 2, 1, f, g), _b([-2.0, -2.0], [0.0, 0.0], [INF, INF], [0.0], [INF]), None, 1.0


def hs035():
    f = lambda x, p: (
        9.0
        - 8 * x[0]
        - 6 * x[1]
        - 4 * x[2]
        + 2 * x[0] ** 2
        + 2 * x[1] ** 2
        + x[2] ** 2
        + 2 * x[0] * x[1]
        + 2 * x[0] * x[2]
    )
    g = lambda x, p: jnp.array([x[0] + x[1] + 2.0 * x[2]])
    return (_cached("hs035", 3, 1, f, g), _b([0.5] * 3, [0.0] * 3, [INF] * 3, [-INF], [3.0]), None, 1.0 / 9.0)


def hs071(p=None):
    """HS071; parameters p = (product bound 25, sum-of-squares 40); f* = 17.0140173."""
    f = lambda x, p: x[0] * x[3] * (x[0] + x[1] + x[2]) + x[2]
    g = lambda x, p: jnp.array([jnp.prod(x) - p[0], jnp.sum(x**2) - p[1]])
    p = jnp.array([25.0, 40.0]) if p is None else jnp.asarray(p, float)
    return (
        _cached("hs071", 4, 2, f, g),
        _b([1.0, 5.0, 5.0, 1.0], [1.0] * 4, [5.0] * 4, [0.0, 0.0], [INF, 0.0]),
        p,
        17.0140172891,
    )


def hs076():
    f = lambda x, p: (
        x[0] ** 2
        + 0.5 * x[1] ** 2
        + x[2] ** 2
        + 0.5 * x[3] ** 2
        - x[0] * x[2]
        + x[2] * x[3]
        - x[0]
        - 3.0 * x[1]
        + x[2]
        - x[3]
    )
    g = lambda x, p: jnp.array([x[0] + 2 * x[1] + x[2] + x[3], 3 * x[0] + x[1] + 2 * x[2] - x[3], x[1] + 4 * x[2]])
    return (
        _cached("hs076", 4, 3, f, g),
        _b([0.5] * 4, [0.0] * 4, [INF] * 4, [-INF, -INF, 1.5], [5.0, 4.0, INF]),
        None,
        -4.681818181,
    )


def hs100():
    def f(x, p):
        return (
            (x[0] - 10) ** 2
            + 5 * (x[1] - 12) ** 2
            + x[2] ** 4
            + 3 * (x[3] - 11) ** 2
            + 10 * x[4] ** 6
            + 7 * x[5] ** 2
            + x[6] ** 4
            - 4 * x[5] * x[6]
            - 10 * x[5]
            - 8 * x[6]
        )

    def g(x, p):
        return jnp.array(
            [
                127 - 2 * x[0] ** 2 - 3 * x[1] ** 4 - x[2] - 4 * x[3] ** 2 - 5 * x[4],
                282 - 7 * x[0] - 3 * x[1] - 10 * x[2] ** 2 - x[3] + x[4],
                196 - 23 * x[0] - x[1] ** 2 - 6 * x[5] ** 2 + 8 * x[6],
                -4 * x[0] ** 2 - x[1] ** 2 + 3 * x[0] * x[1] - 2 * x[2] ** 2 - 5 * x[5] + 11 * x[6],
            ]
        )

    return (
        _cached("hs100", 7, 4, f, g),
        _b([1, 2, 0, 4, 0, 1, 1], [-INF] * 7, [INF] * 7, [0.0] * 4, [INF] * 4),
        None,
        680.6300573,
    )


def wachter_biegler():
    """min x1 s.t. x1^2 - x2 - 1 = 0, x1 - x3 - 0.5 = 0, x2, x3 >= 0, from (-2, 1, 1); f* = 1."""
    f = lambda x, p: x[0]
    g = lambda x, p: jnp.array([x[0] ** 2 - x[1] - 1.0, x[0] - x[2] - 0.5])
    return (
        _cached("wachter_biegler", 3, 2, f, g),
        _b([-2.0, 1.0, 1.0], [-INF, 0.0, 0.0], [INF] * 3, [0.0, 0.0], [0.0, 0.0]),
        None,
        1.0,
    )


def infeasible_disk():
    """x1^2 + x2^2 <= 1 and x1 + x2 >= 3: locally (and globally) infeasible."""
    f = lambda x, p: (x[0] - 1.0) ** 2 + x[1] ** 2
    g = lambda x, p: jnp.array([x[0] ** 2 + x[1] ** 2, x[0] + x[1]])
    return (
        _cached("infeasible_disk", 2, 2, f, g),
        _b([0.0, 0.0], [-INF] * 2, [INF] * 2, [-INF, 3.0], [1.0, INF]),
        None,
        None,
    )


HS_PROBLEMS = {
    "hs001": hs001,
    "hs006": hs006,
    "hs010": hs010,
    "hs013": hs013,
    "hs035": hs035,
    "hs071": hs071,
    "hs076": hs076,
    "hs100": hs100,
}


# --------------------------------------------------------------------------- staged OCP


def staged_nlp(name, N, nx, nu, stage_cost, terminal_cost, dynamics, path, n_path, p_default=None):
    """Build a staged NLP with variables [x_0, u_0, x_1, u_1, ..., x_{N-1}, u_{N-1}, x_N].

    Stage k (k < N) owns (x_k, u_k), the dynamics defect dynamics(x_k, u_k, x_{k+1}, p) (nx rows)
    and path(x_k, u_k, p) (n_path rows); stage N owns x_N. Jacobian and Hessian patterns are the
    dense per-stage blocks, merged into unique (row, col) pairs.
    """
    nw = nx + nu
    n = N * nw + nx
    nc = nx + n_path
    m = N * nc
    nv = nw + nx
    loc = np.arange(N)[:, None] * nw + np.concatenate([np.arange(nw), nw + np.arange(nx)])[None, :]  # (N, nv)

    def stage_c(v, p):
        x, u, xn = v[:nx], v[nx:nw], v[nw:]
        return jnp.concatenate([dynamics(x, u, xn, p), path(x, u, p)])

    def split(z):
        V = z[loc]  # (N, nv)
        return V, z[N * nw :]

    def f(z, p):
        V, xN = split(z)
        return jnp.sum(jax.vmap(lambda v: stage_cost(v[:nx], v[nx:nw], p))(V)) + terminal_cost(xN, p)

    def g(z, p):
        V, _ = split(z)
        return jax.vmap(lambda v: stage_c(v, p))(V).reshape(-1)

    # Jacobian: per stage dense (nc, nv), rows k*nc + i, cols loc[k, j]
    jr = (np.arange(N)[:, None, None] * nc + np.arange(nc)[None, :, None] + 0 * loc[:, None, :]).reshape(-1)
    jc = np.broadcast_to(loc[:, None, :], (N, nc, nv)).reshape(-1)

    def jac_values(z, p):
        V, _ = split(z)
        return jax.vmap(jax.jacfwd(lambda v: stage_c(v, p)))(V).reshape(-1)

    # Hessian: per-stage lower triangles of (nv x nv) blocks + terminal (nx x nx), merged
    a, b = np.tril_indices(nv)
    R = np.maximum(loc[:, a], loc[:, b]).reshape(-1)
    C = np.minimum(loc[:, a], loc[:, b]).reshape(-1)
    ta, tb = np.tril_indices(nx)
    R = np.concatenate([R, N * nw + ta])
    C = np.concatenate([C, N * nw + tb])
    pairs, inv = np.unique(np.stack([R, C], 1), axis=0, return_inverse=True)
    inv = inv.reshape(-1)

    def hess_values(z, lam, sigma, p):
        V, xN = split(z)
        L = lam.reshape(N, nc)

        def lag(v, l):
            return sigma * stage_cost(v[:nx], v[nx:nw], p) + jnp.dot(l, stage_c(v, p))

        Hs = jax.vmap(lambda v, l: jax.hessian(lag)(v, l))(V, L)[:, a, b].reshape(-1)
        Ht = jax.hessian(lambda x: sigma * terminal_cost(x, p))(xN)[ta, tb]
        return jnp.zeros(pairs.shape[0], dtype=Hs.dtype).at[inv].add(jnp.concatenate([Hs, Ht]))

    var_stage = np.concatenate([np.repeat(np.arange(N), nw), np.full(nx, N)])
    con_stage = np.repeat(np.arange(N), nc)
    return NLP(
        n=n,
        m=m,
        f=f,
        g=g,
        grad=jax.grad(f),
        jac_values=jac_values,
        hess_values=hess_values,
        jac_rows=jr,
        jac_cols=jc,
        hess_rows=pairs[:, 0],
        hess_cols=pairs[:, 1],
        var_stage=var_stage,
        con_stage=con_stage,
        name=name,
    )


def cartpole_swingup(N: int = 50, P: int = 1, T: float = 4.0, u_max: float = 20.0, p_max: float = 2.0):
    """P independent cart-poles (coupled through nothing but the stage structure) swung up from
    hanging (theta = 0) to upright (theta = pi) in time T with the implicit midpoint rule.

    Per cart-pole: state (pos, theta, vpos, vtheta), control force u. Variables per stage:
    5P; constraints per stage: 4P dynamics defects + P path inequalities |pos + l sin(theta)| <= 2.5.
    Initial and terminal states are fixed by bounds (fixed variables). p = (h, cart mass, pole mass,
    pole length, gravity). Returns (nlp, bounds, p, None).
    """
    nx, nu = 4 * P, P
    h = T / N
    p = jnp.array([h, 1.0, 0.3, 0.5, 9.81])

    def accel(x, u, p):
        mc, mp, l, grav = p[1], p[2], p[3], p[4]
        th, vth = x[1], x[3]
        s, c = jnp.sin(th), jnp.cos(th)
        thdd = (-grav * s - c * (u + mp * l * vth**2 * s) / (mc + mp)) / (l * (4.0 / 3.0 - mp * c**2 / (mc + mp)))
        xdd = (u + mp * l * (vth**2 * s - thdd * c)) / (mc + mp)
        return jnp.array([x[2], x[3], xdd, thdd])

    def f_all(x, u, p):
        X = x.reshape(P, 4)
        return jax.vmap(lambda xi, ui: accel(xi, ui, p))(X, u).reshape(-1)

    def dynamics(x, u, xn, p):
        return xn - x - p[0] * f_all(0.5 * (x + xn), u, p)

    def path(x, u, p):
        X = x.reshape(P, 4)
        return X[:, 0] + p[3] * jnp.sin(X[:, 1])

    def stage_cost(x, u, p):
        X = x.reshape(P, 4)
        return p[0] * (jnp.sum(u**2) + 0.1 * jnp.sum(X[:, 2:] ** 2))

    def terminal_cost(x, p):
        return 0.0 * jnp.sum(x)

    nlp = staged_nlp(f"cartpole_N{N}_P{P}", N, nx, nu, stage_cost, terminal_cost, dynamics, path, P)
    x_init = np.zeros(4)
    x_goal = np.array([0.0, np.pi, 0.0, 0.0])
    xl = np.tile(np.concatenate([np.tile([-p_max, -2 * np.pi, -INF, -INF], P), np.full(P, -u_max)]), N)
    xu = np.tile(np.concatenate([np.tile([p_max, 3 * np.pi, INF, INF], P), np.full(P, u_max)]), N)
    xl = np.concatenate([xl, np.tile(x_goal, P)])
    xu = np.concatenate([xu, np.tile(x_goal, P)])
    xl[:nx] = np.tile(x_init, P)
    xu[:nx] = np.tile(x_init, P)
    # initial guess: linear interpolation of the angle, zero controls
    t = np.linspace(0.0, 1.0, N + 1)
    nodes = []
    for k in range(N + 1):
        xs = np.tile(np.array([0.0, np.pi * t[k], 0.0, np.pi / T]), P)
        nodes.append(xs if k == N else np.concatenate([xs, np.zeros(P)]))
    x0 = np.concatenate(nodes)
    x0[-nx:] = np.tile(x_goal, P)
    gl = np.tile(np.concatenate([np.zeros(nx), np.full(P, -2.5)]), N)
    gu = np.tile(np.concatenate([np.zeros(nx), np.full(P, 2.5)]), N)
    return nlp, Bounds(x0, xl, xu, gl, gu), p, None
