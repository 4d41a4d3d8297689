"""Inertia correction, Algorithm IC of the IPOPT paper (Sec. 3.1), with IPOPT's degeneracy test.

K of (13) must have inertia (n, m, 0). Trial factorisations add delta_w to the Hessian block
(first trial: 0, or with ``inertia_first_trial="last"`` the decreased memory perturb_dec_fact
delta_w_last once the Hessian's degeneracy is decided; after a wrong inertia:
``first_hessian_perturbation`` or max(min_hessian_perturbation, perturb_dec_fact delta_w_last),
then growth by perturb_inc_fact_first or perturb_inc_fact) and, when K is singular, delta_c =
jacobian_regularization_value mu^jacobian_regularization_exponent to the constraint block.

IPOPT's degeneracy test (PDPerturbationHandler): while it is undetermined whether the Hessian
(h) or the Jacobian (j) is structurally degenerate, the trial pattern (delta_c, delta_w) that
first succeeds decides it; a degenerate part is perturbed from the start of every later
iteration. Its state ``pert = (h, j, degen_iters)`` (int32 (3,)); h, j: 0 undetermined, 1 no,
2 yes.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax

from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.solvers.ipm.options import IPMOptions
from jaxhumanoid.solvers.ipm.problem import Context
from jaxhumanoid.solvers.ipm.state import Prob
from jaxhumanoid.solvers.ipm.step import assemble_base, factor_kkt, factorize

# the trial pattern of the degeneracy test: none, (0, 0), (delta_c, 0), (0, delta_w), (delta_c, delta_w)
T_NONE, T_00, T_C0, T_0X, T_CX = 0, 1, 2, 3, 4
UNDETERMINED, NOT_DEGENERATE, DEGENERATE = 0, 1, 2


class Inertia(NamedTuple):
    """Outcome of Algorithm IC: the accepted factorisation and the regularisation used."""

    A: jax.Array
    B: jax.Array
    fac: kkt.Factor | kkt.CondensedFactor
    invs: tuple  # eliminated rows' inverse pivots (``step.kkt_parts``)
    ok: jax.Array  # inertia (n, m, 0) reached
    dw: jax.Array  # delta_w, delta_c of the accepted factorisation
    dc: jax.Array
    dw_last: jax.Array  # the memory for the next iteration's first delta_w
    n_fact: jax.Array  # factorisations tried
    pert: jax.Array  # (3,) degeneracy test state


def finalize_test(o: IPMOptions, test, pert):
    """The degeneracy state after the trial ``test`` succeeded (or gave a wrong inertia): a
    success without delta_w decides "not degenerate" for the Hessian, one without delta_c for the
    Jacobian; a part that needed its perturbation ``degen_iters_max`` times is degenerate."""
    h, j, d = pert[0], pert[1], pert[2]
    t00 = test == T_00
    tc0 = test == T_C0
    t0x = test == T_0X
    tcx = test == T_CX
    d = d + jnp.where((tc0 & (j == UNDETERMINED)) | (t0x & (h == UNDETERMINED)) | tcx, 1, 0)
    h_n = jnp.where(
        (t00 | tc0) & (h == UNDETERMINED),
        NOT_DEGENERATE,
        jnp.where((t0x | tcx) & (h == UNDETERMINED) & (d >= o.degen_iters_max), DEGENERATE, h),
    )
    j_n = jnp.where(
        (t00 | t0x) & (j == UNDETERMINED),
        NOT_DEGENERATE,
        jnp.where((tc0 | tcx) & (j == UNDETERMINED) & (d >= o.degen_iters_max), DEGENERATE, j),
    )
    # IPOPT decides both at once on the plain trial when both are undetermined
    j_n = jnp.where(t00 & (h == UNDETERMINED) & (j == UNDETERMINED), NOT_DEGENERATE, j_n)
    return jnp.stack([h_n, j_n, d]).astype(jnp.int32)


def wrong_inertia_dw(o: IPMOptions, dw, dw_last):
    """The next delta_w after a wrong inertia at ``dw`` (IC-3 to IC-6)."""
    first = jnp.where(
        dw_last == 0.0,
        o.first_hessian_perturbation,
        jnp.maximum(o.min_hessian_perturbation, o.perturb_dec_fact * dw_last),
    )
    big = (dw_last == 0.0) | (1e5 * dw_last < dw)
    return jnp.where(dw == 0.0, first, jnp.where(big, o.perturb_inc_fact_first, o.perturb_inc_fact) * dw)


def singular_rule(test, pert, dc, delta_cd):
    """The next trial after a singular K (PerturbForSingularity): while the degeneracy test is
    undetermined, walk its pattern (0,0) -> (c,0) -> (0,x) -> (c,x); otherwise delta_c first,
    then delta_w.

    Returns (next delta_c, whether delta_w grows, next test)."""
    undetermined = (pert[0] == UNDETERMINED) | (pert[1] == UNDETERMINED)
    s_dc = jnp.where(
        undetermined,
        jnp.where(
            test == T_00,
            jnp.where(pert[1] == UNDETERMINED, delta_cd, dc),
            jnp.where(test == T_C0, 0.0, jnp.where(test == T_0X, delta_cd, dc)),
        ),
        jnp.where(dc > 0, dc, delta_cd),
    )
    s_dw_grow = jnp.where(undetermined, ~((test == T_00) & (pert[1] == UNDETERMINED)), dc > 0)
    s_test = jnp.where(
        undetermined,
        jnp.where(test == T_00, jnp.where(pert[1] == UNDETERMINED, T_C0, T_0X), jnp.where(test == T_C0, T_0X, T_CX)),
        T_NONE,
    )
    return s_dc, s_dw_grow, s_test


def inertia_corrected_factor(
    ctx: Context, P: Prob, rr, Wvals, jac, sig_x, sig_s, sig_p, sig_n, dw_last, mu, pert
) -> Inertia:
    """Algorithm IC (Sec. 3.1) with IPOPT's rules: the smallest delta_w giving inertia (n, m, 0),
    delta_c = jacobian_regularization_value mu^kappa_c when K is singular; all trial
    factorisations share one traced factorisation inside a while_loop."""
    o, st = ctx.o, ctx.st
    delta_cd = o.jacobian_regularization_value * mu**o.jacobian_regularization_exponent
    S_, nb = st.S, st.nb
    base = assemble_base(ctx, P, Wvals, jac)
    z3 = jnp.zeros((S_, nb, nb))
    # the loop's first carry: zeros shaped like the chosen method's factor (the loop runs once at least)
    fac0 = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(lambda: factor_kkt(ctx, z3, z3)))
    sigs = (sig_x, sig_s, sig_p, sig_n)
    undetermined0 = (pert[0] == UNDETERMINED) | (pert[1] == UNDETERMINED)
    test0 = jnp.where(undetermined0, T_00, T_NONE)
    dc0 = jnp.where(pert[1] == DEGENERATE, delta_cd, 0.0)
    warm = pert[0] == DEGENERATE
    if o.inertia_first_trial == "last":
        warm = warm | ((pert[0] == NOT_DEGENERATE) & (dw_last > 0.0))
    dw0 = jnp.where(warm, wrong_inertia_dw(o, 0.0, dw_last), 0.0)

    def cond(c):
        ok, dw, _, t = c[:4]
        return (~ok) & (dw <= o.max_hessian_perturbation) & (t < o.max_inertia_trials)

    def body(c):
        _, dw, dc, t, test, pert_ = c[:6]
        A_, B_, fac_, invs_ = factorize(ctx, P, rr, base, sigs, dw, dc)
        fac_ = fac_._replace(
            npos=fac_.npos.astype(jnp.int64), nneg=fac_.nneg.astype(jnp.int64), nzero=fac_.nzero.astype(jnp.int64)
        )
        ok = kkt.inertia_ok(st, fac_)
        singular = (~ok) & (fac_.nzero > 0)
        wrong = (~ok) & ~singular
        # wrong inertia: the test is decided (PerturbForWrongInertia), delta_w grows
        pert_ = jnp.where(wrong, finalize_test(o, test, pert_), pert_)
        s_dc, s_dw_grow, s_test = singular_rule(test, pert_, dc, delta_cd)
        dw_n = jnp.where(ok, dw, jnp.where(wrong | (singular & s_dw_grow), wrong_inertia_dw(o, dw, dw_last), dw))
        dc_n = jnp.where(singular, s_dc, dc)
        test_n = jnp.where(ok, test, jnp.where(singular, s_test, T_NONE))
        return ok, dw_n, dc_n, t + 1, test_n, pert_, A_, B_, fac_, invs_

    zm = jnp.zeros(ctx.m)
    ok, dw, dc, trials, test, pert, A, B, fac, invs = lax.while_loop(
        cond,
        body,
        (
            jnp.zeros((), bool),
            dw0,
            dc0,
            jnp.zeros((), jnp.int32),
            jnp.asarray(test0, jnp.int32),
            pert,
            z3,
            z3,
            fac0,
            (zm, zm, zm),
        ),
    )
    pert = jnp.where(ok, finalize_test(o, test, pert), pert)
    new_dw_last = jnp.where(ok & (dw > 0), dw, dw_last)
    return Inertia(A=A, B=B, fac=fac, invs=invs, ok=ok, dw=dw, dc=dc, dw_last=new_dw_last, n_fact=trials, pert=pert)
