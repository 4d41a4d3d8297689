"""The condensed KKT solve (local unknowns first, then the recursion over the stages) against
dense eigvalsh, scipy's sparse direct solve and the block LDL^T, on random staged matrices and on
the humanoid's KKT matrices; under vmap; inside the IPM."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse.linalg as spla
from test_kkt import random_staged_pattern, sparse_kkt

import jaxhumanoid  # noqa: F401  (float64)
import jaxhumanoid.validation.testproblems as tp
from jaxhumanoid.model.params import ContactParams
from jaxhumanoid.solvers.ipm import batch_solve_ipm, kkt, solve_ipm
from jaxhumanoid.solvers.ipm.kkt import condensed
from jaxhumanoid.strategy.posture import reseat_for_contact
from jaxhumanoid.strategy.problem import build_problem
from jaxhumanoid.studies.bench import BENCH_STAGE1_OPTIONS


def staged(seed, S, nx, nc, reverse=False):
    rng = np.random.default_rng(seed)
    n, m, vs, cs, hr, hc, jr, jc = random_staged_pattern(rng, S, nx, nc)
    if reverse:  # stage k becomes S-1-k: the structures order the blocks backwards
        vs, cs = S - 1 - vs, S - 1 - cs
    return rng, (n, m, vs, cs, hr, hc, jr, jc)


@pytest.mark.parametrize(
    "S,nx,nc,shift,reverse",
    [(5, 4, 3, 3.0, False), (12, 5, 4, 0.0, False), (20, 6, 5, 8.0, False), (9, 5, 3, 0.5, True)],
)
def test_inertia_and_solve_match_dense_and_block_ldl(S, nx, nc, shift, reverse):
    rng, pat = staged(S + nx, S, nx, nc, reverse)
    n, m, vs, cs, hr, hc, jr, jc = pat
    cst = kkt.build_condensed(*pat)
    st = cst.st
    assert cst.reversed == reverse and cst.nU + cst.nI >= st.nb - 1
    hv, jv = rng.standard_normal(hr.size), rng.standard_normal(jr.size)
    dx = rng.uniform(0.0, 1.0, n) + shift  # indefinite W where shift is small
    dc = -rng.uniform(0.0, 1e-3, m)
    A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    K = sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, dx, dc)
    ev = np.linalg.eigvalsh(K.toarray())
    cf, lf = condensed.factor(cst, A, B), kkt.factor(st, A, B)
    assert (int(cf.npos), int(cf.nneg), int(cf.nzero)) == (int(np.sum(ev > 0)), int(np.sum(ev < 0)), 0)
    assert (int(cf.npos), int(cf.nneg)) == (int(lf.npos), int(lf.nneg))
    assert bool(kkt.inertia_ok(st, cf)) == bool(kkt.inertia_ok(st, lf))
    rx, rc = rng.standard_normal(n), rng.standard_normal(m)
    ref = spla.spsolve(K, np.concatenate([rx, rc]))
    ux, uc, res = condensed.solve(cst, cf, A, B, jnp.asarray(rx), jnp.asarray(rc), with_residual=True)
    np.testing.assert_allclose(np.concatenate([ux, uc]), ref, rtol=1e-8, atol=1e-8)
    assert float(res) <= 1e-10 * np.max(np.abs(ref))


def test_singular_kkt_is_reported_and_delta_c_cures_it():
    # two identical equality rows and no dual regularisation: K is singular
    n, m = 3, 2
    pat = (n, m, np.zeros(3), np.zeros(2), np.arange(3), np.arange(3), np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]))
    cst = kkt.build_condensed(*pat)
    jv = jnp.array([1.0, 2.0, 1.0, 2.0])
    A, B = kkt.assemble(cst.st, jnp.ones(3), jv, jnp.zeros(3), jnp.zeros(2))
    cf = condensed.factor(cst, A, B)
    assert int(cf.nzero) >= 1 and not bool(kkt.inertia_ok(cst.st, cf))
    A, B = kkt.assemble(cst.st, jnp.ones(3), jv, jnp.zeros(3), -1e-8 * jnp.ones(2))
    assert bool(kkt.inertia_ok(cst.st, condensed.factor(cst, A, B)))


def test_vmapped_factor_and_solve_match_members():
    rng, pat = staged(3, 10, 5, 4)
    n, m, vs, cs, hr, hc, jr, jc = pat
    cst = kkt.build_condensed(*pat)
    hv, jv = rng.standard_normal(hr.size), rng.standard_normal(jr.size)
    dx0 = rng.uniform(0.0, 1.0, n)
    shifts = jnp.array([-2.0, 0.2, 5.0])  # wrong inertia, and right

    def one(t):
        A, B = kkt.assemble(cst.st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx0) + t, -1e-3 * jnp.ones(m))
        cf = condensed.factor(cst, A, B)
        return cf.npos, cf.nneg, condensed.solve(cst, cf, A, B, jnp.ones(n), jnp.ones(m))

    batched = jax.vmap(one)(shifts)
    for i, t in enumerate(shifts):
        single = one(t)
        assert int(batched[0][i]) == int(single[0]) and int(batched[1][i]) == int(single[1])
        np.testing.assert_allclose(np.asarray(batched[2][0][i]), np.asarray(single[2][0]), rtol=1e-9, atol=1e-12)
    assert len({int(v) for v in batched[1]}) > 1


def humanoid_kkt(prob, rng, dw, dc_ineq):
    """K at the problem's initial guess: the Lagrangian's Hessian with random multipliers, the
    IPM's diagonals (Sigma_x log-uniform on bounded variables, -D_c on inequality rows)."""
    nlp, b = prob.nlp, prob.bounds
    x = jnp.asarray(b.x0)
    lam = jnp.asarray(rng.standard_normal(nlp.m))
    hv = np.asarray(nlp.hess_values(x, lam, 1.0, prob.p))
    jv = np.asarray(nlp.jac_values(x, prob.p))
    bounded = np.isfinite(b.xl) | np.isfinite(b.xu)
    dx = np.where(bounded, 10.0 ** rng.uniform(-6, 6, nlp.n), 0.0) + dw
    dc = np.where(b.gl < b.gu, -dc_ineq(nlp.m), -1e-9)
    return hv, jv, dx, dc


def test_humanoid_split_inertia_and_solve():
    """T1 under A,F+C: the interior of a stage is its contact forces and the rows of their law
    (unit-triangular in f); inequality rows stay in the recursion, where a vanishing pivot
    -1/Sigma_s (an active row) cannot spoil the inertia. On the humanoid's KKT matrix with
    inequality pivots from 1e-20 to 1e8 and with and without delta_w, the condensed
    factorisation takes the block LDL^T's decisions (and its counts where K is regular), and the
    solve meets the sparse direct solve's accuracy."""
    prob = build_problem("T1", "A,F+C,2S", N=20)
    nlp = prob.nlp
    cst = kkt.condensed_structure_of(nlp)
    assert kkt.condensed_structure_of(nlp) is cst
    nf = 2 * len(prob.layout.active)
    assert (cst.nIx, cst.nI - cst.nIx) == (nf, nf)
    assert cst.nU < cst.st.nb - 10
    rng = np.random.default_rng(0)
    st = cst.st
    singular = 0
    for dw, dc_ineq in (
        (0.0, lambda m: 10.0 ** rng.uniform(-8, 8, m)),
        (0.0, lambda m: 10.0 ** rng.uniform(-20, -12, m)),
        (1e-4, lambda m: 10.0 ** rng.uniform(-8, 8, m)),
        (1e-4, lambda m: 10.0 ** rng.uniform(-20, -12, m)),
    ):
        hv, jv, dx, dc = humanoid_kkt(prob, rng, dw, dc_ineq)
        A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
        cf, lf = condensed.factor(cst, A, B), kkt.factor(st, A, B)
        # the IPM's decisions (inertia right, or K singular) agree; the counts too where K is regular
        assert bool(kkt.inertia_ok(st, cf)) == bool(kkt.inertia_ok(st, lf))
        assert (int(cf.nzero) > 0) == (int(lf.nzero) > 0)
        if int(lf.nzero) > 0:
            singular += 1
            continue
        assert (int(cf.npos), int(cf.nneg)) == (int(lf.npos), int(lf.nneg))
        K = sparse_kkt(nlp.n, nlp.m, nlp.hess_rows, nlp.hess_cols, hv, nlp.jac_rows, nlp.jac_cols, jv, dx, dc)
        r = rng.standard_normal(nlp.n + nlp.m)
        u = np.concatenate(condensed.solve(cst, cf, A, B, jnp.asarray(r[: nlp.n]), jnp.asarray(r[nlp.n :])))
        ref = spla.spsolve(K, r)
        scale = abs(K).sum(axis=1).max() * np.max(np.abs(u)) + np.max(np.abs(r))
        assert np.max(np.abs(K @ u - r)) <= max(1e-10 * scale, 10 * np.max(np.abs(K @ ref - r)))
    assert singular <= 2


def test_ipm_takes_the_same_steps_with_either_kkt_solve():
    """The IPM's iterates do not depend on which exact KKT solve runs: on the cart-pole (alone and
    in a vmapped batch) and on stage 1 of T3 (N1 = 10), the same iterations and the same optimum
    to rounding."""
    nlp, bounds, p, _ = tp.cartpole_swingup(N=25, P=1)
    a = solve_ipm(nlp, p, bounds)
    b = solve_ipm(nlp, p, bounds, options={"kkt_method": "condensed"})
    assert a.success and b.success and a.iterations == b.iterations
    assert abs(a.objective - b.objective) <= 1e-10 * abs(a.objective)
    # under the batch solve's vmap (local pivots batched over stages inside it), as each alone
    P = jnp.stack([p, p * jnp.array([1.0, 1.1, 1.0, 1.0, 1.0])])
    for member, alone in zip(batch_solve_ipm(nlp, P, bounds, options={"kkt_method": "condensed"}), (b, None)):
        alone = alone or solve_ipm(nlp, P[1], bounds, options={"kkt_method": "condensed"})
        assert member.success and member.iterations == alone.iterations
        assert abs(member.objective - alone.objective) <= 1e-9 * abs(alone.objective)
    relaxed = ContactParams.relaxed()
    final = build_problem("T3", "A,F+C,2S", N=20)
    q1, _ = reseat_for_contact(final.p, final.p.q_start, final.layout.active, relaxed)
    prob = build_problem("T3", "A,F+C,2S", N=10, pseudo_static=True, contact=relaxed, q_start=q1)
    runs = [
        solve_ipm(prob.nlp, prob.p, prob.bounds, options={**BENCH_STAGE1_OPTIONS, "kkt_method": k})
        for k in ("block_ldl", "condensed")
    ]
    assert runs[0].status == runs[1].status == "Solve_Succeeded"
    assert runs[0].iterations == runs[1].iterations
    assert abs(runs[0].objective - runs[1].objective) <= 1e-9 * abs(runs[0].objective)
    np.testing.assert_allclose(runs[1].x, runs[0].x, atol=1e-7)
