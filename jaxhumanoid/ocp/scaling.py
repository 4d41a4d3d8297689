"""Physical scaling of the transcription's NLP: variables and rows in units of O(1).

A solver of the NLP in ``ocp.nlp`` sees angles in radians next to torques of hundreds of newton-metres
and contact forces of hundreds of newtons, and rows in N m, N and m next to each other. The
scaled NLP measures each in a unit of its own size::

    x~ = Dx x,   g~(x~) = Dg g(x),   f~(x~) = sf f(x),     x = x~ / Dx

with Dx = 1 for q and qd (rad, rad/s), 1/torque for u and 1/force for the contact forces f;
Dg = 1 for the kinematic rows (6a), 1/torque for the dynamics rows (8) and 1/(torque h) for (6b)
(which is h times a torque residual), 1/force for the force rows of A and the steady-foot rows
(5), 1/length for the clearance rows; sf = 1/objective. The multipliers of the original problem
follow from those of the scaled one: lam = Dg lam~ / sf, z = Dx z~ / sf.

``scaled_nlp(nlp)`` is the scaled problem as an ``NLP`` whose parameter is the pair (p, S), so that
one compilation serves every scaling (S is a runtime input) and the same solver code runs it.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxhumanoid.ocp.nlp import NLP, Bounds
from jaxhumanoid.ocp.transcription import N_FOOT, Layout

SCALINGS = ("none", "physical")
# The units of the physical scaling: a torque of 10 N m, a force of 100 N, a length of 0.1 m and
# an objective of 100 count as 1. The values of (7) at the tasks' optima are 50-600.
TORQUE_UNIT = 10.0
FORCE_UNIT = 100.0
LENGTH_UNIT = 0.1
OBJECTIVE_UNIT = 100.0


class NLPScaling(NamedTuple):
    """Scale factors of one NLP (all > 0): ``obj`` (), ``x`` (n,), ``g`` (m,)."""

    obj: Any
    x: Any
    g: Any


def check_scaling(scaling: str) -> str:
    if scaling not in SCALINGS:
        raise ValueError(f"scaling: expected one of {SCALINGS}, got {scaling!r}")
    return scaling


def physical_scaling(layout: Layout, T: float) -> NLPScaling:
    """The physical scaling of the transcription ``layout`` over horizon ``T`` (s); the module
    docstring gives the units. Variables are ordered as ``transcription.free_from_full``, rows as
    ``transcription.all_constraints`` (interval by interval, ``Layout.n_con`` rows each)."""
    n, sl = layout.n_links, layout.stage_slices()
    col = np.ones(layout.s)
    col[sl["u"]] = 1.0 / TORQUE_UNIT
    col[sl["f"]] = 1.0 / FORCE_UNIT
    x = np.broadcast_to(col, (layout.N + 1, layout.s))[layout.free_mask()]
    dyn = 1.0 / TORQUE_UNIT if layout.pseudo_static else layout.N / (TORQUE_UNIT * float(T))
    row = np.concatenate(
        [
            np.ones(n),
            np.full(n, dyn),
            np.full(layout.n_f, 1.0 / FORCE_UNIT),
            np.full(N_FOOT, 1.0 / FORCE_UNIT),
            np.full(len(layout.clear_joints), 1.0 / LENGTH_UNIT),
            np.full(layout.n_force_rows, 1.0 / FORCE_UNIT),
        ]
    )
    return NLPScaling(obj=1.0 / OBJECTIVE_UNIT, x=np.ascontiguousarray(x), g=np.tile(row, layout.N))


def scaled_nlp(nlp: NLP) -> NLP:
    """The scaled problem of ``nlp`` (module docstring), with parameter (p, S); built once per NLP."""
    if "scaled" in nlp.cache:
        return nlp.cache["scaled"]
    hr, hc, jr, jc = (np.asarray(a) for a in (nlp.hess_rows, nlp.hess_cols, nlp.jac_rows, nlp.jac_cols))

    def f(y, ps):
        p, s = ps
        return s.obj * nlp.f(y / s.x, p)

    def g(y, ps):
        p, s = ps
        return s.g * nlp.g(y / s.x, p)

    def grad(y, ps):
        p, s = ps
        return s.obj * nlp.grad(y / s.x, p) / s.x

    def jac_values(y, ps):
        p, s = ps
        return s.g[jr] * nlp.jac_values(y / s.x, p) / s.x[jc]

    def hess_values(y, lam, sigma, ps):
        p, s = ps
        return nlp.hess_values(y / s.x, s.g * lam, sigma * s.obj, p) / (s.x[hr] * s.x[hc])

    # replace() leaves the new NLP its own, empty cache (an init=False field)
    out = dataclasses.replace(
        nlp, f=f, g=g, grad=grad, jac_values=jac_values, hess_values=hess_values, name=f"{nlp.name}, scaled"
    )
    nlp.cache["scaled"] = out
    return out


def scaled_bounds(bounds: Bounds, s: NLPScaling) -> Bounds:
    """``bounds`` and the starting point in the scaled variables and rows."""
    x, g = np.asarray(s.x), np.asarray(s.g)
    return Bounds(x0=bounds.x0 * x, xl=bounds.xl * x, xu=bounds.xu * x, gl=bounds.gl * g, gu=bounds.gu * g)


def as_jax(s: NLPScaling) -> NLPScaling:
    """The factors as float64 JAX arrays (the runtime input of ``scaled_nlp``'s functions)."""
    return NLPScaling(*(jnp.asarray(a, dtype=jnp.float64) for a in s))
