"""One-stage (1S) and two-stage (2S) strategies (Sec. III-A.3), producing a ``Solution``.

1S solves the dynamic problem (6) once. 2S solves stage 1, the pseudo-static problem (8) on a
coarse grid (N1 = 30) with the relaxed contact law, with its fallbacks (``stage_one``), then hands
its primal solution over to the dynamic stages under the nominal law (``handover``). ``solve``
takes the everyday arguments as keywords and the strategy's settings as one ``SolveSettings``
(``settings``), checks all of them before any work starts, and runs every NLP through one
``Runner``.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import time
import warnings
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.model import contact as ct
from jaxhumanoid.model import foot as ft
from jaxhumanoid.model import kinematics as kin
from jaxhumanoid.model.params import ContactParams, FootParams, PlanarChain
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.ocp.scheme import parse_scheme
from jaxhumanoid.ocp.tasks import Task, Weights, get_task
from jaxhumanoid.strategy.handover import (
    continuation_stages,
    dynamic_options,
    law_path,
    relaxed_stage_problem,
    stage_two_start,
    with_law,
)
from jaxhumanoid.strategy.posture import check_start_margin, find_equilibrium, margins
from jaxhumanoid.strategy.problem import Problem, build_problem, nlp_guess
from jaxhumanoid.strategy.runner import Runner, StageProgress, stage_stats
from jaxhumanoid.strategy.settings import SOLVERS, SolveSettings, is_count
from jaxhumanoid.strategy.solution import Solution
from jaxhumanoid.strategy.stage_one import stage_one


def make_solution(problem: Problem, x, stages, solver: str, warm_start=None) -> Solution:
    """Trajectory arrays and derived quantities (forces, gaps, foot reaction) of a solution x."""
    layout, p = problem.layout, problem.p
    Z = problem.full(x)
    sl = layout.stage_slices()
    N, h = layout.N, float(p.T) / layout.N
    q, qd, u = Z[:, sl["q"]], Z[:, sl["qd"]], Z[:-1, sl["u"]]
    qbar, qdbar = 0.5 * (q[:-1] + q[1:]), 0.5 * (qd[:-1] + qd[1:])
    if layout.pseudo_static:
        qdbar = np.diff(q, axis=0) / h
    idx = np.asarray(layout.active, dtype=int) - 1
    qdd = np.zeros_like(qbar) if layout.pseudo_static else np.diff(qd, axis=0) / h
    qd_used = np.zeros_like(qbar) if layout.pseudo_static else qdbar
    forces, f_c0, margins, gaps, terms = jax.tree_util.tree_map(
        np.asarray, _derived(layout, p, jnp.asarray(Z), qbar, qdbar, qd_used, qdd)
    )
    f_contact = np.zeros((N, layout.n_links, 2))
    f_contact[:, idx] = forces
    terms = {k: float(terms[k]) for k in tr.OBJECTIVE_TERMS}  # in (7)'s order (a jitted dict comes back sorted)
    return Solution(
        task=problem.task.key,
        scheme=str(problem.scheme),
        solver=solver,
        t=np.linspace(0.0, float(p.T), N + 1),
        q=q,
        qd=qd,
        u=u,
        f_contact=f_contact,
        gaps=gaps,
        foot_reaction=f_c0,
        foot_margins=margins,
        objective=float(sum(terms.values())),
        objective_terms=terms,
        stages=stages,
        active=tuple(layout.active),
        geometry={
            "a": np.asarray(p.model.a),
            "names": tuple(p.model.names),
            "ankle_height": float(p.foot.ankle_height),
            "a0f": float(p.foot.a0f),
            "a0b": float(p.foot.a0b),
            "mu": float(p.contact.mu),
            "m": np.asarray(p.model.m),
            "g": float(p.model.g),
            "c": np.asarray(p.model.c),
            "inertia": np.asarray(p.model.inertia),
            "u_max": np.asarray(p.model.u_max),
            "kappa": float(p.contact.kappa),
            "f0": float(p.contact.f0),
            "xhat": float(p.contact.xhat),
            "goal": np.asarray(problem.task.goal),
            "goal_tolerance": float(problem.task.goal_tolerance),
            **{f"margin_{k}": float(getattr(p.foot_margin, k)) for k in ft.MARGIN_FIELDS},
        },
        warm_start=warm_start,
    )


@functools.partial(jax.jit, static_argnums=0)
def _derived(layout: tr.Layout, p, Z, qbar, qdbar, qd_used, qdd):
    """``make_solution``'s contact forces (N, k, 2), foot reaction, rows (5), gaps and the terms of
    (7) as one program: evaluated op by op, each of their operations compiles on its own."""
    N = layout.N
    if layout.augmented:
        forces = Z[:-1, layout.stage_slices()["f"]].reshape(N, -1, 2)
    else:
        forces = jax.vmap(lambda a, b: ct.contact_forces(p.model, p.foot, p.contact, a, b, layout.active))(qbar, qdbar)
    f_c0 = jax.vmap(lambda a, b, c, f: ft.foot_reaction(p.model, a, b, c, f))(qbar, qd_used, qdd, forces)
    u1 = Z[:-1, layout.stage_slices()["u"]][:, 0]
    margins = jax.vmap(lambda f, u: ft.foot_constraints(p.foot, p.contact.mu, f, u))(f_c0, u1)
    gaps = jax.vmap(lambda qq: kin.contact_gaps(p.model, p.foot, qq))(Z[:, layout.stage_slices()["q"]])
    return forces, f_c0, margins, gaps, tr.objective_terms(layout, Z, p)


def check_arguments(**kwargs) -> None:
    """``solve``'s keyword arguments checked as ``solve`` checks them before any work: a ValueError
    names the field and the values it allows (the command line's status 2)."""
    bound = inspect.signature(solve).bind(**kwargs)
    bound.apply_defaults()
    _check_arguments(bound.arguments)


def _check_arguments(a: dict) -> None:
    """Every argument of ``solve`` (``a``: name -> value) checked before any work, each error
    naming its field (the settings checked themselves when they were made)."""
    get_task(a["task"])
    parse_scheme(a["scheme"])
    if a["solver"] not in SOLVERS:
        raise ValueError(f"solver: {a['solver']!r} not in {SOLVERS}")
    if not is_count(a["N"], 3):
        raise ValueError(f"N: expected an integer number of intervals >= 3, got {a['N']!r}")
    T = a["T"]
    if isinstance(T, bool) or not isinstance(T, (int, float, np.integer, np.floating)) or not np.isfinite(T) or T <= 0:
        raise ValueError(f"T: expected a positive horizon in seconds (a number), got {T!r}")
    types = {"model": PlanarChain, "contact": ContactParams, "foot": FootParams, "settings": SolveSettings}
    for name, cls in types.items():
        if a[name] is not None and not isinstance(a[name], cls):
            raise ValueError(f"{name}: expected a {cls.__name__} or None, got {type(a[name]).__name__}")
    if a["options"] is not None and not isinstance(a["options"], Mapping):
        raise ValueError(f"options: expected a dict of solver options or None, got {type(a['options']).__name__}")


def _weights_array(weights, n: int):
    """``weights`` as the (n + 3,) array of (7): a ``Weights``, an array or None (the task's)."""
    if weights is None:
        return None
    if isinstance(weights, Weights):
        return weights.as_array(n)
    w = np.asarray(weights, dtype=float) if not isinstance(weights, str) else np.array([np.nan])
    if w.shape != (n + 3,) or not np.all(np.isfinite(w)) or np.any(w < 0):
        raise ValueError(
            f"weights: expected a Weights or {n + 3} finite weights >= 0 (w_u1..w_u{n}, w_qd, w_dqd, "
            f"w_du), got {weights!r}"
        )
    return w


def _seated_task(task: Task, model, contact, foot) -> Task:
    """The task with its start posture moved to the nearest static equilibrium that keeps the
    foot steady with margin under the given body and law, when it does not already."""
    if model is None and contact is None and foot is None:
        return task
    body = PlanarChain.humanoid() if model is None else model
    if body.n != task.n:
        raise ValueError(f"model: task {task.key} is posed for {task.n} joints, the chain has {body.n} links")
    if margins(body, task.start, task.active, contact=contact, foot=foot).ok:
        return task
    q_min, q_max = task.joint_ranges(body)
    eq = find_equilibrium(body, task.start, task.active, contact=contact, foot=foot, q_min=q_min, q_max=q_max)
    warnings.warn(
        f"task {task.key}: start posture moved by up to {eq.moved:.1e} rad to the nearest static "
        "equilibrium that keeps the foot steady under the given body and law",
        stacklevel=3,
    )
    return dataclasses.replace(task, start=eq.q)


def solve(
    task="T1",
    scheme="A,F+C,2S",
    solver: str = "ipopt",
    N: int = 100,
    T: float = 5.0,
    *,
    options: Mapping | None = None,
    weights=None,
    model: PlanarChain | None = None,
    contact: ContactParams | None = None,
    foot: FootParams | None = None,
    settings: SolveSettings | None = None,
    verbose: bool = False,
    progress: StageProgress | None = None,
) -> Solution:
    """Solve one task with one strategy.

    ``task``: a key (``T1``..``T4``), a readable name or a ``Task``. ``scheme``: the formulation
    and strategy (``ocp.scheme``; 1S or 2S). ``solver``: ``"ipopt"``, ``"ipm"`` (the package's own
    interior-point method) or ``"casadi"``. ``N``: intervals of the (final) grid; ``T``: the
    horizon in seconds. ``options``: solver options of every stage (``SolveSettings`` adds
    per-stage ones). ``weights``: a ``Weights`` or the n + 3 cost weights of (7) (default the
    task's), used by every stage. ``model`` (default ``PlanarChain.humanoid()``) and ``foot``
    (default ``FootParams.paper()``) apply to every stage; ``contact`` (default nominal) is the law
    of the dynamic stages. ``settings`` (default ``SolveSettings()``): how the strategy runs,
    stage 1's grid N1 and law, the initial guess, the hand-over, the relaxed-law stages' solver,
    per-stage options, the foot margin and the NLPs' units. When the body, the foot or the law is
    given and the task's start posture does not keep the foot steady under them, it is moved to
    the nearest posture that does (``posture.find_equilibrium``; a warning says so), or a
    ValueError says none was found. ``verbose`` prints the backend's iteration log;
    ``progress`` (e.g. ``jaxhumanoid.progress.IterationLine``) is called after every solver
    iteration with (stage name, iteration, objective, primal infeasibility). Every argument is
    checked before any work starts."""
    _check_arguments(dict(locals()))  # solve's arguments, before anything else is bound
    settings = SolveSettings() if settings is None else settings
    task, scheme, T = get_task(task), parse_scheme(scheme), float(T)
    weights = _weights_array(weights, task.n if model is None else model.n)
    foot_margin = ft.check_foot_margin(settings.foot_margin, FootParams.paper() if foot is None else foot)
    t0 = time.perf_counter()  # set-up from here on counts as the first stages' compile time
    task = _seated_task(task, model, contact, foot)
    if not foot_margin.is_zero:
        check_start_margin(task, PlanarChain.humanoid() if model is None else model, foot_margin, contact, foot)
    final = build_problem(
        task,
        scheme,
        N=N,
        T=T,
        weights=weights,
        model=model,
        contact=contact,
        foot=foot,
        # 2S: the dynamic stages start from stage 1's solution
        guess=nlp_guess(settings.guess) if scheme.stages == 1 else "linear",
        foot_margin=foot_margin,
    )
    runner = Runner(solver, verbose, progress, settings.scaling)
    relaxed_runner = runner.with_solver(settings.relaxed_solver(solver))
    dynamic = [relaxed_runner, runner] if settings.handover == "continuation" else [runner]
    stage2 = dynamic_options(options, settings, scheme.stages == 2)
    if scheme.stages == 2:  # the dynamic stages compile while stage 1 runs
        for r in {r.solver: r for r in dynamic}.values():
            r.precompile(final, stage2)
    setup_final = time.perf_counter() - t0
    if scheme.stages == 1:
        x0 = final.bounds.x0
        res = runner.run(final, x0, stage2, "single stage")
        return make_solution(final, res.x, [stage_stats("single stage", final, [res], setup_final, x0)], solver)
    law1 = ContactParams.relaxed() if settings.contact_stage1 is None else settings.contact_stage1
    t0 = time.perf_counter()
    relaxed, law_step = relaxed_stage_problem(final, law1, settings.continuation_steps)  # its law: law1 or a step on
    setup_relaxed = time.perf_counter() - t0  # stage 1's set-up too: its start re-seated for law1
    stats1, Z1 = stage_one(relaxed, settings, options, relaxed_runner)
    x0, Zf = stage_two_start(Z1, final)
    warm = {"t": np.linspace(0.0, T, N + 1), "q": Zf[:, final.layout.stage_slices()["q"]]}
    if settings.handover == "continuation":
        later = law_path(relaxed.p.contact, final.p.contact, settings.continuation_steps)[1:]
        path = [relaxed, *(with_law(final, law) for law in later)]
        more, x = continuation_stages(path, x0, stage2, (relaxed_runner, runner), setup_final)
    else:
        name = "stage 2 (dynamic)"
        res = runner.run(final, x0, stage2, name)
        more, x = [stage_stats(name, final, [res], setup_final, x0)], res.x
    setup1 = stats1.compile_time_s + setup_relaxed
    stages = [dataclasses.replace(stats1, law_step=law_step, compile_time_s=setup1), *more]
    return make_solution(final, x, stages, solver, warm_start=warm)
