"""IPOPT with exact sparse Jacobian and Hessian from JAX.

IPOPT is driven through its C interface (``ipopt_capi``), which copies derivative values with one
memcpy instead of cyipopt's per-entry loop. The library is the casadi wheel's (IPOPT 3.14.19 with
METIS-ordered MUMPS; ``ipopt_capi.default_library_path``), or the cyipopt wheel's where asked.
IPOPT's options pass straight through (``options={"tol": 1e-9, ...}``). The iteration log is
written by IPOPT to a file and read back into ``NLPResult.log`` (and echoed when ``verbose``);
per-iteration statistics come from the intermediate callback.

``NLPResult.iterations`` is IPOPT's own count, the "Number of Iterations" of its log. The
intermediate callback is not a counter: IPOPT reports the iterate where its restoration phase
returns twice (from the restoration phase and again from the regular one), and a restoration phase
that ends the solve reports one iterate beyond IPOPT's count.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
import time

import cyipopt
import jax
import numpy as np

from jaxhumanoid.ocp.nlp import NLP, Bounds
from jaxhumanoid.solvers import ipopt_capi
from jaxhumanoid.solvers.result import IterationCallback, NLPResult, constraint_violation
from jaxhumanoid.solvers.status import status_name, succeeded

DEFAULT_OPTIONS = {
    "tol": 1e-8,
    "max_iter": 3000,
    "mu_strategy": "monotone",
    "linear_solver": "mumps",
    "hessian_approximation": "exact",
    "print_level": 0,
    "file_print_level": 5,
    "sb": "yes",
}
_INF = 2e19  # IPOPT's "no bound" is anything beyond nlp_lower/upper_bound_inf (1e19)


@contextlib.contextmanager
def captured_log(opts: dict, prefix: str = "ipopt_"):
    """Point IPOPT's ``output_file`` at a temporary file (unless ``opts`` already names one) and
    yield a dict whose ``"text"`` holds the iteration log once the block has ended."""
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".log")
    os.close(fd)
    opts.setdefault("output_file", tmp)
    out = {"text": ""}
    try:
        yield out
    finally:
        if os.path.exists(opts["output_file"]):
            with open(opts["output_file"]) as fh:
                out["text"] = fh.read()
        if os.path.exists(tmp):
            os.remove(tmp)


class _Callbacks:
    """What IPOPT calls, as jitted JAX functions fed numpy arrays.

    IPOPT asks for f and g at every trial point, and for grad f and the Jacobian at every
    accepted one, in separate callbacks at the same x. Each pair is one fused jitted call whose
    second half is kept until IPOPT reports a new x: half the dispatches per iteration.
    """

    def __init__(self, nlp: NLP, p, progress: IterationCallback | None = None):
        self.p = p
        self.progress = progress
        jitted = nlp.jitted()
        self._pairs = {"fg": jitted.fg, "dj": jitted.grad_jac}
        self._hess = jitted.hess
        self._cache: dict = {}
        self.history: dict[str, list] = {
            k: []
            for k in (
                "objective",
                "inf_pr",
                "inf_du",
                "mu",
                "d_norm",
                "regularization",
                "alpha_du",
                "alpha_pr",
                "ls_trials",
            )
        }
        self.last_iteration = -1  # IPOPT's number of the last iterate reported, -1 before any
        self.eval_time = 0.0
        self.eval_calls = 0

    def warm_up(self, nlp: NLP, x) -> float:
        """Compile every callback, the three programs at once (``NLP.precompile``); returns the
        wall time (none where they were compiled already)."""
        t0 = time.perf_counter()
        nlp.precompile(x, self.p).result()
        return time.perf_counter() - t0

    def _timed(self, fn, *args):
        t0 = time.perf_counter()
        out = jax.tree_util.tree_map(np.asarray, fn(*args))
        self.eval_time += time.perf_counter() - t0
        self.eval_calls += 1
        return out

    def new_point(self):
        self._cache.clear()

    def _pair(self, key, x):
        if key not in self._cache:
            self._cache[key] = self._timed(self._pairs[key], x, self.p)
        return self._cache[key]

    def functions(self) -> dict:
        return {
            "f": lambda x: float(self._pair("fg", x)[0]),
            "g": lambda x: self._pair("fg", x)[1],
            "grad": lambda x: self._pair("dj", x)[0],
            "jac": lambda x: self._pair("dj", x)[1],
            "hess": lambda x, lam, obj_factor: self._timed(self._hess, x, lam, obj_factor, self.p),
            "intermediate": self.intermediate,
            "new_point": self.new_point,
        }

    def intermediate(
        self,
        alg_mod,
        iter_count,
        obj_value,
        inf_pr,
        inf_du,
        mu,
        d_norm,
        regularization_size,
        alpha_du,
        alpha_pr,
        ls_trials,
    ):
        # The iterate where the restoration phase returns is reported again by the regular phase:
        # its regular-phase statistics replace the restoration phase's, one entry per iterate.
        if int(iter_count) == self.last_iteration:
            for values in self.history.values():
                values.pop()
        self.last_iteration = int(iter_count)
        for key, val in zip(
            self.history, (obj_value, inf_pr, inf_du, mu, d_norm, regularization_size, alpha_du, alpha_pr, ls_trials)
        ):
            self.history[key].append(val)
        if self.progress is not None:
            self.progress(int(iter_count), float(obj_value), float(inf_pr))


def _iteration_count(log: str, last_iteration: int) -> int:
    """IPOPT's iteration count: the "Number of Iterations" of its ``log``, or, where the log does
    not have it (``file_print_level`` below 3), the last iteration IPOPT reported to the callback."""
    found = re.findall(r"^Number of Iterations\.+:\s*(\d+)", log, flags=re.MULTILINE)
    if found:
        return int(found[-1])
    return max(last_iteration, 0)


def _finite_or_inf(a, sign):
    a = np.asarray(a, dtype=float)
    return np.where(np.isfinite(a), a, sign * _INF)


def solve_ipopt(
    nlp: NLP,
    p,
    bounds: Bounds,
    x0=None,
    options: dict | None = None,
    verbose: bool = False,
    warm: NLPResult | None = None,
    progress: IterationCallback | None = None,
    library_path: str | None = None,
) -> NLPResult:
    """Solve ``nlp`` at parameters ``p`` with IPOPT (exact Hessian, MUMPS by default).

    ``options`` are IPOPT options, merged over ``DEFAULT_OPTIONS``; ``verbose`` echoes IPOPT's
    iteration log; ``warm`` (an earlier result) supplies starting multipliers (lam_g, z_l, z_u),
    which IPOPT uses with ``warm_start_init_point=yes``; ``progress`` is called with (iteration,
    objective, primal infeasibility) from IPOPT's intermediate callback; ``library_path`` names the
    IPOPT library (``ipopt_capi.default_library_path()`` if None). The returned ``NLPResult.success``
    is True for Solve_Succeeded and Solved_To_Acceptable_Level only.
    """
    opts = dict(DEFAULT_OPTIONS)
    opts.update(options or {})
    x0 = np.asarray(bounds.x0 if x0 is None else x0, dtype=float)
    if x0.shape != (nlp.n,):
        raise ValueError(f"x0: expected shape ({nlp.n},), got {x0.shape}")
    if not np.all(np.isfinite(x0)):
        raise ValueError("x0: contains NaN or inf")
    cb = _Callbacks(nlp, p, progress)
    compile_time = cb.warm_up(nlp, x0)
    mults = {} if warm is None else {"mult_g": warm.lam_g, "mult_x_L": warm.z_l, "mult_x_U": warm.z_u}
    with captured_log(opts) as log:
        t0 = time.perf_counter()
        code, x, g_val, obj, lam_g, z_l, z_u = ipopt_capi.solve(
            nlp.n,
            nlp.m,
            _finite_or_inf(bounds.xl, -1),
            _finite_or_inf(bounds.xu, 1),
            _finite_or_inf(bounds.gl, -1),
            _finite_or_inf(bounds.gu, 1),
            (nlp.jac_rows, nlp.jac_cols),
            (nlp.hess_rows, nlp.hess_cols),
            cb.functions(),
            opts,
            x0,
            **mults,
            library_path=library_path,
        )
        solve_time = time.perf_counter() - t0
    if verbose:
        print(log["text"])
    status = status_name(code)
    return NLPResult(
        x=x,
        lam_g=lam_g,
        z_l=z_l,
        z_u=z_u,
        status=status,
        success=succeeded(status),
        iterations=_iteration_count(log["text"], cb.last_iteration),
        solve_time_s=solve_time,
        compile_time_s=compile_time,
        objective=obj,
        max_constraint_violation=constraint_violation(g_val, x, bounds.gl, bounds.gu, bounds.xl, bounds.xu),
        history={
            **{k: np.asarray(v) for k, v in cb.history.items()},
            "eval_time_s": cb.eval_time,
            "eval_calls": cb.eval_calls,
        },
        log=log["text"],
    )


def solve_cyipopt_reference(nlp: NLP, p, bounds: Bounds, x0=None, options: dict | None = None):
    """The same solve through cyipopt's own Python binding (no fused calls, per-entry copies) and
    its wheel's IPOPT library.

    For cross-checks and benchmarks of ``solve_ipopt`` only: with ``library_path=
    ipopt_capi.wheel_library_path()`` that is the same IPOPT build, so the iterates must agree to
    round-off. Returns (x, info, solve_time_s) as cyipopt gives them.
    """
    jitted = nlp.jitted()
    f, g, grad, jac, hess = jitted.f, jitted.g, jitted.grad, jitted.jac_values, jitted.hess
    x0 = np.asarray(bounds.x0 if x0 is None else x0, dtype=float)

    class _Problem:
        def objective(self, x):
            return float(f(x, p))

        def gradient(self, x):
            return np.asarray(grad(x, p))

        def constraints(self, x):
            return np.asarray(g(x, p))

        def jacobian(self, x):
            return np.asarray(jac(x, p))

        def jacobianstructure(self):
            return nlp.jac_rows, nlp.jac_cols

        def hessian(self, x, lam, sigma):
            return np.asarray(hess(x, lam, sigma, p))

        def hessianstructure(self):
            return nlp.hess_rows, nlp.hess_cols

    obj = _Problem()
    for out in (
        obj.objective(x0),
        obj.constraints(x0),
        obj.gradient(x0),
        obj.jacobian(x0),
        obj.hessian(x0, np.ones(nlp.m), 1.0),
    ):
        jax.block_until_ready(out)
    prob = cyipopt.Problem(
        n=nlp.n,
        m=nlp.m,
        problem_obj=obj,
        lb=_finite_or_inf(bounds.xl, -1),
        ub=_finite_or_inf(bounds.xu, 1),
        cl=_finite_or_inf(bounds.gl, -1),
        cu=_finite_or_inf(bounds.gu, 1),
    )
    for key, val in {**DEFAULT_OPTIONS, "file_print_level": 0, **(options or {})}.items():
        prob.add_option(key, val)
    t0 = time.perf_counter()
    x, info = prob.solve(x0)
    return x, info, time.perf_counter() - t0
