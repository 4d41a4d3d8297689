"""IPMOptions as a pytree: float options are traced leaves (a new value reuses the compiled solver),
integer, boolean and string options are static (a new value compiles another)."""

import dataclasses

import jax
import numpy as np

from jaxhumanoid.solvers.ipm import IPMOptions, solve_ipm
from jaxhumanoid.solvers.ipm.options import FLOAT_FIELDS, STATIC_FIELDS, as_float64
from jaxhumanoid.validation import testproblems as tp


def test_float_fields_are_leaves_and_the_rest_is_structure():
    o = IPMOptions()
    leaves, treedef = jax.tree.flatten(o)
    assert len(leaves) == len(FLOAT_FIELDS) and "tol" in FLOAT_FIELDS and "max_iter" in STATIC_FIELDS
    assert set(FLOAT_FIELDS) | set(STATIC_FIELDS) == {f.name for f in dataclasses.fields(IPMOptions)}
    assert jax.tree.structure(o.replace(tol=1e-3, mu_init=0.5)) == treedef
    assert jax.tree.structure(o.replace(max_iter=7)) != treedef
    assert jax.tree.structure(o.replace(nlp_scaling_method="none")) != treedef
    assert jax.tree.unflatten(treedef, leaves) == o
    # inside jit the float fields are tracers and the static fields plain values
    seen = []

    def f(q):
        seen.append((type(q.max_iter), isinstance(q.tol, jax.core.Tracer)))
        return 2.0 * q.tol

    assert float(jax.jit(f)(o)) == 2e-8 and seen == [(int, True)]
    assert all(type(v) is np.float64 for v in jax.tree.leaves(as_float64(o.replace(tol=1))))


def test_changing_a_float_option_does_not_recompile_but_a_static_one_does():
    nlp, bounds, p, _ = tp.hs071()
    first = solve_ipm(nlp, p, bounds, options={"tol": 1e-9})
    compiled = nlp.cache[("ipm", "stepped")]["compiled"]
    n0 = len(compiled)
    again = solve_ipm(nlp, p, bounds, options={"tol": 1e-7, "mu_init": 0.05, "kappa_sigma": 1e9})
    assert again.compile_time_s == 0.0 and len(compiled) == n0
    assert again.success and again.history["mu"][0] == 0.05 and first.history["mu"][0] == 0.1
    other = solve_ipm(nlp, p, bounds, options={"tol": 1e-9, "max_soc": 2})
    assert other.compile_time_s > 0.0 and len(compiled) > n0
    assert other.success
