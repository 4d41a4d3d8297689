"""Block-tridiagonal KKT solve and inertia vs scipy.sparse direct solve and dense eigvalsh."""

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import jaxhumanoid  # noqa: F401  (float64)
import jax
import jax.numpy as jnp

from jaxhumanoid.solvers.ipm import kkt


def random_staged_pattern(rng, S, nx, nc):
    """Variables/constraints per stage, Jacobian coupling stages k and k+1, Hessian k,k+1."""
    var_stage = np.repeat(np.arange(S), nx)
    con_stage = np.repeat(np.arange(S - 1), nc) if S > 1 else np.repeat([0], nc)
    # shuffle the global numbering so stage ordering is not the identity permutation
    n, m = var_stage.size, con_stage.size
    pv = rng.permutation(n)
    pc = rng.permutation(m)
    var_stage = var_stage[pv]
    con_stage = con_stage[pc]
    jr, jc = [], []
    for j in range(m):
        k = con_stage[j]
        cand = np.nonzero((var_stage == k) | (var_stage == k + 1))[0]
        for i in rng.choice(cand, size=min(len(cand), 5), replace=False):
            jr.append(j)
            jc.append(i)
    hr, hc = [], []
    for i in range(n):
        hr.append(i)
        hc.append(i)
        cand = np.nonzero(np.abs(var_stage - var_stage[i]) <= 1)[0]
        for i2 in rng.choice(cand, size=min(len(cand), 3), replace=False):
            r, c = max(i, i2), min(i, i2)
            if r != c:
                hr.append(r)
                hc.append(c)
    h = np.unique(np.stack([hr, hc], 1), axis=0)
    jj = np.unique(np.stack([jr, jc], 1), axis=0)
    return n, m, var_stage, con_stage, h[:, 0], h[:, 1], jj[:, 0], jj[:, 1]


def sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, dx, dc):
    W = sp.coo_matrix((hv, (hr, hc)), shape=(n, n)).tocsr()
    W = W + sp.triu(W.T, k=1) + sp.diags(dx)
    J = sp.coo_matrix((jv, (jr, jc)), shape=(m, n)).tocsr()
    return sp.bmat([[W, J.T], [J, sp.diags(dc)]]).tocsc()


@pytest.mark.parametrize("S,nx,nc,shift", [(1, 6, 3, 0.0), (5, 4, 3, 0.0), (12, 5, 4, 3.0), (30, 6, 5, 8.0)])
def test_block_tridiagonal_solve_and_inertia(S, nx, nc, shift):
    rng = np.random.default_rng(S * 100 + nx)
    n, m, vs, cs, hr, hc, jr, jc = random_staged_pattern(rng, S, nx, nc)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    assert st.S == S and st.size >= n + m
    hv = rng.standard_normal(hr.size)
    jv = rng.standard_normal(jr.size)
    dx = rng.uniform(0.0, 1.0, n) + shift      # indefinite W when shift == 0
    dc = -rng.uniform(0.0, 1e-3, m)
    A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    K = sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, dx, dc)
    ev = np.linalg.eigvalsh(K.toarray())
    rx, rc = rng.standard_normal(n), rng.standard_normal(m)
    ref = spla.spsolve(K, np.concatenate([rx, rc]))
    # Cholesky fast path with eigh fallback / eigh only (the latter where W is indefinite; each
    # variant costs a compilation)
    for fast in (True, False) if shift == 0.0 else (True,):
        fac = kkt.factor(st, A, B, fast=fast)
        assert int(fac.npos) == int(np.sum(ev > 0))
        assert int(fac.nneg) == int(np.sum(ev < 0))
        assert int(fac.nzero) == 0
        ux, uc = kkt.solve(st, fac, A, B, jnp.asarray(rx), jnp.asarray(rc))
        np.testing.assert_allclose(np.concatenate([ux, uc]), ref, rtol=1e-8, atol=1e-8)
    # the dense stage-ordered matrix is a symmetric permutation of K, padding aside
    Kd = kkt.dense_matrix(st, A, B)
    perm = np.concatenate([st.var_pos, st.con_pos])
    np.testing.assert_allclose(Kd[np.ix_(perm, perm)], K.toarray(), atol=1e-14)


def test_early_exit_decides_inertia_as_the_full_factorisation():
    # the IPM's inertia-correction trials stop eliminating once the inertia is known not to be
    # (n, m, 0) (kkt.negative_caps); over Hessian shifts across the change of inertia, the
    # decision must equal the full factorisation's, and a matrix with the right inertia must be
    # factored exactly as without the exit
    rng = np.random.default_rng(11)
    n, m, vs, cs, hr, hc, jr, jc = random_staged_pattern(rng, 30, 6, 5)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    hv, jv = rng.standard_normal(hr.size), rng.standard_normal(jr.size)
    dx0 = rng.uniform(0.0, 1.0, n)
    exits = 0
    for shift in (-3.0, -1.5, -0.5, 0.0, 0.3, 0.6, 1.0, 1.5, 2.0, 3.0, 8.0):
        A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx0 + shift), -1e-3 * jnp.ones(m))
        full, early = kkt.factor(st, A, B), kkt.factor(st, A, B, early_exit=True)
        paths = np.asarray(kkt.pivot_paths(st, A, B, early_exit=True))
        ok = bool(kkt.inertia_ok(st, full))
        assert bool(kkt.inertia_ok(st, early)) == ok, shift
        done = paths != 3
        np.testing.assert_array_equal(np.asarray(early.N)[done], np.asarray(full.N)[done])
        if ok:
            assert np.all(done)
        exits += int(not done[0])
        if not done[1]:
            assert not ok and int(early.nneg) < int(full.nneg)
    assert exits >= 3
    # the exit comes early where W is indefinite everywhere; under vmap a block is skipped only
    # where every member has decided, and each member decides as alone
    shifts = jnp.array([-3.0, -1.5, 8.0])
    A, B = jax.vmap(lambda t: kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx0) + t,
                                           -1e-3 * jnp.ones(m)))(shifts)
    assert np.sum(np.asarray(kkt.pivot_paths(st, A[0], B[0], early_exit=True)) == 3) >= st.S // 2
    for sel, skipped in ((np.array([0, 1]), True), (np.array([0, 2]), False)):
        fb = jax.vmap(lambda A_, B_: kkt.factor(st, A_, B_, early_exit=True))(A[sel], B[sel])
        pb = np.asarray(jax.vmap(lambda A_, B_: kkt.pivot_paths(st, A_, B_, early_exit=True))(A[sel], B[sel]))
        assert np.any(pb == 3) == skipped
        for j, i in enumerate(sel):
            assert bool(kkt.inertia_ok(st, jax.tree.map(lambda a: a[j], fb))) == (i == 2)
        if not skipped:
            np.testing.assert_allclose(np.asarray(fb.N[1]), np.asarray(kkt.factor(st, A[2], B[2]).N), rtol=1e-12, atol=1e-14)


def test_singular_kkt_reports_zero_eigenvalue():
    # two identical equality-constraint rows, no dual regularisation: K is singular
    n, m = 3, 2
    st = kkt.build_structure(n, m, np.zeros(3), np.zeros(2), np.arange(3), np.arange(3),
                             np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]))
    A, B = kkt.assemble(st, jnp.ones(3), jnp.array([1.0, 2.0, 1.0, 2.0]), jnp.zeros(3), jnp.zeros(2))
    fac = kkt.factor(st, A, B)
    assert int(fac.nzero) >= 1
    assert not bool(kkt.inertia_ok(st, fac))
    A, B = kkt.assemble(st, jnp.ones(3), jnp.array([1.0, 2.0, 1.0, 2.0]), jnp.zeros(3),
                        -1e-8 * jnp.ones(2))
    fac = kkt.factor(st, A, B)
    assert bool(kkt.inertia_ok(st, fac))


def test_structure_rejects_non_tridiagonal_coupling():
    with pytest.raises(ValueError, match="block-tridiagonal"):
        kkt.build_structure(3, 1, np.array([0, 1, 2]), np.array([0]), np.arange(3), np.arange(3),
                            np.array([0, 0]), np.array([0, 2]))


def ocp_like_pattern(rng, S, nx, nc, n0):
    """Stage 0 has only n0 < nc variables (a fixed initial state), so the forward pivot block D_0
    is structurally singular; the rows of stage k act on stage k+1 through an identity-like part."""
    var_stage = np.concatenate([np.zeros(n0, np.int64), np.repeat(np.arange(1, S), nx)])
    con_stage = np.repeat(np.arange(S - 1), nc)
    first = np.concatenate([[0], np.cumsum([n0] + [nx] * (S - 1))])
    jr, jc = [], []
    for j, k in enumerate(con_stage):
        jr.append(j)
        jc.append(first[k + 1] + j % nc)                      # x_{k+1} term
        own = np.arange(first[k], first[k + 1])
        for i in rng.choice(own, size=min(2, own.size), replace=False):
            jr.append(j)
            jc.append(i)
    n = var_stage.size
    hr, hc = np.arange(n), np.arange(n)
    jj = np.unique(np.stack([jr, jc], 1), axis=0)
    return n, con_stage.size, var_stage, con_stage, hr, hc, jj[:, 0], jj[:, 1]


def test_structurally_singular_first_block_is_eliminated_last():
    rng = np.random.default_rng(7)
    n, m, vs, cs, hr, hc, jr, jc = ocp_like_pattern(rng, S=8, nx=5, nc=4, n0=2)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    # stage 0 is block 0, the border of the arrowhead order 1, ..., S-1, 0: eliminated last
    assert np.all(st.var_pos[vs == 0] // st.nb == 0), "stage 0 must be the border (last pivot) block"
    hv = rng.uniform(0.5, 2.0, hr.size)
    jv = rng.standard_normal(jr.size)
    dc = np.zeros(m)                                           # equality rows, no regularisation
    A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.zeros(n), jnp.asarray(dc))
    K = sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, np.zeros(n), dc)
    ev = np.linalg.eigvalsh(K.toarray())
    fac = kkt.factor(st, A, B)
    assert (int(fac.npos), int(fac.nneg), int(fac.nzero)) == (int(np.sum(ev > 0)), int(np.sum(ev < 0)), 0)
    assert bool(kkt.inertia_ok(st, fac))
    r = rng.standard_normal(n + m)
    ux, uc = kkt.solve(st, fac, A, B, jnp.asarray(r[:n]), jnp.asarray(r[n:]))
    np.testing.assert_allclose(np.concatenate([ux, uc]), spla.spsolve(K, r), rtol=1e-8, atol=1e-8)



def double_integrator_pattern(S, nq, nu, h=0.1):
    """A transcribed OCP: stage k holds (q_k, v_k, u_k), stage 0 only u_0 (fixed initial state);
    the 2 nq equality rows of interval k are q_{k+1} - q_k - h v_{k+1} and v_{k+1} - v_k - h u_k
    (plus a coupling of v_{k+1} to q_{k+1}, a linearised force). Interval 0's rows outnumber
    stage 0's variables, so stage 0 must be the border block."""
    idx, var_stage = [], []
    for k in range(S):
        names = ([] if k == 0 else [("q", i) for i in range(nq)] + [("v", i) for i in range(nq)]) + [("u", i) for i in range(nu)]
        idx.append({nm: len(var_stage) + j for j, nm in enumerate(names)})
        var_stage += [k] * len(names)
    jr, jc, jv, con_stage = [], [], [], []
    for k in range(S - 1):
        for i in range(nq):
            j = len(con_stage)
            ent = [(idx[k + 1][("q", i)], 1.0), (idx[k + 1][("v", i)], -h)] + ([(idx[k][("q", i)], -1.0)] if k else [])
            for c, v in ent:
                jr.append(j), jc.append(c), jv.append(v)
            con_stage.append(k)
            j = len(con_stage)
            ent = [(idx[k + 1][("v", i)], 1.0), (idx[k + 1][("q", (i + 1) % nq)], 0.3 * h), (idx[k][("u", i % nu)], -h)] \
                + ([(idx[k][("v", i)], -1.0)] if k else [])
            for c, v in ent:
                jr.append(j), jc.append(c), jv.append(v)
            con_stage.append(k)
    n = len(var_stage)
    return n, len(con_stage), idx, np.array(var_stage), np.array(con_stage), np.array(jr), np.array(jc), np.array(jv)


@pytest.mark.parametrize("q_curv", [-0.5, -40.0])
def test_indefinite_state_hessian_fast_path_and_fallback(q_curv):
    """The joint-angle Hessian of the humanoid comes only from constraint curvature and is
    indefinite: the plain quasi-definite test fails on every pivot block, the gamma-congruence
    fast path (Cholesky only) certifies them; with strong negative curvature K has the wrong
    inertia and the blocks fall back to eigh. Inertia against eigvalsh, solution against spsolve."""
    rng = np.random.default_rng(3)
    S, nq, nu = 9, 3, 2
    n, m, idx, vs, cs, jr, jc, jv = double_integrator_pattern(S, nq, nu)
    hr, hc, hv = [], [], []
    for k in range(S):
        for nm, i in idx[k].items():
            hr.append(i), hc.append(i)
            hv.append({"q": q_curv, "v": 1.0, "u": 1e-2}[nm[0]] * rng.uniform(0.5, 1.5))
        if k:                                  # q-v coupling within a stage
            for i in range(nq):
                r_, c_ = sorted((idx[k][("q", i)], idx[k][("v", i)]), reverse=True)
                hr.append(r_), hc.append(c_), hv.append(0.2)
    hr, hc, hv = np.array(hr), np.array(hc), np.array(hv)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    assert np.all(st.var_pos[vs == 0] // st.nb == 0)          # stage 0 is the border
    assert np.all(st.b_rows < st.nbx)                         # fill on primal rows: diagonal R path
    dx = np.zeros(n)
    dx[rng.choice(n, 4, replace=False)] = 10.0 ** rng.uniform(-6, 6, 4)   # a few active bounds
    dc = np.zeros(m)
    A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    K = sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, dx, dc)
    ev = np.linalg.eigvalsh(K.toarray())
    fac = kkt.factor(st, A, B)
    paths = np.asarray(kkt.pivot_paths(st, A, B))
    assert (int(fac.npos), int(fac.nneg), int(fac.nzero)) == (int(np.sum(ev > 0)), int(np.sum(ev < 0)), 0)
    correct = int(np.sum(ev > 0)) == n
    assert bool(kkt.inertia_ok(st, fac)) == correct
    if q_curv == -0.5:
        assert correct and np.sum(paths[1:] == 0) >= S - 2   # (nearly) every scanned block on the fast path
        # ... which the plain quasi-definite test (gamma = 0) would not give: P is indefinite
        d = kkt.equilibrate(A, B)
        As, _ = kkt.scale_blocks(A, B, d)
        assert np.all(np.isnan(np.asarray(jnp.linalg.cholesky(As[1:, :st.nbx, :st.nbx]))[:, -1, -1]))
    else:
        assert not correct and np.any(paths == 2)          # eigh fallback exercised
    r = rng.standard_normal(n + m)
    ux, uc = kkt.solve(st, fac, A, B, jnp.asarray(r[:n]), jnp.asarray(r[n:]))
    np.testing.assert_allclose(np.concatenate([ux, uc]), spla.spsolve(K, r), rtol=1e-8, atol=1e-8)
    if q_curv != -0.5:
        return
    # the general (non-diagonal R) fast path: the reverse orientation puts fill on constraint rows
    stb = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc, order="backward")
    Ab, Bb = kkt.assemble(stb, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    facb = kkt.factor(stb, Ab, Bb)
    assert (int(facb.npos), int(facb.nneg), int(facb.nzero)) == (int(np.sum(ev > 0)), int(np.sum(ev < 0)), 0)
    ux, uc = kkt.solve(stb, facb, Ab, Bb, jnp.asarray(r[:n]), jnp.asarray(r[n:]))
    np.testing.assert_allclose(np.concatenate([ux, uc]), spla.spsolve(K, r), rtol=1e-8, atol=1e-8)


def test_vmapped_factor_matches_members_with_mixed_pivot_paths():
    """Under vmap the fast/eigendecomposition choice of each pivot block has its own batching rule
    (eigendecompose only when some member needs it): a batch of a matrix whose blocks (nearly)
    all take the fast path and one that falls back to eigh (strong negative curvature, wrong
    inertia) gives each member's own pivot paths, inertia and solution, as factored alone; so
    does a batch of two members with correct inertia."""
    rng = np.random.default_rng(5)
    S, nq, nu = 9, 3, 2
    n, m, idx, vs, cs, jr, jc, jv = double_integrator_pattern(S, nq, nu)
    hr = np.array([i for k in range(S) for i in idx[k].values()])
    scale = {"q": 1.0, "v": 1.0, "u": 1e-2}
    kind = np.array([scale[nm[0]] for k in range(S) for nm in idx[k]])
    is_q = np.array([nm[0] == "q" for k in range(S) for nm in idx[k]])
    st = kkt.build_structure(n, m, vs, cs, hr, hr, jr, jc)
    dx, dc = jnp.zeros(n), jnp.zeros(m)
    hvs = [np.where(is_q, q_curv, kind) * rng.uniform(0.5, 1.5, n) for q_curv in (-0.5, -40.0, 0.7)]
    A, B = jax.vmap(lambda hv: kkt.assemble(st, hv, jnp.asarray(jv), dx, dc))(jnp.asarray(np.stack(hvs)))
    r = jnp.asarray(rng.standard_normal(n + m))
    solve = lambda A_, B_: kkt.solve(st, kkt.factor(st, A_, B_), A_, B_, r[:n], r[n:])   # noqa: E731
    for sel in (np.array([0, 1]), np.array([0, 2])):
        fb = jax.vmap(lambda A_, B_: kkt.factor(st, A_, B_))(A[sel], B[sel])
        pb = np.asarray(jax.vmap(lambda A_, B_: kkt.pivot_paths(st, A_, B_))(A[sel], B[sel]))
        ub = jax.vmap(solve)(A[sel], B[sel])
        for j, i in enumerate(sel):
            f1 = kkt.factor(st, A[i], B[i])
            assert (int(fb.npos[j]), int(fb.nneg[j]), int(fb.nzero[j])) == (int(f1.npos), int(f1.nneg), int(f1.nzero))
            np.testing.assert_array_equal(pb[j], np.asarray(kkt.pivot_paths(st, A[i], B[i])))
            u1 = solve(A[i], B[i])
            np.testing.assert_allclose(np.concatenate([ub[0][j], ub[1][j]]), np.concatenate(u1), rtol=1e-10, atol=1e-12)
        if sel[1] == 1:                                   # the fallback member: more blocks on eigh
            assert np.sum(pb[1] == 2) > np.sum(pb[0] == 2)
