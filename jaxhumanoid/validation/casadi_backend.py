"""The NLP (7) rebuilt in CasADi SX and solved with ``casadi.nlpsol('ipopt')``: a second, independent
implementation for cross-validation (``jaxhumanoid.validation.checks``) and a reference solver.

Decision: the model equations are derived here independently of ``jaxhumanoid.model``; only the
task/scheme/layout definitions (``ocp.transcription.Layout``: free-variable order, constraint order
per interval, which joints carry forces or clearance constraints) and the numeric parameters (read
from ``Problem.p``) are shared. A shared model source would let a model bug pass unnoticed.

The model, from the paper's Euler-Lagrange equations (1)-(2) in the absolute link angles
theta_l = q_1 + ... + q_l, e_l = (cos theta_l, sin theta_l), e_l' = (-sin theta_l, cos theta_l):

* joint O_i = O_0 + sum_{k<=i} a_k e_k, and sum_l m_l COM_l = M O_0 + sum_k w_k e_k with the
  mass-weighted lever w_k = m_k (a_k - c_k) + a_k (m_{k+1} + ... + m_n);
* kinetic energy T = 1/2 sum_jk S_jk cos(theta_j - theta_k) thetad_j thetad_k with S_jk = a_j w_k
  (j < k, S symmetric), S_kk = m_k (a_k - c_k)^2 + a_k^2 (m_{k+1} + ... + m_n) + i_k; its Euler-Lagrange
  equations in theta are sum_k S_jk (cos(theta_j - theta_k) thetadd_k + sin(theta_j - theta_k)
  thetad_k^2) + g w_j cos theta_j = e_j' . (a_j sum_{i >= j} f_ci). With cos(theta_j - theta_k) =
  c_j c_k + s_j s_k and sin(theta_j - theta_k) = s_j c_k - c_j s_k the first sum is
  c_j (S alpha)_j + s_j (S beta)_j, alpha_k = c_k thetadd_k - s_k thetad_k^2, beta_k = s_k thetadd_k
  + c_k thetad_k^2 (d^2 e_k / dt^2 = (-beta_k, alpha_k)), and S v costs O(n), not O(n^2), by the
  structure of S: (S v)_j = w_j sum_{k<j} a_k v_k + S_jj v_j + a_j sum_{k>j} w_k v_k;
* the joint coordinates q see these through theta = P q, P lower-triangular ones: the residual of
  (1) is P^T (theta-residual) - u, a suffix sum, since B = P^T M P, G = P^T G_theta and
  J_vi^T f = P^T J_vi,theta^T f;
* foot reaction of Sec. II-E: sum_l m_l a_COM_l + (0, M g) - sum_i f_ci, with sum_l m_l a_COM_l =
  sum_k w_k d^2 e_k / dt^2 built from the same alpha, beta;
* contact laws (3)-(4) written out (the softplus of (3) as max(z, 0) + log1p(2^-|z|) / ln 2, the
  same function, safe from overflow for deep penetration).

The test suite checks this form against the energy: B, C qd and G obtained by CasADi's AD of T and V
(``tests/test_casadi.py``).

The NLP is built as CasADi does best (the paper's Sec. II-B): one SX function of one interval
(its 2 s inputs, the stage vectors at both ends), minimal because every trigonometric and
kinematic subexpression is formed once and shared; it is called on the symbols of every interval,
which gives one SX graph of the whole problem. IPOPT gets CasADi's exact SX derivatives of it
(sparse Jacobian and Lagrangian Hessian by AD with graph colouring), evaluated by CasADi's virtual
machine: no Python runs between IPOPT's iterations unless a ``progress`` callback is asked for.

The chain has n = len(a) links (any n >= 2). Variable order equals our free-variable order and
constraint order equals ours, so every vector, Jacobian and Hessian compares entry by entry.
"""

from __future__ import annotations

import dataclasses
import time

import casadi as ca
import numpy as np

from jaxhumanoid.ocp.scaling import NLPScaling, scaled_bounds
from jaxhumanoid.solvers.ipopt import DEFAULT_OPTIONS, captured_log
from jaxhumanoid.solvers.result import IterationCallback, NLPResult, constraint_violation, unscaled
from jaxhumanoid.solvers.status import succeeded


@dataclasses.dataclass(frozen=True)
class _Numbers:
    """Plain floats of ``OCPParams`` (the only thing taken from our parameter pytree)."""

    a: np.ndarray
    c: np.ndarray
    m: np.ndarray
    inertia: np.ndarray
    g: float
    a0f: float
    a0b: float
    ankle_height: float
    kappa: float
    f0: float
    xhat: float
    mu: float
    weights: np.ndarray
    T: float
    q_start: np.ndarray
    margin_load: float  # the foot margin (``model.foot.FootMargin``): minimum f_n0 (N),
    margin_friction: float  # the fraction of mu kept unused,
    margin_cop: float  # the distance (m) of the centre of pressure from toe and heel

    @property
    def n(self) -> int:
        """Number of links."""
        return int(self.a.size)

    @property
    def outboard_mass(self) -> np.ndarray:
        """m_{k+1} + ... + m_n for each link k."""
        return np.concatenate([np.cumsum(self.m[::-1])[::-1][1:], [0.0]])

    @property
    def lever(self) -> np.ndarray:
        """w_k = m_k (a_k - c_k) + a_k (m_{k+1} + ... + m_n): sum_l m_l COM_l = M O_0 + sum_k w_k e_k."""
        return self.m * (self.a - self.c) + self.a * self.outboard_mass

    @property
    def inertia_diagonal(self) -> np.ndarray:
        """S_kk = m_k (a_k - c_k)^2 + a_k^2 (m_{k+1} + ... + m_n) + i_k (module docstring)."""
        return self.m * (self.a - self.c) ** 2 + self.a**2 * self.outboard_mass + self.inertia


def _numbers(p) -> _Numbers:
    arr = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
    return _Numbers(
        a=arr(p.model.a),
        c=arr(p.model.c),
        m=arr(p.model.m),
        inertia=arr(p.model.inertia),
        g=float(p.model.g),
        a0f=float(p.foot.a0f),
        a0b=float(p.foot.a0b),
        ankle_height=float(p.foot.ankle_height),
        kappa=float(p.contact.kappa),
        f0=float(p.contact.f0),
        xhat=float(p.contact.xhat),
        mu=float(p.contact.mu),
        weights=arr(p.weights),
        T=float(p.T),
        q_start=arr(p.q_start),
        margin_load=float(p.foot_margin.load) * float(np.sum(arr(p.model.m))) * float(p.model.g),
        margin_friction=float(p.foot_margin.friction),
        margin_cop=float(p.foot_margin.cop),
    )


def _cumsum(v: list) -> list:
    out = list(v[:1])
    for x in v[1:]:
        out.append(out[-1] + x)
    return out


def _sum(v: list):
    out = v[0]
    for x in v[1:]:
        out = out + x
    return out


def _plus(x, y):
    """x + y, where None stands for a structural zero (no node in the graph)."""
    return y if x is None else x if y is None else x + y


def _suffix_sum(v: list) -> list:
    """[v_k + ... + v_n for each k]: P^T v for P the lower-triangular ones."""
    return _cumsum(v[::-1])[::-1]


def _scalars(v) -> list:
    return [v[k] for k in range(v.shape[0])]


@dataclasses.dataclass(frozen=True)
class _Pose:
    """cos and sin of the absolute angles of a configuration q, each formed once."""

    cos: list
    sin: list

    @staticmethod
    def of(q: list) -> _Pose:
        theta = _cumsum(q)
        return _Pose([ca.cos(t) for t in theta], [ca.sin(t) for t in theta])


def _heights(nb: _Numbers, pose: _Pose) -> list:
    """y of O_1..O_n: h_ankle + sum_{k<=i} a_k sin theta_k."""
    return [nb.ankle_height + y for y in _cumsum([float(nb.a[k]) * s for k, s in enumerate(pose.sin)])]


def _normal_force(nb: _Numbers, y):
    """(3): f_n = f0 log2(1 + 2^z), z = -kappa y / f0, as f0 (max(z, 0) + log1p(2^-|z|) / ln 2)."""
    z = (-nb.kappa / nb.f0) * y
    return nb.f0 * ca.fmax(z, 0.0) + (nb.f0 / np.log(2.0)) * ca.log1p(ca.exp(-np.log(2.0) * ca.fabs(z)))


def _contact_laws(nb: _Numbers, pose: _Pose, thetad: list, active) -> list:
    """[(f_t, f_n)] of (3)-(4) at the joints in ``active``: the gap is the height of O_i and the sliding
    velocity its x-velocity, -sum_{k<=i} a_k sin(theta_k) thetad_k."""
    heights = _heights(nb, pose)
    xd = _cumsum([-float(nb.a[k]) * s * td for k, (s, td) in enumerate(zip(pose.sin, thetad))])
    out = []
    for i in active:
        f_n = _normal_force(nb, heights[i - 1])
        out.append((-nb.mu * f_n * ca.tanh(xd[i - 1] / nb.xhat), f_n))  # (4)
    return out


def _off_diagonal_products(nb: _Numbers, v: list) -> list:
    """(S v)_j - S_jj v_j = w_j sum_{k<j} a_k v_k + a_j sum_{k>j} w_k v_k (module docstring), in O(n)."""
    a, w, n = nb.a, nb.lever, nb.n
    before = _cumsum([float(a[k]) * v[k] for k in range(n - 1)])  # before[j - 1]: the sum over k < j
    after = _suffix_sum([float(w[k]) * v[k] for k in range(1, n)])  # after[j]: the sum over k > j
    out = []
    for j in range(n):
        terms = ([float(w[j]) * before[j - 1]] if j > 0 else []) + ([float(a[j]) * after[j]] if j < n - 1 else [])
        out.append(terms[0] + terms[1] if len(terms) == 2 else terms[0])
    return out


def _dynamics(nb: _Numbers, pose: _Pose, u: list, forces: list, active, motion=None) -> tuple[list, list]:
    """(residual, foot reaction): the residual of (1), B qdd + C qd + G - Q, for ``motion`` =
    (thetad, thetadd), or of (8), G - Q, for None; and the ground reaction (f_t0, f_n0) on the foot
    (Sec. II-E). ``forces``: (f_t, f_n) at the joints in ``active``."""
    n, a, w, d = nb.n, nb.a, nb.lever, nb.inertia_diagonal
    cos, sin = pose.cos, pose.sin
    at_joint = dict(zip(active, forces))
    fx: list = [None] * (n + 1)  # sum of the contact forces at O_i, i >= k (J_vi,theta^T f_i: a_k e_k' . f_i)
    fy: list = [None] * (n + 1)
    for k in range(n - 1, -1, -1):
        here = at_joint.get(k + 1, (None, None))
        fx[k], fy[k] = _plus(fx[k + 1], here[0]), _plus(fy[k + 1], here[1])
    weight = float(np.sum(nb.m)) * nb.g
    reaction = [0.0, weight] if fx[0] is None else [-fx[0], weight - fy[0]]
    # r_j = cos theta_j along_cos_j + sin theta_j along_sin_j + extra_j
    along_cos = [_plus(float(nb.g * w[j]), None if fy[j] is None else -float(a[j]) * fy[j]) for j in range(n)]
    along_sin = [0.0 if fx[j] is None else float(a[j]) * fx[j] for j in range(n)]
    extra: list = [0.0] * n
    if motion is not None:
        thetad, thetadd = motion
        sq = [td * td for td in thetad]
        alpha = [c * tdd - s * v for c, s, tdd, v in zip(cos, sin, thetadd, sq)]  # (d^2 e_k / dt^2)_y
        beta = [s * tdd + c * v for c, s, tdd, v in zip(cos, sin, thetadd, sq)]  # -(d^2 e_k / dt^2)_x
        s_alpha, s_beta = _off_diagonal_products(nb, alpha), _off_diagonal_products(nb, beta)
        along_cos = [x + y for x, y in zip(along_cos, s_alpha)]
        along_sin = [x + y for x, y in zip(along_sin, s_beta)]
        extra = [float(d[j]) * thetadd[j] for j in range(n)]
        # sum_l m_l a_COM_l = sum_k w_k d^2 e_k / dt^2
        reaction[0] = reaction[0] - _sum([float(w[k]) * beta[k] for k in range(n)])
        reaction[1] = reaction[1] + _sum([float(w[k]) * alpha[k] for k in range(n)])
    r = [c * x + s * y + e for c, s, x, y, e in zip(cos, sin, along_cos, along_sin, extra)]
    return [v - uj for v, uj in zip(_suffix_sum(r), u)], reaction


def _foot_constraints(nb: _Numbers, f_c0: list, u1) -> list:
    """(5a)-(5c) in product form, each >= 0, tightened by the foot margin."""
    f_t0, f_n0 = f_c0
    mu, a0f, a0b = (1.0 - nb.margin_friction) * nb.mu, nb.a0f - nb.margin_cop, nb.a0b - nb.margin_cop
    return [f_n0 - nb.margin_load, mu * f_n0 - f_t0, mu * f_n0 + f_t0, a0f * f_n0 + u1, a0b * f_n0 - u1]


def equilibrium_torques(nb: _Numbers, q, active) -> np.ndarray:
    """u with G(q) = Q(q, 0, u): the fixed u_0 of the initial static equilibrium."""
    qs = ca.SX.sym("q", nb.n)
    pose, rest = _Pose.of(_scalars(qs)), [0.0] * nb.n
    gravity, _ = _dynamics(nb, pose, rest, _contact_laws(nb, pose, rest, active), active)
    return np.asarray(ca.Function("u0", [qs], [ca.vertcat(*gravity)])(q)).ravel()


def _interval_function(nb: _Numbers, layout, last: bool) -> ca.Function:
    """(z_k, z_k+1) -> (constraints, cost) of one interval in our order ((6a), (6b) or (8), A-laws,
    (5), clearance, scheme E's normal forces) and its cost (7); z are stage vectors of the full
    layout: q (n), qd (n), u (n), then the 2|F| contact forces."""
    h, n = nb.T / layout.N, nb.n
    za, zb = ca.SX.sym("za", layout.s), ca.SX.sym("zb", layout.s)
    A, B = _scalars(za), _scalars(zb)
    q0, qd0, u, q1, qd1, u1 = A[0:n], A[n : 2 * n], A[2 * n : 3 * n], B[0:n], B[n : 2 * n], B[2 * n : 3 * n]
    pose = _Pose.of([0.5 * (x + y) for x, y in zip(q0, q1)])
    qdbar = [0.5 * (x + y) for x, y in zip(qd0, qd1)]
    rate = [(y - x) / h for x, y in zip(q0, q1)] if layout.pseudo_static else qdbar
    thetad = _cumsum(rate)
    laws = _contact_laws(nb, pose, thetad, layout.active)
    if layout.augmented:
        forces = [(A[3 * n + 2 * j], A[3 * n + 2 * j + 1]) for j in range(len(layout.active))]
    else:
        forces = laws
    rows = [y - x - h * v for x, y, v in zip(q0, q1, qdbar)]  # (6a)
    if layout.pseudo_static:
        residual, f_c0 = _dynamics(nb, pose, u, forces, layout.active)
        rows += residual  # (8)
    else:
        thetadd = _cumsum([(y - x) / h for x, y in zip(qd0, qd1)])
        residual, f_c0 = _dynamics(nb, pose, u, forces, layout.active, (thetad, thetadd))
        rows += [h * v for v in residual]  # (6b)
    if layout.augmented:
        rows += [v - law for f, fl in zip(forces, laws) for v, law in zip(f, fl)]
    rows += _foot_constraints(nb, f_c0, u[0])
    if layout.clear_joints:
        heights = _heights(nb, _Pose.of(q1))
        rows += [heights[i - 1] for i in layout.clear_joints]
    if layout.force_rows:
        rows += [f_n for _, f_n in laws]  # bounded above by the force limit
    w = [float(v) for v in nb.weights]
    w_u, w_qd, w_dqd, w_du = w[:n], w[n], w[n + 1], w[n + 2]
    effort = _sum([w_u[j] * u[j] * u[j] + w_qd * qd0[j] * qd0[j] for j in range(n)])
    change = _sum([w_dqd * (y - x) * (y - x) for x, y in zip(qd0, qd1)])
    if not last:
        change = change + _sum([w_du * (y - x) * (y - x) for x, y in zip(u, u1)])
    return ca.Function("interval", [za, zb], [ca.vertcat(*rows), h * effort + change / h])


@dataclasses.dataclass(frozen=True)
class CasadiNLP:
    """The NLP (7) as CasADi SX expressions of the symbol ``x`` (our free-variable order; with a
    scaling, the scaled variables y = Dx x of ``ocp.scaling`` and f, g those of the scaled problem)."""

    x: ca.SX
    f: ca.SX
    g: ca.SX
    u0: np.ndarray  # the fixed equilibrium torques of stage 0
    build_time_s: float


def build_casadi_nlp(problem, scaling: NLPScaling | None = None) -> CasadiNLP:
    """Build the CasADi twin of ``problem.nlp`` from ``problem.layout`` and the numbers in ``problem.p``:
    the interval function called on the stage vectors of every interval (module docstring)."""
    t0 = time.perf_counter()
    layout = problem.layout
    nb = _numbers(problem.p)
    u0 = equilibrium_torques(nb, nb.q_start, layout.active)
    free = layout.free_mask()
    x = ca.SX.sym("x", int(free.sum()))
    fixed = np.zeros(free.shape)
    fixed[0, 0 : nb.n], fixed[0, 2 * nb.n : 3 * nb.n] = nb.q_start, u0
    z = ca.SX(ca.DM(fixed.ravel()))
    z[np.flatnonzero(free.ravel()).tolist()] = x if scaling is None else x / ca.DM(np.asarray(scaling.x))
    s = layout.s
    stage = [z[k * s : (k + 1) * s] for k in range(layout.N + 1)]
    inner, final = _interval_function(nb, layout, last=False), _interval_function(nb, layout, last=True)
    cons, costs = [], []
    for k in range(layout.N):
        c_k, l_k = (final if k == layout.N - 1 else inner)(stage[k], stage[k + 1])
        cons.append(c_k)
        costs.append(l_k)
    f, g = ca.sum1(ca.vertcat(*costs)), ca.vertcat(*cons)
    if scaling is not None:
        f, g = float(scaling.obj) * f, ca.DM(np.asarray(scaling.g)) * g
    return CasadiNLP(x=x, f=f, g=g, u0=u0, build_time_s=time.perf_counter() - t0)


def derivative_function(cnlp: CasadiNLP) -> ca.Function:
    """(x, lam, sigma) -> (f, grad f, g, dg/dx, tril of sigma d2f + sum lam_j d2g_j), all sparse-exact."""
    lam, sigma = ca.SX.sym("lam", cnlp.g.shape[0]), ca.SX.sym("sigma")
    hess = ca.tril(ca.hessian(sigma * cnlp.f + ca.dot(lam, cnlp.g), cnlp.x)[0])
    return ca.Function(
        "derivatives",
        [cnlp.x, lam, sigma],
        [cnlp.f, ca.gradient(cnlp.f, cnlp.x), cnlp.g, ca.jacobian(cnlp.g, cnlp.x), hess],
        ["x", "lam", "sigma"],
        ["f", "grad", "g", "jac", "hess"],
    )


_HISTORY_KEYS = {
    "objective": "obj",
    "inf_pr": "inf_pr",
    "inf_du": "inf_du",
    "mu": "mu",
    "d_norm": "d_norm",
    "regularization": "regularization_size",
    "alpha_du": "alpha_du",
    "alpha_pr": "alpha_pr",
    "ls_trials": "ls_trials",
}
_EVAL_STATS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l")


class _Progress(ca.Callback):
    """CasADi's ``iteration_callback``: hands every iterate's (iteration, objective, primal
    infeasibility of g) to ``progress``; the bound violation of x is zero inside IPOPT."""

    def __init__(self, n: int, m: int, gl, gu, progress: IterationCallback):
        ca.Callback.__init__(self)
        self.sizes = {"x": n, "f": 1, "g": m, "lam_x": n, "lam_g": m, "lam_p": 0}
        self.gl, self.gu, self.progress, self.k = np.asarray(gl), np.asarray(gu), progress, 0
        self.construct("progress", {})

    def get_n_in(self):
        return ca.nlpsol_n_out()

    def get_n_out(self):
        return 1

    def get_name_in(self, i):
        return ca.nlpsol_out(i)

    def get_name_out(self, i):
        return "ret"

    def get_sparsity_in(self, i):
        size = self.sizes[ca.nlpsol_out(i)]
        return ca.Sparsity.dense(size, 1) if size else ca.Sparsity(0, 0)

    def eval(self, arg):
        values = dict(zip((ca.nlpsol_out(i) for i in range(ca.nlpsol_n_out())), arg))
        g = np.asarray(values["g"]).ravel()
        inf = float(np.max(np.maximum(0.0, np.maximum(self.gl - g, g - self.gu)), initial=0.0))
        self.progress(self.k, float(values["f"]), inf)
        self.k += 1
        return [0]


def solve_casadi(
    problem,
    x0=None,
    options: dict | None = None,
    verbose: bool = False,
    progress: IterationCallback | None = None,
    scaling: NLPScaling | None = None,
) -> NLPResult:
    """Solve ``problem`` (a ``strategy.problem.Problem``) with CasADi's IPOPT.

    ``options`` are IPOPT options merged over ``solvers.ipopt.DEFAULT_OPTIONS`` (exact Hessian,
    MUMPS, same tol and mu_strategy as our IPOPT path). ``compile_time_s`` is the time to build
    the SX graph and the solver (derivative graphs included); ``solve_time_s`` is the wall time of the
    solver call (CasADi's ``t_wall_total`` where its statistics report one). ``progress`` is
    called with (iteration, objective, primal infeasibility) at every iterate. With ``scaling``
    (``ocp.scaling``) IPOPT runs the scaled graph f~(y) = sf f(y / Dx), g~ = Dg g(y / Dx), the
    problem ``ocp.scaling.scaled_nlp`` states, and the result comes back in the original units.
    """
    bounds, nlp = problem.bounds, problem.nlp
    x0 = np.asarray(bounds.x0 if x0 is None else x0, dtype=np.float64)
    if x0.shape != (nlp.n,):
        raise ValueError(f"x0: expected shape ({nlp.n},), got {x0.shape}")
    if not np.all(np.isfinite(x0)):
        raise ValueError("x0: contains NaN or inf")
    opts = dict(DEFAULT_OPTIONS)
    opts.update(options or {})
    t0 = time.perf_counter()
    cnlp = build_casadi_nlp(problem, scaling)
    b = bounds
    if scaling is not None:
        b = scaled_bounds(bounds, scaling)
        x0 = x0 * np.asarray(scaling.x)
    with captured_log(opts, prefix="casadi_ipopt_") as log:
        try:
            nlpsol_opts: dict = {"ipopt": opts, "print_time": False, "error_on_fail": False}
            if progress is not None:
                nlpsol_opts["iteration_callback"] = _Progress(nlp.n, nlp.m, b.gl, b.gu, progress)
            solver = ca.nlpsol("solver", "ipopt", {"x": cnlp.x, "f": cnlp.f, "g": cnlp.g}, nlpsol_opts)
        except RuntimeError as err:
            raise ValueError(f"options: CasADi/IPOPT rejected the options {sorted(opts)} ({err})") from err
        build_time = time.perf_counter() - t0
        t1 = time.perf_counter()
        sol = solver(x0=x0, lbx=b.xl, ubx=b.xu, lbg=b.gl, ubg=b.gu)
        solve_time = time.perf_counter() - t1
        stats = solver.stats()
    if verbose:
        print(log["text"])
    x = np.asarray(sol["x"]).ravel()
    lam_x = np.asarray(sol["lam_x"]).ravel()
    g_val = np.asarray(sol["g"]).ravel()
    status = str(stats.get("return_status", "Unknown_Status"))
    iters = stats.get("iterations", {})
    history: dict = {ours: np.asarray(iters.get(theirs, [])) for ours, theirs in _HISTORY_KEYS.items()}
    history["eval_time_s"] = float(sum(stats.get(f"t_wall_{k}", 0.0) for k in _EVAL_STATS))
    res = NLPResult(
        x=x,
        lam_g=np.asarray(sol["lam_g"]).ravel(),
        z_l=np.maximum(-lam_x, 0.0),
        z_u=np.maximum(lam_x, 0.0),
        status=status,
        success=succeeded(status),
        iterations=int(stats.get("iter_count", 0)),
        solve_time_s=float(stats.get("t_wall_total", solve_time)),
        compile_time_s=build_time,
        objective=float(sol["f"]),
        max_constraint_violation=constraint_violation(g_val, x, b.gl, b.gu, b.xl, b.xu),
        history=history,
        log=log["text"],
    )
    if scaling is None:
        return res
    x, g_val = x / np.asarray(scaling.x), g_val / np.asarray(scaling.g)
    return unscaled(res, scaling, constraint_violation(g_val, x, bounds.gl, bounds.gu, bounds.xl, bounds.xu))
