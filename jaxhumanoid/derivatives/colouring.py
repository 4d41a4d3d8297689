"""Graph colourings that compress sparse Jacobians and Hessians (numpy / scipy.sparse only).

Colours are int64 arrays of shape (n,), one per variable, numbered 0..num_colours-1; a colour
class is a seed vector (``seed_matrix``) for one directional derivative.

* Jacobian (Curtis-Powell-Reid): columns sharing a row get different colours, i.e. a distance-1
  colouring of the column intersection graph (distance-2 in the bipartite graph). Then every
  J[i, j] is read directly from the compressed product (J S^T)[i, colour[j]].
* Hessian (star colouring, Gebremedhin-Manne-Pothen): a distance-1 colouring of the adjacency
  graph in which every path on four vertices uses at least three colours. Then for every nonzero
  H[i, j] the colour of j is unique among the neighbours of i, or the other way round, so the
  entry is read directly from one Hessian-vector product (``star_recovery``).

Both greedy colourers visit vertices in a chosen order; ``order="best"`` runs the natural,
largest-first and smallest-last orders and keeps the fewest colours (natural order is optimal on
banded patterns, the degree-based orders on irregular ones).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from jaxhumanoid.derivatives.sparsity import check_pattern

ORDERS = ("natural", "largest_first", "smallest_last")


def column_intersection_graph(rows, cols, shape: tuple[int, int]) -> sp.csr_matrix:
    """Adjacency (n, n) of columns that share a row of the (m, n) pattern; no self-loops."""
    rows, cols = check_pattern(rows, cols, shape)
    pattern = sp.csr_matrix((np.ones(rows.size, dtype=np.int64), (rows, cols)), shape=shape)
    return _without_diagonal(pattern.T @ pattern)


def symmetric_adjacency(rows, cols, n: int) -> sp.csr_matrix:
    """Adjacency (n, n) of a symmetric pattern given by any triangle(s); no self-loops."""
    rows, cols = _as_coords(rows, cols, n)
    off = rows != cols
    r = np.concatenate([rows[off], cols[off]])
    c = np.concatenate([cols[off], rows[off]])
    return _without_diagonal(sp.csr_matrix((np.ones(r.size, dtype=np.int64), (r, c)), shape=(n, n)))


def _as_coords(rows, cols, n):
    rows = np.asarray(rows)
    cols = np.asarray(cols)
    if rows.ndim != 1 or rows.shape != cols.shape:
        raise ValueError(f"rows/cols: expected 1-D arrays of equal length, got shapes {rows.shape} and {cols.shape}")
    rows = rows.astype(np.int64)
    cols = cols.astype(np.int64)
    if rows.size and (min(rows.min(), cols.min()) < 0 or max(rows.max(), cols.max()) >= n):
        raise ValueError(f"rows/cols: entries must lie in [0, {n})")
    return rows, cols


def _without_diagonal(adj) -> sp.csr_matrix:
    adj = sp.csr_matrix(adj)
    adj.setdiag(0)
    adj.eliminate_zeros()
    adj.data[:] = 1
    adj.sort_indices()
    return adj


def vertex_order(adj: sp.csr_matrix, order: str) -> np.ndarray:
    """Visiting order (n,) of the vertices of ``adj`` for a greedy colouring.

    natural: 0..n-1; largest_first: by decreasing degree (stable); smallest_last: repeatedly
    remove a vertex of minimum remaining degree and colour in reverse removal order.
    """
    n = adj.shape[0]
    if order == "natural":
        return np.arange(n, dtype=np.int64)
    degree = np.diff(adj.indptr)
    if order == "largest_first":
        return np.argsort(-degree, kind="stable").astype(np.int64)
    if order == "smallest_last":
        return _smallest_last(adj, degree)
    raise ValueError(f"order: expected one of {ORDERS + ('best',)}, got {order!r}")


def _smallest_last(adj, degree) -> np.ndarray:
    # Bucket queue on the remaining degree; after a removal the minimum drops by at most one.
    indptr, indices = adj.indptr, adj.indices
    deg = degree.astype(np.int64)
    buckets: list[set[int]] = [set() for _ in range(int(deg.max(initial=0)) + 1)]
    for v, d in enumerate(deg):
        buckets[d].add(v)
    removed = np.zeros(deg.size, dtype=bool)
    removal = []
    low = 0
    for _ in range(deg.size):
        while not buckets[low]:
            low += 1
        v = buckets[low].pop()
        removed[v] = True
        removal.append(v)
        for w in indices[indptr[v] : indptr[v + 1]]:
            if not removed[w]:
                buckets[deg[w]].remove(w)
                deg[w] -= 1
                buckets[deg[w]].add(w)
        low = max(low - 1, 0)
    return np.array(removal[::-1], dtype=np.int64)


def _smallest_free(forbidden: np.ndarray) -> int:
    used = np.zeros(forbidden.size + 1, dtype=bool)
    used[forbidden[forbidden <= forbidden.size]] = True
    return int(np.argmin(used))


def _greedy_distance1(adj: sp.csr_matrix, visit: np.ndarray) -> np.ndarray:
    indptr, indices = adj.indptr, adj.indices
    colours = np.full(adj.shape[0], -1, dtype=np.int64)
    for v in visit:
        nbr = colours[indices[indptr[v] : indptr[v + 1]]]
        colours[v] = _smallest_free(nbr[nbr >= 0])
    return colours


def _csr_gather(indptr, indices, vertices):
    """Neighbours of each vertex in ``vertices``, concatenated, and the vertex each came from."""
    starts = indptr[vertices]
    lens = indptr[vertices + 1] - starts
    total = int(lens.sum())
    offsets = np.repeat(starts - np.cumsum(lens) + lens, lens) + np.arange(total)
    return indices[offsets], np.repeat(vertices, lens)


def _greedy_star(adj: sp.csr_matrix, visit: np.ndarray) -> np.ndarray:
    # A partial colouring stays a star colouring if, when v is coloured, no path on four coloured
    # vertices through v alternates two colours. By symmetry of paths it suffices to check v as an
    # end (v-w-x-y) and as an inner vertex (u-v-w-x). count[x, c] = number of coloured neighbours
    # of x with colour c turns "x has another neighbour coloured like w" into a lookup.
    n = adj.shape[0]
    indptr, indices = adj.indptr, adj.indices
    colours = np.full(n, -1, dtype=np.int64)
    count = np.zeros((n, 8), dtype=np.int32)
    for v in visit:
        nbrs = indices[indptr[v] : indptr[v + 1]]
        cw = colours[nbrs]
        forbidden = [cw[cw >= 0]]
        coloured = nbrs[cw >= 0]
        if coloured.size:
            x, w = _csr_gather(indptr, indices, coloured)
            keep = (x != v) & (colours[x] >= 0)
            x, w = x[keep], w[keep]
            c_w = colours[w]
            end = count[x, c_w] >= 2  # v-w-x-y with colour(y) = colour(w), y != w
            inner = count[v, c_w] >= 2  # u-v-w-x with colour(u) = colour(w), u != w
            forbidden.append(colours[x[end | inner]])
        c = _smallest_free(np.concatenate(forbidden))
        if c >= count.shape[1]:
            count = np.concatenate([count, np.zeros_like(count)], axis=1)
        colours[v] = c
        count[nbrs, c] += 1
    return colours


def _best(colour_fn, adj, order):
    orders = ORDERS if order == "best" else (order,)
    best = None
    for name in orders:
        colours = colour_fn(adj, vertex_order(adj, name))
        if best is None or colours.max(initial=-1) < best.max(initial=-1):
            best = colours
    return best


def colour_columns(rows, cols, shape: tuple[int, int], order: str = "best") -> np.ndarray:
    """Column colouring (n,) of an (m, n) Jacobian pattern: columns sharing a row differ."""
    adj = column_intersection_graph(rows, cols, shape)
    return _best(_greedy_distance1, adj, order)


def star_colouring(rows, cols, n: int, order: str = "best") -> np.ndarray:
    """Star colouring (n,) of a symmetric (n, n) pattern given by its lower triangle (or both)."""
    adj = symmetric_adjacency(rows, cols, n)
    return _best(_greedy_star, adj, order)


def num_colours(colours) -> int:
    """Number of colours (seed vectors) used: max + 1, 0 for no variables."""
    colours = np.asarray(colours)
    return int(colours.max()) + 1 if colours.size else 0


def seed_matrix(colours) -> np.ndarray:
    """One-hot seeds, float64 shape (num_colours, n): row c is the indicator of colour class c."""
    colours = _check_colours(colours, np.asarray(colours).size)
    seeds = np.zeros((num_colours(colours), colours.size))
    seeds[colours, np.arange(colours.size)] = 1.0
    return seeds


def _check_colours(colours, n: int) -> np.ndarray:
    colours = np.asarray(colours)
    if colours.shape != (n,):
        raise ValueError(f"colours: expected shape ({n},), got {colours.shape}")
    if colours.size and (not np.issubdtype(colours.dtype, np.integer) or colours.min() < 0):
        raise ValueError("colours: expected non-negative integers")
    return colours.astype(np.int64)


def is_valid_column_colouring(rows, cols, shape: tuple[int, int], colours) -> bool:
    """True if no two columns that share a row of the (m, n) pattern have the same colour."""
    rows, cols = check_pattern(rows, cols, shape)
    colours = _check_colours(colours, shape[1])
    keys = rows * max(num_colours(colours), 1) + colours[cols]
    return bool(np.unique(keys).size == keys.size)


def _neighbour_colour_counts(adj: sp.csr_matrix, colours: np.ndarray) -> np.ndarray:
    """count[i, c] = number of neighbours of i with colour c, dense (n, num_colours)."""
    n, k = colours.size, max(num_colours(colours), 1)
    onehot = sp.csr_matrix((np.ones(n, dtype=np.int64), (np.arange(n), colours)), shape=(n, k))
    return (adj @ onehot).toarray()


def is_valid_star_colouring(rows, cols, n: int, colours) -> bool:
    """True if ``colours`` allows direct recovery of the symmetric pattern (a star colouring).

    Conditions: adjacent vertices differ, and for every off-diagonal nonzero (i, j) the colour of
    j is unique among the neighbours of i or the colour of i is unique among those of j.
    """
    adj = symmetric_adjacency(rows, cols, n)
    colours = _check_colours(colours, n)
    i, j = adj.nonzero()
    if np.any(colours[i] == colours[j]):
        return False
    count = _neighbour_colour_counts(adj, colours)
    return bool(np.all((count[i, colours[j]] == 1) | (count[j, colours[i]] == 1)))


def jacobian_recovery(rows, cols, shape: tuple[int, int], colours) -> tuple[np.ndarray, np.ndarray]:
    """Where each J[rows[k], cols[k]] sits in the compressed (num_colours, m) product S J^T.

    Returns (colour_index, row_index), int64 arrays of shape (nnz,). Raises ValueError if the
    colouring is invalid for the pattern.
    """
    if not is_valid_column_colouring(rows, cols, shape, colours):
        raise ValueError("colours: not a valid column colouring of the Jacobian pattern")
    rows, cols = check_pattern(rows, cols, shape)
    return np.asarray(colours, dtype=np.int64)[cols], rows


def star_recovery(rows, cols, n: int, colours) -> tuple[np.ndarray, np.ndarray]:
    """Where each lower-triangle H[rows[k], cols[k]] sits in the compressed (num_colours, n) H S^T.

    Entry (i, j) is read from the product seeded with colour(j) at component i when colour(j) is
    unique among the neighbours of i (diagonal entries always are), otherwise from colour(i) at
    component j. Returns (colour_index, component_index), int64 arrays of shape (nnz,). Raises
    ValueError if the colouring is not a star colouring of the pattern.
    """
    rows, cols = check_pattern(rows, cols, (n, n), lower=True)
    if not is_valid_star_colouring(rows, cols, n, colours):
        raise ValueError("colours: not a valid star colouring of the Hessian pattern")
    colours = np.asarray(colours, dtype=np.int64)
    count = _neighbour_colour_counts(symmetric_adjacency(rows, cols, n), colours)
    direct = (rows == cols) | (count[rows, colours[cols]] == 1)
    colour_index = np.where(direct, colours[cols], colours[rows])
    component = np.where(direct, rows, cols)
    return colour_index, component
