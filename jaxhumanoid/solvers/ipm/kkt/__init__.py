"""Structure-exploiting solution of the IPM's augmented (KKT) system with exact inertia.

The reduced primal-dual system solved at every iteration (IPOPT paper, eq. (13) after the slack
step has been eliminated, see ``algorithm.py``) is

    [ W + Sigma_x + delta_w I     J^T  ] [dx]   [r_x]
    [ J                          -D_c  ] [dy] = [r_c] ,       D_c = diag(d_c) >= 0,

with W (n x n) the Hessian of the Lagrangian, J (m x n) the constraint Jacobian. No n x n
matrix is formed. The package, in the order of the data flow:

- ``structure``: the unknowns ordered stage by stage, ``[x_0, y_0, x_1, y_1, ...]``
  (``NLP.var_stage`` / ``NLP.con_stage``), each stage padded with decoupled +-1 rows to a
  common block size nb = nbx + nbc, laid out [variables | constraints]; K is block-tridiagonal
  with S diagonal blocks A_k and sub-diagonal blocks B_k = K[stage k+1, stage k], B_k nonzero
  only on the few local rows ``b_rows`` / columns ``b_cols`` (the variables shared by
  neighbouring stages). A single-stage problem is one dense block.
- ``assembly``: the blocks (A, B) (S, nb, nb) from the NLP's values, diagonal updates, the
  symmetric Ruiz equilibration diag(d) K diag(d) (a congruence: inertia unchanged; without it
  the block elimination, which cannot pivot across stages, loses every digit on the graded
  matrices near the end of a solve), block products.
- ``pivot``: one pivot block D_k = [[P, Q^T], [Q, R]] factored as D_k^{-1} = N diag(+-1) N^T
  with its exact inertia: the quasi-definite fast path (a unit-triangular congruence with an
  augmented-Lagrangian term, certified by Cholesky factorisations only) and the
  eigendecomposition where it fails; the batching rule that keeps ``vmap`` on the fast path.
- ``elimination``: the block LDL^T in the arrowhead order 1, 2, ..., S-1, 0 (block 0, the
  border, eliminated last):

      D_1 = A_1,   D_{k+1} = A_{k+1} - B_k D_k^{-1} B_k^T,   L_{k+1,k} = B_k D_k^{-1},
      X_1 = B_0^T, X_{k+1} = -X_k D_k^{-1} B_k^T,            L_{0,k} = X_k D_k^{-1},
      D_0 = A_0 - sum_k X_k D_k^{-1} X_k^T,

  inertia(K) = sum_k inertia(D_k) (Sylvester) minus the padding's known signs. The border is
  the end stage whose equality rows outnumber its variables (a fixed initial state makes that
  block singular on its own although K is not); as the border it receives the Schur complements
  of all other blocks first. For the IPM's inertia-correction trials the loop can stop once the
  blocks done rule out inertia (n, m, 0) (Haynsworth bound, ``elimination.negative_caps``).
- ``condensed``: the alternative with smaller blocks: each stage's local unknowns (contact
  forces, their law's rows, inequality rows) eliminated for all stages at once, then the block
  LDL^T above over the unknowns that link the stages; inertia by Haynsworth's additivity.
- ``substitution``: the block forward/backward substitution (the couplings X_k applied by
  r-dimensional recursions, never stored) and adaptive iterative refinement on the
  equilibrated residual (IPOPT's rule).
"""

from jaxhumanoid.solvers.ipm.kkt.assembly import (
    add_diagonal,
    assemble,
    dense_matrix,
    equilibrate,
    from_blocks,
    matvec,
    scale_blocks,
    to_blocks,
)
from jaxhumanoid.solvers.ipm.kkt.condensed import (
    CondensedFactor,
    CondensedStructure,
    build_condensed,
    condensed_structure_of,
)
from jaxhumanoid.solvers.ipm.kkt.elimination import Factor, factor, inertia_ok, negative_caps, pivot_paths
from jaxhumanoid.solvers.ipm.kkt.pivot import QD_GAMMA
from jaxhumanoid.solvers.ipm.kkt.structure import KKTStructure, build_structure, structure_of
from jaxhumanoid.solvers.ipm.kkt.substitution import border_coupling, solve, solve_vec

__all__ = [
    "QD_GAMMA",
    "CondensedFactor",
    "CondensedStructure",
    "build_condensed",
    "condensed_structure_of",
    "Factor",
    "KKTStructure",
    "add_diagonal",
    "assemble",
    "border_coupling",
    "build_structure",
    "dense_matrix",
    "equilibrate",
    "factor",
    "from_blocks",
    "inertia_ok",
    "matvec",
    "negative_caps",
    "pivot_paths",
    "scale_blocks",
    "solve",
    "solve_vec",
    "structure_of",
    "to_blocks",
]
