"""The checks bite: deliberately broken NLPs fail cross-validation and finite differences, the
intact one passes."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhumanoid  # noqa: F401  (float64)
from jaxhumanoid.model import dynamics as dyn
from jaxhumanoid.ocp import transcription as tr
from jaxhumanoid.strategy.problem import build_problem, stage_problem
from jaxhumanoid.validation import checks


@pytest.fixture(scope="module")
def problem():
    return build_problem("T1", "A,F,1S", N=6)


def _by_name(rows):
    return {r.quantity: r for r in rows}


def _with_nlp(problem, **changes):
    return dataclasses.replace(problem, nlp=dataclasses.replace(problem.nlp, **changes))


def _coriolis_flipped(problem):
    """g with the sign of the Coriolis/centrifugal term C qd of (6b) flipped in every interval."""
    layout, nlp = problem.layout, problem.nlp

    def g(x, p):
        Z = tr.full_from_free(layout, x, p)
        qbar = 0.5 * (Z[:-1, 0:5] + Z[1:, 0:5])
        qdbar = 0.5 * (Z[:-1, 5:10] + Z[1:, 5:10])
        cqd = jax.vmap(lambda a, b: dyn.coriolis_vector(p.model, a, b))(qbar, qdbar)
        h = p.T / layout.N
        G = nlp.g(x, p).reshape(layout.N, layout.n_con)
        return G.at[:, 5:10].add(-2.0 * h * cqd).ravel()

    return _with_nlp(problem, g=g)


def _foot_rows_shifted(problem):
    """g whose steady-foot rows (5) of interval k hold those of interval k+1 (a stage-index slip)."""
    layout, nlp = problem.layout, problem.nlp
    foot = slice(10 + layout.n_f, 15 + layout.n_f)

    def g(x, p):
        G = nlp.g(x, p).reshape(layout.N, layout.n_con)
        return G.at[:-1, foot].set(G[1:, foot]).ravel()

    return _with_nlp(problem, g=g)


def _jacobian_entry_dropped(problem):
    """The Jacobian pattern without its largest entry at the start point."""
    nlp = problem.nlp
    drop = int(np.argmax(np.abs(np.asarray(nlp.jac_values(problem.bounds.x0, problem.p)))))
    keep = np.delete(np.arange(nlp.nnz_jac), drop)
    return _with_nlp(
        problem,
        jac_rows=nlp.jac_rows[keep],
        jac_cols=nlp.jac_cols[keep],
        jac_values=lambda x, p: nlp.jac_values(x, p)[keep],
    )


def _hessian_objective_doubled(problem):
    """Hessian values with the objective weight sigma doubled."""
    nlp = problem.nlp
    return _with_nlp(problem, hess_values=lambda x, lam, sigma, p: nlp.hess_values(x, lam, 2.0 * sigma, p))


def test_intact_problem_passes(problem):
    rows = checks.cross_validate(problem, points=1, seed=1) + checks.finite_difference_check(problem, seed=1)
    assert all(r.ok for r in rows), [r for r in rows if not r.ok]


def test_coriolis_sign_flip_is_caught(problem):
    bad = _coriolis_flipped(problem)
    cross = _by_name(checks.cross_validate(bad, points=1, seed=1))
    assert not cross["g"].ok and cross["g"].value > 1e-6
    fd = _by_name(checks.finite_difference_check(bad, seed=1, columns=200))
    assert not fd["jacobian"].ok


def test_stage_index_slip_is_caught(problem):
    cross = _by_name(checks.cross_validate(_foot_rows_shifted(problem), points=1, seed=1))
    assert not cross["g"].ok and cross["g"].value > 1e-3


def test_dropped_jacobian_entry_is_caught(problem):
    # At random points the contact-law entries may underflow to 0 (large gaps), so check at x0.
    cross = _by_name(checks.cross_validate(_jacobian_entry_dropped(problem), points=0, x=problem.bounds.x0))
    assert cross["jacobian pattern"].value >= 1 and not cross["jacobian pattern"].ok
    assert not cross["jacobian"].ok


def test_wrong_hessian_is_caught(problem):
    bad = _hessian_objective_doubled(problem)
    fd = _by_name(checks.finite_difference_check(bad, seed=1))
    assert not fd["hessian-vector f"].ok and fd["hessian-vector lam.g"].ok
    assert not _by_name(checks.cross_validate(bad, points=1, seed=1))["hessian (tril)"].ok


def test_table_rows_and_format():
    problems = [(checks.case_label("T1", "A,F+C,1S", True, 4), stage_problem("T1", "A,F+C,1S", 4, True))]
    rows = checks.check_table(problems, points=1)
    assert rows and all(r["ok"] for r in rows)
    assert {"case", "check", "quantity", "value", "tol", "ok"} <= set(rows[0])
    text = checks.format_table(rows)
    assert "hessian (tril)" in text and "NO" not in text


def test_bad_arguments(problem):
    with pytest.raises(ValueError, match="points"):
        checks.cross_validate(problem, points=-1)
    with pytest.raises(ValueError, match="x"):
        checks.cross_validate(problem, points=1, x=np.zeros(3))
    with pytest.raises(ValueError, match="columns"):
        checks.finite_difference_check(problem, columns=0)
    with pytest.raises(ValueError, match="points"):
        checks.cross_validate(problem, points=0)


def test_sample_points_inside_bounds(problem):
    xs = checks.sample_points(problem.bounds, 3, seed=0)
    assert xs.shape == (3, problem.nlp.n)
    assert np.all(xs >= problem.bounds.xl) and np.all(xs <= problem.bounds.xu)
    assert jnp.isfinite(jnp.asarray(xs)).all()
