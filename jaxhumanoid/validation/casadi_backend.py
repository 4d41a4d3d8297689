"""The NLP (7) rebuilt in CasADi SX and solved with ``casadi.nlpsol('ipopt')``: a second, independent
implementation for cross-validation (``jaxhumanoid.validation.checks``) and a reference solver.

Decision: the model equations are derived here independently of ``jaxhumanoid.model``; only the
task/scheme/layout definitions (``ocp.transcription.Layout``: free-variable order, constraint order
per interval, which joints carry forces or clearance constraints) and the numeric parameters (read
from ``Problem.p``) are shared. A shared model source would let a model bug pass unnoticed, so:

* kinematics from the chain geometry directly: O_l = O_{l-1} + a_l e_l, COM_l = O_l - c_l e_l,
  e_l = (cos theta_l, sin theta_l), theta_l = q_1 + ... + q_l (conventions of ``jaxhumanoid.model``);
* B(q) = d2T/dqd2 of the kinetic energy T = 1/2 sum_l (m_l |J_l qd|^2 + i_l thetad_l^2), J_l the COM
  Jacobian obtained by symbolic differentiation, not the paper's pattern form (Sec. II-C);
* C(q, qd) qd from the Euler-Lagrange equations, d/dt(dT/dqd) - dT/dq - B qdd
  = (d/dq (B qd)) qd - dT/dq (the Christoffel-symbol form, without forming C);
* G(q) = dV/dq with V = g sum_l m_l y_COM_l; Q of (2) with joint Jacobians J_vi = dO_i/dq;
* contact laws (3)-(4) written out (the softplus of (3) as max(z, 0) + log2(1 + 2^-|z|), which is
  the same function, safe from overflow for deep penetration);
* foot reaction of (5) from the COM accelerations a_l = J_l qdd + (d/dq (J_l qd)) qd.

The chain has n = len(a) links (any n >= 2). Variable order equals our free-variable order and
constraint order equals ours, so every vector, Jacobian and Hessian compares entry by entry.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

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


@dataclasses.dataclass(frozen=True)
class _Model:
    """CasADi functions of one configuration (pure symbols in, SX out), Sec. II-A/C/D/E."""

    mass_matrix: ca.Function  # q -> B (n x n)                        (1)
    coriolis: ca.Function  # q, qd -> C qd                            (1)
    gravity: ca.Function  # q -> G                                    (1)
    joint_points: ca.Function  # q -> (2 x n) positions of O_1..O_n
    joint_jacobians: ca.Function  # q -> (2n x n), rows 2i, 2i+1 = J_v of O_{i+1}
    momentum_rate: ca.Function  # q, qd, qdd -> sum_l m_l a_COM_l      (5)


def _model(nb: _Numbers) -> _Model:
    """Lagrangian mechanics of the chain, derived symbolically (see module docstring)."""
    n = nb.n
    q, qd, qdd = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n)
    theta, thetad = ca.cumsum(q), ca.cumsum(qd)
    joint: Any = ca.vertcat(0.0, nb.ankle_height)  # DM, then SX once a joint angle enters
    joints, coms = [], []
    for l in range(n):
        e = ca.vertcat(ca.cos(theta[l]), ca.sin(theta[l]))
        joint = joint + float(nb.a[l]) * e
        joints.append(joint)
        coms.append(joint - float(nb.c[l]) * e)
    com_jac = [ca.jacobian(pc, q) for pc in coms]
    kinetic = 0.5 * sum(
        float(nb.m[l]) * ca.sumsqr(com_jac[l] @ qd) + float(nb.inertia[l]) * thetad[l] ** 2 for l in range(n)
    )
    potential = nb.g * sum(float(nb.m[l]) * coms[l][1] for l in range(n))
    B = ca.hessian(kinetic, qd)[0]
    momentum = ca.gradient(kinetic, qd)
    cqd = ca.jacobian(momentum, q) @ qd - ca.gradient(kinetic, q)
    G = ca.gradient(potential, q)
    P = ca.horzcat(*joints)
    JV = ca.vertcat(*[ca.jacobian(pj, q) for pj in joints])
    rate = sum(float(nb.m[l]) * (com_jac[l] @ qdd + ca.jacobian(com_jac[l] @ qd, q) @ qd) for l in range(n))
    return _Model(
        mass_matrix=ca.Function("B", [q], [ca.densify(B)]),
        coriolis=ca.Function("Cqd", [q, qd], [cqd]),
        gravity=ca.Function("G", [q], [G]),
        joint_points=ca.Function("O", [q], [P]),
        joint_jacobians=ca.Function("Jv", [q], [JV]),
        momentum_rate=ca.Function("mdot", [q, qd, qdd], [rate]),
    )


def _normal_force(nb: _Numbers, y):
    """(3): f_n = f0 log2(1 + 2^z), z = -kappa y / f0, as f0 (max(z, 0) + log2(1 + 2^-|z|))."""
    z = -nb.kappa * y / nb.f0
    return nb.f0 * (ca.fmax(z, 0.0) + ca.log1p(2.0 ** (-ca.fabs(z))) / np.log(2.0))


def _contact_forces(nb: _Numbers, model: _Model, q, qd, active) -> list:
    """[(f_t, f_n)] of (3)-(4) at the joints in ``active``: gap = height of O_i, xd = its x-velocity."""
    P, JV = model.joint_points(q), model.joint_jacobians(q)
    out = []
    for i in active:
        f_n = _normal_force(nb, P[1, i - 1])
        xd = JV[2 * (i - 1), :] @ qd
        out.append(ca.vertcat(-nb.mu * f_n * ca.tanh(xd / nb.xhat), f_n))  # (4)
    return out


def _generalized_forces(model: _Model, q, u, forces, active):
    """Q of (2): u + sum_i J_vi^T f_ci."""
    JV = model.joint_jacobians(q)
    Q = u
    for i, f in zip(active, forces):
        Q = Q + JV[2 * (i - 1) : 2 * i, :].T @ f
    return Q


def _foot_reaction(nb: _Numbers, model: _Model, q, qd, qdd, forces):
    """Ground reaction on the massless foot: sum_l m_l a_COM_l + (0, M g) - sum_i f_ci (Sec. II-E)."""
    reaction = model.momentum_rate(q, qd, qdd) + ca.vertcat(0.0, float(np.sum(nb.m)) * nb.g)
    for f in forces:
        reaction = reaction - f
    return reaction


def _foot_constraints(nb: _Numbers, f_c0, u1):
    """(5a)-(5c) in product form, each >= 0, tightened by the foot margin."""
    f_t0, f_n0 = f_c0[0], f_c0[1]
    mu, a0f, a0b = (1.0 - nb.margin_friction) * nb.mu, nb.a0f - nb.margin_cop, nb.a0b - nb.margin_cop
    return ca.vertcat(f_n0 - nb.margin_load, mu * f_n0 - f_t0, mu * f_n0 + f_t0, a0f * f_n0 + u1, a0b * f_n0 - u1)


def equilibrium_torques(nb: _Numbers, model: _Model, q, active) -> np.ndarray:
    """u with G(q) = Q(q, 0, u): the fixed u_0 of the initial static equilibrium."""
    q, rest = ca.DM(q), ca.DM.zeros(nb.n)
    forces = _contact_forces(nb, model, q, rest, active)
    return np.asarray(ca.evalf(model.gravity(q) - _generalized_forces(model, q, rest, forces, active))).ravel()


def _interval(nb: _Numbers, model: _Model, layout, za, zb, last: bool):
    """Constraints of interval k in our order ((6a), (6b) or (8), A-laws, (5), clearance, scheme E's
    normal forces) and its cost (7)."""
    h, n = nb.T / layout.N, nb.n
    # stage entries: q (n), qd (n), u (n), then the 2|F| contact forces
    q0, qd0, u, q1, qd1, u1 = za[0:n], za[n : 2 * n], za[2 * n : 3 * n], zb[0:n], zb[n : 2 * n], zb[2 * n : 3 * n]
    qbar, qdbar = 0.5 * (q0 + q1), 0.5 * (qd0 + qd1)
    rate = (q1 - q0) / h if layout.pseudo_static else qdbar
    laws = _contact_forces(nb, model, qbar, rate, layout.active)
    if layout.augmented:
        forces = [za[3 * n + 2 * j : 3 * n + 2 * j + 2] for j in range(len(layout.active))]
    else:
        forces = laws
    parts = [q1 - q0 - h * qdbar]  # (6a)
    Q = _generalized_forces(model, qbar, u, forces, layout.active)
    if layout.pseudo_static:
        parts.append(model.gravity(qbar) - Q)  # (8)
        f_c0 = _foot_reaction(nb, model, qbar, ca.DM.zeros(n), ca.DM.zeros(n), forces)
    else:
        qdd = (qd1 - qd0) / h
        residual = model.mass_matrix(qbar) @ qdd + model.coriolis(qbar, qdbar) + model.gravity(qbar) - Q
        parts.append(h * residual)  # (6b)
        f_c0 = _foot_reaction(nb, model, qbar, qdbar, qdd, forces)
    if layout.augmented:
        parts += [fv - fl for fv, fl in zip(forces, laws)]
    parts.append(_foot_constraints(nb, f_c0, u[0]))
    if layout.clear_joints:
        heights = model.joint_points(q1)[1, :]
        parts.append(ca.vertcat(*[heights[i - 1] for i in layout.clear_joints]))
    if layout.force_rows:
        parts.append(ca.vertcat(*[f[1] for f in laws]))  # f_n, bounded above by the force limit
    w = [float(v) for v in nb.weights]
    du = (u1 - u) * (0.0 if last else 1.0)
    w_u, w_qd, w_dqd, w_du = w[:n], w[n], w[n + 1], w[n + 2]
    effort = h * (ca.dot(ca.DM(w_u), u**2) + w_qd * ca.sumsqr(qd0))
    cost = effort + (w_dqd * ca.sumsqr(qd1 - qd0) + w_du * ca.sumsqr(du)) / h
    return ca.vertcat(*parts), cost


@dataclasses.dataclass(frozen=True)
class CasadiNLP:
    """The NLP (7) as CasADi SX expressions of the symbol ``x`` (our free-variable order)."""

    x: ca.SX
    f: ca.SX
    g: ca.SX
    u0: np.ndarray  # the fixed equilibrium torques of stage 0
    build_time_s: float


def build_casadi_nlp(problem) -> CasadiNLP:
    """Build the CasADi twin of ``problem.nlp`` from ``problem.layout`` and the numbers in ``problem.p``."""
    t0 = time.perf_counter()
    layout = problem.layout
    nb = _numbers(problem.p)
    model = _model(nb)
    u0 = equilibrium_torques(nb, model, nb.q_start, layout.active)
    free = layout.free_mask()
    x = ca.SX.sym("x", int(free.sum()))
    fixed = np.zeros(free.shape)
    fixed[0, 0 : nb.n], fixed[0, 2 * nb.n : 3 * nb.n] = nb.q_start, u0
    stages, k_free = [], 0
    for k in range(layout.N + 1):
        entries = []
        for j in range(layout.s):
            if free[k, j]:
                entries.append(x[k_free])
                k_free += 1
            else:
                entries.append(ca.SX(fixed[k, j]))
        stages.append(ca.vertcat(*entries))
    cons: list = []
    cost: Any = 0
    for k in range(layout.N):
        c_k, l_k = _interval(nb, model, layout, stages[k], stages[k + 1], last=k == layout.N - 1)
        cons.append(c_k)
        cost = cost + l_k
    return CasadiNLP(x=x, f=cost, g=ca.vertcat(*cons), u0=u0, build_time_s=time.perf_counter() - t0)


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
    cnlp = build_casadi_nlp(problem)
    xs, fs, gs, b = cnlp.x, cnlp.f, cnlp.g, bounds
    if scaling is not None:
        xs, fs, gs = _scaled_graph(cnlp, scaling)
        b = scaled_bounds(bounds, scaling)
        x0 = x0 * np.asarray(scaling.x)
    with captured_log(opts, prefix="casadi_ipopt_") as log:
        try:
            nlpsol_opts: dict = {"ipopt": opts, "print_time": False, "error_on_fail": False}
            if progress is not None:
                nlpsol_opts["iteration_callback"] = _Progress(nlp.n, nlp.m, b.gl, b.gu, progress)
            solver = ca.nlpsol("solver", "ipopt", {"x": xs, "f": fs, "g": gs}, nlpsol_opts)
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


def _scaled_graph(cnlp: CasadiNLP, s: NLPScaling):
    """(y, f~, g~) of the scaled problem (``ocp.scaling``) from the graph of ``cnlp``."""
    y = ca.SX.sym("y", cnlp.x.shape[0])
    f, g = ca.substitute([cnlp.f, cnlp.g], [cnlp.x], [y / ca.DM(np.asarray(s.x))])
    return y, float(s.obj) * f, ca.DM(np.asarray(s.g)) * g
