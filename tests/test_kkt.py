"""Block-tridiagonal KKT solve and inertia vs scipy.sparse direct solve and dense eigvalsh."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.ocp.nlp import NLP
from jaxhumanoid.solvers.ipm import kkt
from jaxhumanoid.solvers.ipm.kkt import assembly, pivot, substitution


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
    dx = rng.uniform(0.0, 1.0, n) + shift  # indefinite W when shift == 0
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
    A, B = jax.vmap(
        lambda t: kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx0) + t, -1e-3 * jnp.ones(m))
    )(shifts)
    assert np.sum(np.asarray(kkt.pivot_paths(st, A[0], B[0], early_exit=True)) == 3) >= st.S // 2
    for sel, skipped in ((np.array([0, 1]), True), (np.array([0, 2]), False)):
        fb = jax.vmap(lambda A_, B_: kkt.factor(st, A_, B_, early_exit=True))(A[sel], B[sel])
        pb = np.asarray(jax.vmap(lambda A_, B_: kkt.pivot_paths(st, A_, B_, early_exit=True))(A[sel], B[sel]))
        assert np.any(pb == 3) == skipped
        for j, i in enumerate(sel):
            assert bool(kkt.inertia_ok(st, jax.tree.map(lambda a, j=j: a[j], fb))) == (i == 2)
        if not skipped:
            np.testing.assert_allclose(
                np.asarray(fb.N[1]), np.asarray(kkt.factor(st, A[2], B[2]).N), rtol=1e-12, atol=1e-14
            )


def test_singular_kkt_reports_zero_eigenvalue():
    # two identical equality-constraint rows, no dual regularisation: K is singular
    n, m = 3, 2
    st = kkt.build_structure(
        n, m, np.zeros(3), np.zeros(2), np.arange(3), np.arange(3), np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1])
    )
    A, B = kkt.assemble(st, jnp.ones(3), jnp.array([1.0, 2.0, 1.0, 2.0]), jnp.zeros(3), jnp.zeros(2))
    fac = kkt.factor(st, A, B)
    assert int(fac.nzero) >= 1
    assert not bool(kkt.inertia_ok(st, fac))
    A, B = kkt.assemble(st, jnp.ones(3), jnp.array([1.0, 2.0, 1.0, 2.0]), jnp.zeros(3), -1e-8 * jnp.ones(2))
    fac = kkt.factor(st, A, B)
    assert bool(kkt.inertia_ok(st, fac))


def test_structure_rejects_non_tridiagonal_coupling():
    with pytest.raises(ValueError, match="block-tridiagonal"):
        kkt.build_structure(
            3, 1, np.array([0, 1, 2]), np.array([0]), np.arange(3), np.arange(3), np.array([0, 0]), np.array([0, 2])
        )


def ocp_like_pattern(rng, S, nx, nc, n0):
    """Stage 0 has only n0 < nc variables (a fixed initial state), so the forward pivot block D_0
    is structurally singular; the rows of stage k act on stage k+1 through an identity-like part."""
    var_stage = np.concatenate([np.zeros(n0, np.int64), np.repeat(np.arange(1, S), nx)])
    con_stage = np.repeat(np.arange(S - 1), nc)
    first = np.concatenate([[0], np.cumsum([n0] + [nx] * (S - 1))])
    jr, jc = [], []
    for j, k in enumerate(con_stage):
        jr.append(j)
        jc.append(first[k + 1] + j % nc)  # x_{k+1} term
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
    dc = np.zeros(m)  # equality rows, no regularisation
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
        states = [] if k == 0 else [("q", i) for i in range(nq)] + [("v", i) for i in range(nq)]
        names = states + [("u", i) for i in range(nu)]
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
            ent = [
                (idx[k + 1][("v", i)], 1.0),
                (idx[k + 1][("q", (i + 1) % nq)], 0.3 * h),
                (idx[k][("u", i % nu)], -h),
            ] + ([(idx[k][("v", i)], -1.0)] if k else [])
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
        if k:  # q-v coupling within a stage
            for i in range(nq):
                r_, c_ = sorted((idx[k][("q", i)], idx[k][("v", i)]), reverse=True)
                hr.append(r_), hc.append(c_), hv.append(0.2)
    hr, hc, hv = np.array(hr), np.array(hc), np.array(hv)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    assert np.all(st.var_pos[vs == 0] // st.nb == 0)  # stage 0 is the border
    assert np.all(st.b_rows < st.nbx)  # fill on primal rows: diagonal R path
    dx = np.zeros(n)
    dx[rng.choice(n, 4, replace=False)] = 10.0 ** rng.uniform(-6, 6, 4)  # a few active bounds
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
        assert correct and np.sum(paths[1:] == 0) >= S - 2  # (nearly) every scanned block on the fast path
        # ... which the plain quasi-definite test (gamma = 0) would not give: P is indefinite
        d = kkt.equilibrate(A, B)
        As, _ = kkt.scale_blocks(A, B, d)
        assert np.all(np.isnan(np.asarray(jnp.linalg.cholesky(As[1:, : st.nbx, : st.nbx]))[:, -1, -1]))
    else:
        assert not correct and np.any(paths == 2)  # eigh fallback exercised
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
    solve = lambda A_, B_: kkt.solve(st, kkt.factor(st, A_, B_), A_, B_, r[:n], r[n:])  # noqa: E731
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
        if sel[1] == 1:  # the fallback member: more blocks on eigh
            assert np.sum(pb[1] == 2) > np.sum(pb[0] == 2)


# ------------------------------------------------------------------ the package's parts on their own
def tiny_staged_nlp_pattern(reverse=False):
    """Three stages: stage 0 holds x0, stage 1 (x1, x2), stage 2 (x3, x4); interval 0's rows
    c0 = (x0, x1), c1 = (x2); interval 1's rows c2 = (x1, x3), c3 = (x2, x4); diagonal Hessian.
    ``reverse``: the same with the stage ids mirrored (2 - k)."""
    vs, cs = np.array([0, 1, 1, 2, 2]), np.array([0, 0, 1, 1])
    if reverse:
        vs, cs = 2 - vs, 2 - cs
    jr, jc = np.array([0, 0, 1, 2, 2, 3, 3]), np.array([0, 1, 2, 1, 3, 2, 4])
    return 5, 4, vs, cs, np.arange(5), np.arange(5), jr, jc


def test_structure_of_a_tiny_staged_nlp():
    st = kkt.build_structure(*tiny_staged_nlp_pattern())
    assert (st.S, st.nb, st.nbx) == (3, 4, 2)
    # block k: [x.., primal padding | c.., dual padding], positions k * nb + local
    np.testing.assert_array_equal(st.var_pos, [0, 4, 5, 8, 9])
    np.testing.assert_array_equal(st.con_pos, [2, 3, 6, 7])
    np.testing.assert_array_equal(st.pad_pos, [1, 10, 11])
    np.testing.assert_array_equal(st.pad_sign, [1.0, -1.0, -1.0])
    assert (st.n_pad_pos, st.n_pad_neg) == (1, 2)
    # the couplings: K[x1, c0], K[x2, c1] in B_0 and K[x3, c2], K[x4, c3] in B_1, all on the
    # primal rows 0, 1 and the dual columns 2, 3
    np.testing.assert_array_equal(st.b_rows, [0, 1])
    np.testing.assert_array_equal(st.b_cols, [2, 3])
    _, B = kkt.assemble(st, jnp.arange(1.0, 6.0), jnp.arange(10.0, 17.0), jnp.zeros(5), -jnp.ones(4))
    B = np.asarray(B)
    assert B[0, 0, 2] == 11.0 and B[0, 1, 3] == 12.0 and B[1, 0, 2] == 14.0 and B[1, 1, 3] == 16.0
    assert np.count_nonzero(B) == 4
    # the Haynsworth caps: k (nb - nbx) + m_0 negative eigenvalues for blocks 1..k, at most m + 2
    np.testing.assert_array_equal(kkt.negative_caps(st), [2, 4, 6])
    # mirrored stage ids: "auto" puts stage 2 (now the one with one variable and two rows) first
    stm = kkt.build_structure(*tiny_staged_nlp_pattern(reverse=True))
    np.testing.assert_array_equal(stm.var_pos, st.var_pos)
    np.testing.assert_array_equal(stm.con_pos, st.con_pos)
    stf = kkt.build_structure(*tiny_staged_nlp_pattern(reverse=True), order="forward")
    assert stf.var_pos[0] // stf.nb == 2


def test_structure_is_cached_in_the_nlp():
    n, m, vs, cs, hr, hc, jr, jc = tiny_staged_nlp_pattern()
    fn = lambda *a: None  # never evaluated
    nlp = NLP(
        n=n,
        m=m,
        f=fn,
        g=fn,
        grad=fn,
        jac_values=fn,
        hess_values=fn,
        jac_rows=jr,
        jac_cols=jc,
        hess_rows=hr,
        hess_cols=hc,
        var_stage=vs,
        con_stage=cs,
    )
    st = kkt.structure_of(nlp)
    assert kkt.structure_of(nlp) is st and st in nlp.cache.values()
    assert not hasattr(nlp, "_kkt_structure_cache")
    np.testing.assert_array_equal(st.var_pos, kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc).var_pos)


def saddle_block(rng, nbx, R):
    """[[P, Q^T], [Q, R]] with P indefinite (eigenvalues of both signs) and Q of full row rank."""
    nc = R.shape[0]
    U = np.linalg.qr(rng.standard_normal((nbx, nbx)))[0]
    P = U @ np.diag(np.linspace(-0.5, 1.0, nbx)) @ U.T
    Q = rng.standard_normal((nc, nbx))
    return np.block([[P, Q.T], [Q, R]])


def inverse_of(N, sgn):
    return np.asarray(N) @ np.diag(np.asarray(sgn)) @ np.asarray(N).T


def test_quasidefinite_pivot_certifies_an_indefinite_primal_block():
    rng = np.random.default_rng(2)
    nbx, nc = 3, 2
    D = saddle_block(rng, nbx, np.zeros((nc, nc)))
    # P indefinite with nc < nbx: inertia (nbx, nc, 0) iff P is definite on null(Q); make it so
    Z = np.linalg.svd(D[nbx:, :nbx])[2][nc:].T
    D[:nbx, :nbx] += Z @ Z.T
    ev = np.linalg.eigvalsh(D)
    assert (np.sum(ev > 0), np.sum(ev < 0)) == (nbx, nc)
    N, ok = pivot.quasidefinite_block(jnp.asarray(D), nbx)
    assert bool(ok)
    np.testing.assert_allclose(inverse_of(N, np.r_[np.ones(nbx), -np.ones(nc)]), np.linalg.inv(D), rtol=1e-9, atol=1e-9)
    _, ok0 = pivot.quasidefinite_block(jnp.asarray(D), nbx, gamma=0.0)  # plain test: P indefinite
    assert not bool(ok0)
    Nk, sgn, info = pivot.pivot(jnp.asarray(D), nbx, True, 1e-12)
    np.testing.assert_array_equal(np.asarray(info), [nc, 0, 0])
    np.testing.assert_allclose(inverse_of(Nk, sgn), np.linalg.inv(D), rtol=1e-9, atol=1e-9)


def test_diagonal_dual_fast_path_matches_the_general_one():
    rng = np.random.default_rng(4)
    nbx, nc = 3, 2
    A = jnp.asarray(saddle_block(rng, nbx, np.diag([-1e-3, -1e-2]))[None])
    Z = np.linalg.svd(np.asarray(A[0, nbx:, :nbx]))[2][nc:].T
    A = A.at[0, :nbx, :nbx].add(Z @ Z.T)
    Pt, Qt, Rd = pivot.qd_diag_pre(A, nbx)
    Nd, okd = pivot.qd_diag_core(Pt[0], Qt[0], Rd[0])
    Ng, okg = pivot.quasidefinite_block(A[0], nbx)
    assert bool(okd) and bool(okg)
    sgn = np.r_[np.ones(nbx), -np.ones(nc)]
    np.testing.assert_allclose(inverse_of(Nd, sgn), np.linalg.inv(np.asarray(A[0])), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(inverse_of(Nd, sgn), inverse_of(Ng, sgn), rtol=1e-9, atol=1e-9)
    # R with a positive entry: M = I - gamma R is not positive definite, the path reports failure
    Ab = A.at[0, nbx, nbx].set(1.0)
    Pt, Qt, Rd = pivot.qd_diag_pre(Ab, nbx)
    assert not bool(pivot.qd_diag_core(Pt[0], Qt[0], Rd[0])[1])


def test_eigen_pivot_counts_signs_and_zeros():
    rng = np.random.default_rng(6)
    U = np.linalg.qr(rng.standard_normal((4, 4)))[0]
    D = U @ np.diag([3.0, -2.0, 0.0, 1e-3]) @ U.T
    _, _, info = pivot.eigen_pivot(jnp.asarray(D), 1e-10)
    np.testing.assert_array_equal(np.asarray(info), [1, 1, 2])
    D[2, 2] += 0.5  # nonsingular: an exact inverse
    ev = np.linalg.eigvalsh(D)
    N, sgn, info = pivot.eigen_pivot(jnp.asarray(D), 1e-10)
    np.testing.assert_array_equal(np.asarray(info), [np.sum(ev < 0), 0, 2])
    np.testing.assert_allclose(inverse_of(N, sgn), np.linalg.inv(D), rtol=1e-10, atol=1e-10)
    _, _, info = pivot.eigen_pivot(jnp.asarray(np.where(np.eye(4) > 0, np.nan, D)), 1e-10)
    np.testing.assert_array_equal(np.asarray(info), [0, 4, 2])  # non-finite: all zero
    # a block without inertia (nbx, nc, 0) leaves the fast path for the eigendecomposition
    Dw = np.diag([1.0, 1.0, 1.0, -1.0])
    _, sgn, info = pivot.pivot(jnp.asarray(Dw), 2, True, 1e-10)
    np.testing.assert_array_equal(np.asarray(info), [1, 0, 2])
    assert sorted(np.asarray(sgn)) == [-1.0, 1.0, 1.0, 1.0]


def test_refinement_meets_the_residual_ratio_and_reports_the_residual():
    rng = np.random.default_rng(8)
    n, m, vs, cs, hr, hc, jr, jc = random_staged_pattern(rng, 6, 4, 3)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    hv, jv = rng.standard_normal(hr.size), rng.standard_normal(jr.size)
    dx = 10.0 ** rng.uniform(-6, 6, n)  # graded barrier terms
    dc = -(10.0 ** rng.uniform(-8, -2, m))
    A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    fac = kkt.factor(st, A, B)
    assert int(fac.nzero) == 0
    rx, rc = jnp.asarray(rng.standard_normal(n)), jnp.asarray(rng.standard_normal(m))
    ux, uc, res = kkt.solve(st, fac, A, B, rx, rc, with_residual=True)
    K = sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, dx, dc)
    r, u = np.concatenate([rx, rc]), np.concatenate([ux, uc])
    res_np = np.max(np.abs(r - K @ u))
    knorm = abs(K).sum(axis=1).max()
    eps = np.finfo(float).eps
    assert abs(float(res) - res_np) <= 100 * eps * (knorm * np.max(np.abs(u)) + np.max(np.abs(r)))
    u_blk, r_blk = kkt.to_blocks(st, ux, uc), kkt.to_blocks(st, rx, rc)
    res_blk = r_blk - kkt.matvec(A, B, u_blk)
    ratio = substitution.refinement_ratio(fac, u_blk, res_blk, jnp.max(jnp.abs(fac.d * r_blk)))
    assert float(ratio) <= 1e-10
    # no refinement: one plain block solve
    px, pc = kkt.solve(st, fac, A, B, rx, rc, min_steps=0, max_steps=0)
    plain = kkt.solve_vec(st, fac, kkt.border_coupling(st, fac, B), r_blk)
    np.testing.assert_allclose(
        np.concatenate([px, pc]), np.concatenate(kkt.from_blocks(st, plain)), rtol=1e-12, atol=1e-14 * np.max(np.abs(u))
    )


def test_block_products_and_compact_equilibration():
    rng = np.random.default_rng(9)
    n, m, vs, cs, hr, hc, jr, jc = random_staged_pattern(rng, 5, 4, 3)
    st = kkt.build_structure(n, m, vs, cs, hr, hc, jr, jc)
    hv, jv = rng.standard_normal(hr.size), rng.standard_normal(jr.size)
    dx, dc = 10.0 ** rng.uniform(-4, 4, n), -(10.0 ** rng.uniform(-6, 0, m))
    A, B = kkt.assemble(st, jnp.asarray(hv), jnp.asarray(jv), jnp.asarray(dx), jnp.asarray(dc))
    rx, rc = jnp.asarray(rng.standard_normal(n)), jnp.asarray(rng.standard_normal(m))
    u = kkt.to_blocks(st, rx, rc)
    back = kkt.from_blocks(st, u)
    np.testing.assert_array_equal(back[0], rx)
    np.testing.assert_array_equal(back[1], rc)
    assert np.all(np.asarray(u).reshape(-1)[st.pad_pos] == 0.0)
    K = sparse_kkt(n, m, hr, hc, hv, jr, jc, jv, dx, dc)
    y = kkt.from_blocks(st, kkt.matvec(A, B, u))
    np.testing.assert_allclose(np.concatenate(y), K @ np.concatenate([rx, rc]), rtol=1e-12, atol=1e-12)
    yc = assembly.matvec_compact(st, A, B, u)
    np.testing.assert_allclose(yc, kkt.matvec(A, B, u), rtol=1e-13, atol=1e-13)
    d, As, Bc = assembly.equilibrate_compact(st, A, B)
    d_ref = kkt.equilibrate(A, B)
    As_ref, Bs_ref = kkt.scale_blocks(A, B, d_ref)
    np.testing.assert_allclose(d, d_ref, rtol=1e-14)
    np.testing.assert_allclose(As, As_ref, rtol=1e-14, atol=1e-300)
    np.testing.assert_allclose(Bc, np.asarray(Bs_ref)[:, st.b_rows][:, :, st.b_cols], rtol=1e-14, atol=1e-300)
    # after equilibration every row of K has largest entry close to 1
    Ks = kkt.dense_matrix(st, *kkt.scale_blocks(A, B, d))
    assert np.all(np.abs(np.max(np.abs(Ks), axis=1) - 1.0) < 0.5)
