"""User-facing drivers: compile (cached), run, unscale, and package an ``NLPResult``."""

from __future__ import annotations

import concurrent.futures
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxhumanoid.ocp.nlp import NLP, Bounds
from jaxhumanoid.solvers.ipm.algorithm import advance, solve, start_at
from jaxhumanoid.solvers.ipm.log import format_log, trim_history
from jaxhumanoid.solvers.ipm.options import IPMOptions, as_float64, make_options
from jaxhumanoid.solvers.ipm.problem import make_context, prepare, scaled_prob, solution
from jaxhumanoid.solvers.ipm.state import Evals, Solution
from jaxhumanoid.solvers.result import IterationCallback, NLPResult, constraint_violation
from jaxhumanoid.solvers.status import SUCCESS, Status


def _batched_core(nlp: NLP):
    """jit of the vmapped solver core, cached in ``nlp.cache``: the jitted function of batched
    (x0, xl, xu, gl, gu, p) and shared options, and its compiled executables, one per argument
    structure (the static options are part of the options' pytree structure) and shapes."""
    key = ("ipm", "batched")
    if key not in nlp.cache:

        def fn(x0, xl, xu, gl, gu, p, opts):
            return solve(nlp, opts, x0, xl, xu, gl, gu, p)

        nlp.cache[key] = {"fn": jax.jit(jax.vmap(fn, in_axes=(0, 0, 0, 0, 0, 0, None))), "compiled": {}}
    return nlp.cache[key]


def _check_shapes(nlp, x0, bounds):
    if np.shape(x0) != (nlp.n,):
        raise ValueError(f"x0 must have shape ({nlp.n},), got {np.shape(x0)}")
    if np.shape(bounds.gl) != (nlp.m,):
        raise ValueError(f"bounds.gl must have shape ({nlp.m},), got {np.shape(bounds.gl)}")


def _fixed_multipliers(nlp, out: Solution, lam):
    """Bound multipliers of fixed variables from the stationarity residual (make_parameter)."""
    fixed = np.asarray(out.fixed)
    if not fixed.any():
        return np.asarray(out.zl), np.asarray(out.zu)
    jt = np.zeros(nlp.n)
    np.add.at(jt, np.asarray(nlp.jac_cols), np.asarray(out.jac) * lam[np.asarray(nlp.jac_rows)])
    r = np.asarray(out.grad) + jt
    zl = np.where(fixed, np.maximum(r, 0.0), np.asarray(out.zl))
    zu = np.where(fixed, np.maximum(-r, 0.0), np.asarray(out.zu))
    return zl, zu


def _package(nlp, out: Solution, bounds, opts, solve_time, compile_time):
    code = Status(int(out.status))
    status = code.name
    k = int(out.k)
    x = np.asarray(out.x)
    lam = np.asarray(out.lam)
    zl, zu = _fixed_multipliers(nlp, out, lam)
    history = trim_history(out.hist, k) if opts.keep_history else None
    header = f"jaxhumanoid IPM on {nlp.name}: n={nlp.n}, m={nlp.m}"
    log = format_log(history, k, status, header=header) if history else None
    if history is not None and opts.print_level > 0:
        print(log)
    viol = constraint_violation(np.asarray(out.g), x, bounds.gl, bounds.gu, bounds.xl, bounds.xu)
    return NLPResult(
        x=x,
        lam_g=lam,
        z_l=zl,
        z_u=zu,
        status=status,
        success=code in SUCCESS,
        iterations=k,
        solve_time_s=solve_time,
        compile_time_s=compile_time,
        objective=float(out.f),
        max_constraint_violation=viol,
        history=history,
        log=log,
    )


def _compiled(core, args):
    """The core compiled for ``args`` (once per argument structure and shapes), and the time this
    call spent compiling it (0 when it was compiled already)."""
    key = jax.tree.structure(args), tuple(jnp.shape(a) for a in jax.tree.leaves(args))
    if key in core["compiled"]:
        return core["compiled"][key], 0.0
    t0 = time.perf_counter()
    core["compiled"][key] = core["fn"].lower(*args).compile()
    return core["compiled"][key], time.perf_counter() - t0


def _compile_and_run(core, args):
    """Run the compiled core on ``args`` (compiling once per argument structure and shapes).

    Returns (numpy outputs, solve time, compile time of this call)."""
    compiled, compile_time = _compiled(core, args)
    t0 = time.perf_counter()
    out = jax.block_until_ready(compiled(*args))
    solve_time = time.perf_counter() - t0
    return jax.tree.map(np.asarray, out), solve_time, compile_time


def _stepped_core(nlp: NLP):
    """The solver core in jitted parts, cached in ``nlp.cache``: the bounds and starting point,
    the checked initial state from the NLP's evaluations there, iterations up to a given count
    (``advance``, its state argument donated, so that the history and the other unchanged arrays
    are not copied) and the unscaled solution. The evaluations at the start are the NLP's own
    jitted functions (``NLP.jitted``), which IPOPT compiles too, so that a solve after IPOPT's on
    the same NLP compiles no copy of them. The loop body is the one of ``_core``, so the iterates
    are the same; the host sees the state between calls."""
    key = ("ipm", "stepped")
    if key not in nlp.cache:

        def start_(B, p, at_x0, raw, o):
            ctx = make_context(nlp, o)
            return start_at(ctx, scaled_prob(ctx, B, p, *at_x0), B.x, raw)

        nlp.cache[key] = {
            "prepare": jax.jit(lambda x0, xl, xu, gl, gu, o: prepare(make_context(nlp, o), x0, xl, xu, gl, gu)),
            "start": jax.jit(start_),
            "advance": jax.jit(
                lambda P, S, o, k_stop: advance(make_context(nlp, o), P, S, k_stop), donate_argnums=(1,)
            ),
            "finish": jax.jit(lambda P, S, o: solution(make_context(nlp, o), S, P)),
            "nlp": nlp.jitted(),
            "compiled": set(),
        }
    return nlp.cache[key]


# a call of the stepped core runs about this long (s) before the host reports its iterations
REPORT_INTERVAL_S = 0.5
MAX_CHUNK = 100
_ALL = np.iinfo(np.int32).max  # a chunk that runs to the end


def _run_stepped(core, args, progress: IterationCallback | None, max_chunks: int | None = None):
    """Run the stepped core: every iteration in one call of ``advance`` without ``progress``;
    with it, a chunk of iterations at a time, calling ``progress(k, objective, inf_pr)`` for every
    iteration k from the history after each chunk. The chunks run one compiled loop, so the
    iterates do not depend on them. A chunk lasts about ``REPORT_INTERVAL_S``: a call costs about a
    millisecond besides its iterations, a tenth of an iteration of the humanoid's stage 2. The
    first call of each part compiles it; that time counts as compile time. ``max_chunks`` stops
    after that many chunks (``precompile_ipm``'s run)."""
    x0, xl, xu, gl, gu, p, opts = args
    compile_time, solve_time = 0.0, 0.0

    def call(name, fn, *a):
        # a part compiles on its first call for each structure (static options) and shapes
        nonlocal compile_time, solve_time
        key = name, jax.tree.structure(a), tuple(np.shape(v) for v in jax.tree.leaves(a))
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*a))
        dt = time.perf_counter() - t0
        if key in core["compiled"]:
            solve_time += dt
        else:
            core["compiled"].add(key)
            compile_time += dt
        return out, dt

    B, _ = call("prepare", core["prepare"], x0, xl, xu, gl, gu, opts)
    fns = core["nlp"]
    at_x0, _ = call("grad_jac", fns.grad_jac, B.x0, p)
    (f, g), _ = call("fg", fns.fg, B.x, p)
    (grad, jac), _ = call("grad_jac", fns.grad_jac, B.x, p)
    (S, P), _ = call("start", core["start"], B, p, at_x0, Evals(f=f, g=g, grad=grad, jac=jac), opts)
    k_done, chunk = 0, 1 if progress is not None or max_chunks is not None else _ALL
    if progress is not None:
        progress(0, float(S.hist["obj"][0]), float(S.hist["inf_pr"][0]))
    chunks = 0
    while not bool(S.done) and (max_chunks is None or chunks < max_chunks):
        chunks += 1
        k_stop = min(k_done + chunk, _ALL)
        S, dt = call("advance", core["advance"], P, S, opts, jnp.asarray(k_stop, jnp.int32))
        k = int(S.k)
        if progress is not None:
            obj, inf_pr = jax.device_get((S.hist["obj"], S.hist["inf_pr"]))
            for j in range(k_done + 1, k + 1):
                progress(j, float(obj[j]), float(inf_pr[j]))
            chunk = int(np.clip(REPORT_INTERVAL_S * (k - k_done) / max(dt, 1e-9), 1, MAX_CHUNK))
        k_done = k
    out, _ = call("finish", core["finish"], P, S, opts)
    return jax.tree.map(np.asarray, out), solve_time, compile_time


def solve_ipm(
    nlp: NLP,
    p,
    bounds: Bounds,
    x0=None,
    options: IPMOptions | dict | None = None,
    progress: IterationCallback | None = None,
) -> NLPResult:
    """Solve the NLP with the own interior-point method; warm start from ``x0`` if given.

    The jitted parts (``_stepped_core``) are compiled once per (NLP, integer/boolean/string
    options, argument shapes) and cached; float options (tolerances, mu_init, ...) are runtime
    inputs and never recompile. The compile time is reported in ``compile_time_s`` (0 on a cache
    hit). ``progress`` is called with (iteration, objective, primal infeasibility) for every
    iteration; the solve then runs a chunk of iterations at a time, with the same iterates bit for
    bit as without it.
    """
    opts = make_options(options)
    x0 = np.asarray(bounds.x0 if x0 is None else x0, dtype=float)
    _check_shapes(nlp, x0, bounds)
    if progress is not None and not opts.keep_history:
        raise ValueError("progress: needs the IPM's history (options keep_history=True)")
    args = _solve_args(x0, bounds, p, opts)
    waited = 0.0
    pending = nlp.cache.get(("ipm", "precompile"))
    if pending is not None and not pending.done():  # a compilation started earlier (``precompile_ipm``)
        t0 = time.perf_counter()
        concurrent.futures.wait([pending])
        waited = time.perf_counter() - t0
    out, solve_time, compile_time = _run_stepped(_stepped_core(nlp), args, progress)
    return _package(nlp, out, bounds, opts, solve_time, compile_time + waited)


def _solve_args(x0, bounds: Bounds, p, opts: IPMOptions) -> tuple:
    """The arguments of the compiled core: (x0, xl, xu, gl, gu, p, options)."""
    arrays = (x0, bounds.xl, bounds.xu, bounds.gl, bounds.gu)
    return (*(jnp.asarray(a, float) for a in arrays), p, as_float64(opts))


def precompile_ipm(nlp: NLP, p, bounds: Bounds, options: IPMOptions | dict | None = None) -> concurrent.futures.Future:
    """Compile, in a background thread, the programs that ``solve_ipm(nlp, p', bounds', options=
    options)`` compiles for a p' and bounds' shaped like ``p`` and ``bounds``. Returns a future
    that is done when they are; a later ``solve_ipm`` on ``nlp`` waits for it (the wait counts as
    its compile time) and then runs at once, e.g. a dynamic stage compiled while stage 1 solves.
    The programs compile by running: one iteration from ``bounds.x0``. A second call returns the
    first call's future."""
    key = ("ipm", "precompile")
    if key not in nlp.cache:
        args = _solve_args(np.asarray(bounds.x0, float), bounds, p, make_options(options))
        core = _stepped_core(nlp)
        work = lambda: _run_stepped(core, args, None, max_chunks=1)  # noqa: E731
        pool = concurrent.futures.ThreadPoolExecutor(1)
        nlp.cache[key] = pool.submit(work)
        pool.shutdown(wait=False)
    return nlp.cache[key]


def batch_solve_ipm(nlp: NLP, p_batch, bounds: Bounds, x0=None, options=None) -> list[NLPResult]:
    """Solve a batch under ``jax.vmap``: ``p_batch`` leaves and any of x0/xl/xu/gl/gu may carry a
    leading batch axis (others are broadcast). Converged members freeze while others iterate."""
    opts = make_options(options)
    leaves = jax.tree.leaves(p_batch)
    if not leaves:
        raise ValueError("batch_solve_ipm: p_batch must have at least one batched leaf")
    nbatch = int(np.shape(leaves[0])[0])
    x0 = np.asarray(bounds.x0 if x0 is None else x0, dtype=float)

    def bc(a, size):
        a = np.asarray(a, dtype=float)
        return np.broadcast_to(a, (nbatch, size)) if a.ndim == 1 else a

    arrs = [bc(x0, nlp.n), bc(bounds.xl, nlp.n), bc(bounds.xu, nlp.n), bc(bounds.gl, nlp.m), bc(bounds.gu, nlp.m)]
    core = _batched_core(nlp)
    args = tuple(jnp.asarray(a) for a in arrs) + (p_batch, as_float64(opts))
    out, solve_time, compile_time = _compile_and_run(core, args)
    results = []
    for b in range(nbatch):
        ob = jax.tree.map(lambda a, b=b: a[b], out)
        bb = Bounds(arrs[0][b], arrs[1][b], arrs[2][b], arrs[3][b], arrs[4][b])
        results.append(_package(nlp, ob, bb, opts, solve_time, compile_time))
    return results
