"""The NLP (7) as a handful of pure functions: the one interface every solver consumes.

    minimize_x  f(x, p)   subject to   gl <= g(x, p) <= gu,   xl <= x <= xu

``p`` is a pytree of everything numeric the problem depends on (model, contact and cost
parameters, goal, horizon), so that solves can be batched with ``vmap`` over ``p`` and
differentiated with respect to it. Everything in ``NLP`` itself is static (shapes, sparsity,
stage layout) and hashable by identity, so an NLP can be closed over by ``jit``.

Sparse derivatives are given as values on fixed coordinate patterns:

    jac_values(x, p)                 -> (nnz_jac,)  at (jac_rows, jac_cols) of dg/dx
    hess_values(x, lam, sigma, p)    -> (nnz_hess,) at (hess_rows, hess_cols), lower triangle
                                        (row >= col) of sigma * d2f/dx2 + sum_j lam_j d2g_j/dx2

Stage layout: ``var_stage[i]`` and ``con_stage[j]`` give the stage (time interval) of variable i
and constraint j. Every Jacobian entry couples a constraint of stage k only with variables of
stages k and k+1, and every Hessian entry couples variables of stages differing by at most one,
so the KKT matrix ordered stage by stage is block-tridiagonal.

``NLP.jitted()`` gives the NLP's functions compiled once per NLP (``JittedNLP``); every solver and
the sensitivities call these, so one NLP is traced once however many modules evaluate it.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import numpy as np

# XLA's CPU compiler options for the NLP's programs (jaxlib is pinned: the names are its). Without
# the MLIR fusion emitters they compile in two thirds of the time, to the same bits and speed;
# without YNNPACK's fusions (its reductions and dots) an IPOPT iteration's evaluations take a
# quarter less time (scripts/bench_iteration.py).
COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False, "xla_cpu_experimental_ynn_fusion_type": ""}


class JittedNLP(NamedTuple):
    """The functions of one NLP under ``jax.jit``. ``fg`` and ``grad_jac`` fuse the pairs a
    solver asks for at the same point (IPOPT: f and g at every trial point, grad f and the
    Jacobian at every accepted one) into one dispatch each; the single functions are parts of
    them, so that an NLP compiles three programs."""

    fg: Callable[[Any, Any], Any]  # (x, p) -> (f, g)
    grad_jac: Callable[[Any, Any], Any]  # (x, p) -> (grad, jac_values)
    hess: Callable[[Any, Any, Any, Any], Any]  # (x, lam, sigma, p) -> hess_values
    f: Callable[[Any, Any], Any]
    g: Callable[[Any, Any], Any]
    grad: Callable[[Any, Any], Any]
    jac_values: Callable[[Any, Any], Any]


@dataclasses.dataclass(frozen=True, eq=False)
class NLP:
    n: int
    m: int
    f: Callable[[Any, Any], Any]
    g: Callable[[Any, Any], Any]
    grad: Callable[[Any, Any], Any]
    jac_values: Callable[[Any, Any], Any]
    hess_values: Callable[[Any, Any, Any, Any], Any]
    jac_rows: np.ndarray
    jac_cols: np.ndarray
    hess_rows: np.ndarray
    hess_cols: np.ndarray
    var_stage: np.ndarray
    con_stage: np.ndarray
    name: str = "nlp"
    # Compiled functions of the solvers and sensitivities, keyed by their owner and static
    # options: they live and die with this NLP instead of in module-level caches.
    cache: dict = dataclasses.field(default_factory=dict, init=False, repr=False, compare=False)

    def jitted(self) -> JittedNLP:
        """The NLP's functions compiled once for this NLP (kept in ``cache``)."""
        if "jitted" not in self.cache:
            fg = jax.jit(lambda x, p: (self.f(x, p), self.g(x, p)), compiler_options=COMPILER_OPTIONS)
            grad_jac = jax.jit(lambda x, p: (self.grad(x, p), self.jac_values(x, p)), compiler_options=COMPILER_OPTIONS)
            self.cache["jitted"] = JittedNLP(
                fg=fg,
                grad_jac=grad_jac,
                hess=jax.jit(self.hess_values, compiler_options=COMPILER_OPTIONS),
                f=lambda x, p: fg(x, p)[0],
                g=lambda x, p: fg(x, p)[1],
                grad=lambda x, p: grad_jac(x, p)[0],
                jac_values=lambda x, p: grad_jac(x, p)[1],
            )
        return self.cache["jitted"]

    def precompile(self, x, p) -> concurrent.futures.Future:
        """Compile the three programs of ``jitted()`` for arguments shaped like x (n,) and p, in
        background threads (XLA compiles outside the GIL, so they share the cores with the caller
        and with each other). Returns a future that is done when all three are; calls at these
        shapes then run at once, e.g. a later stage's programs compiled while an earlier stage
        solves. A second call at the same shapes returns the first call's future, so a solver's
        warm-up waits for a compilation started earlier instead of starting its own."""
        key = ("precompile", _signature(x), _signature(p))
        if key not in self.cache:
            ev = self.jitted()
            calls = [(ev.fg, (x, p)), (ev.grad_jac, (x, p)), (ev.hess, (x, np.ones(self.m), 1.0, p))]
            pool = concurrent.futures.ThreadPoolExecutor(len(calls) + 1)
            parts = [pool.submit(_run, fn, args) for fn, args in calls]
            self.cache[key] = pool.submit(_wait, parts)  # raises the first error of the three
            pool.shutdown(wait=False)
        return self.cache[key]

    @property
    def nnz_jac(self) -> int:
        return int(self.jac_rows.size)

    @property
    def nnz_hess(self) -> int:
        return int(self.hess_rows.size)


def _signature(tree) -> tuple:
    """What ``jax.jit`` keys its compiled programs on: the tree's structure and each leaf's shape
    and type (a Python scalar is weakly typed)."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return (treedef, *((np.shape(a), _dtype(a).str, isinstance(a, (int, float))) for a in leaves))


def _dtype(a) -> np.dtype:
    """The dtype of an array leaf, or numpy's for a Python scalar (without converting an array)."""
    return np.dtype(a.dtype) if hasattr(a, "dtype") else np.result_type(type(a))


def _run(fn, args):
    return jax.block_until_ready(fn(*args))


def _wait(futures) -> None:
    for f in futures:
        f.result()


@dataclasses.dataclass(frozen=True)
class Bounds:
    """Numeric bounds and the starting point; -inf/inf mark a missing bound."""

    x0: np.ndarray
    xl: np.ndarray
    xu: np.ndarray
    gl: np.ndarray
    gu: np.ndarray

    def __post_init__(self):
        n, m = self.x0.shape[0], self.gl.shape[0]
        for name, arr, size in (("xl", self.xl, n), ("xu", self.xu, n), ("gu", self.gu, m)):
            if arr.shape != (size,):
                raise ValueError(f"Bounds.{name}: expected shape ({size},), got {arr.shape}")
        if np.any(self.xl > self.xu):
            raise ValueError(
                f"Bounds.xl/xu: lower bound above upper bound at indices {np.nonzero(self.xl > self.xu)[0][:10]}"
            )
        if np.any(self.gl > self.gu):
            raise ValueError(
                f"Bounds.gl/gu: lower bound above upper bound at indices {np.nonzero(self.gl > self.gu)[0][:10]}"
            )
