"""Numba kernels of the float32 kd-tree (no validation: :mod:`.kdtree` validates).

The tree follows Arya & Mount's ANN (the library Krüger et al. 2010 used): sliding-midpoint
splits, buckets of at most ``leafsize`` points, depth-first search with incremental
distances to the far cells and the ``(1 + eps)`` pruning rule of ε-approximate search.
Beyond ANN, each node also has the tight bounding box of its points (:func:`._tree_kernels.node_boxes`,
derived from the stored tree, never saved): a stacked cell that survives the cheap
incremental test is re-tested on its exact box distance when popped, and a bucket reached
by descending is scanned only if its box is within reach. This cuts the points a 256-NN
query scans in 15-d about fourfold (the incremental bound alone is the distance to the
split-plane rectangle, much looser than the box of the few points inside it).

Points are stored once, permuted into tree order, as float32 (no float64 copy); squared
distances are accumulated in float64 so that the ranking matches a float64 reference.
Ordering of neighbours is lexicographic on ``(distance, row id)``, so ties resolve to the
smaller row id exactly as a sorted brute force does.

Exclusion: a candidate ``i`` is skipped when ``excl >= 0`` and it lies in the query's group
(clip) within ``excl`` frames: ``group[i] == qg and |frame[i] - qf| <= excl``.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

_IMAX = np.iinfo(np.int64).max


@njit(cache=True, inline="always")
def _before(d1: float, i1: int, d2: float, i2: int) -> bool:
    return d1 < d2 or (d1 == d2 and i1 < i2)


@njit(cache=True)
def _heap_replace(hd: np.ndarray, hi: np.ndarray, dist: float, idx: int) -> None:
    """Replace the root of a max-heap on (dist, id) and sift down."""
    k = hd.shape[0]
    pos = 0
    while True:
        c = 2 * pos + 1
        if c >= k:
            break
        if c + 1 < k and _before(hd[c], hi[c], hd[c + 1], hi[c + 1]):
            c += 1
        if _before(dist, idx, hd[c], hi[c]):
            hd[pos] = hd[c]
            hi[pos] = hi[c]
            pos = c
        else:
            break
    hd[pos] = dist
    hi[pos] = idx


@njit(cache=True, inline="always")
def _box_dist(q: np.ndarray, lo: np.ndarray, hi: np.ndarray, node: int, d: int) -> float:
    """Squared distance from ``q`` to the box of ``node``, summed in dimension order.

    Each per-dimension gap is at most that of any point in the box and the float64 rounding
    is monotonic, so the sum never exceeds the distance ``_search`` computes for such a point
    (pruning on it cannot drop a tied neighbour).
    """
    acc = 0.0
    for j in range(d):
        v = q[j]
        g = np.float64(lo[node, j]) - v
        if g > 0.0:
            acc += g * g
        else:
            g = v - np.float64(hi[node, j])
            if g > 0.0:
                acc += g * g
    return acc


@njit(cache=True)
def _search(
    q: np.ndarray,
    tree: tuple[np.ndarray, ...],
    qg: int,
    qf: int,
    excl: int,
    hd: np.ndarray,
    hi_: np.ndarray,
    eps_fac: float,
    r2: float,
    st_node: np.ndarray,
    st_rd: np.ndarray,
    st_off: np.ndarray,
    cur_off: np.ndarray,
) -> None:
    """Depth-first search with an explicit stack (numba cannot cache recursive functions).

    ``tree`` is :meth:`.kdtree.KDTreeIndex._tree_args`' tuple. Each stacked far cell carries its
    incremental-distance vector ``off`` (per-dimension distance from the query to the cell's
    split-plane rectangle) and its squared lower bound ``rd``. The O(1) incremental bound decides
    what is stacked; a popped cell is tested again on the exact distance to its points' bounding
    box (tighter, O(d)) against the current bound, and so is a bucket reached by descending.
    """
    data, perm, start, end, left, right, sdim, sval, blo, bhi, groups, frames = tree
    d = data.shape[1]
    top = 1
    st_node[0] = 0
    st_rd[0] = 0.0
    for j in range(d):
        st_off[0, j] = 0.0
    while top > 0:
        top -= 1
        node = st_node[top]
        rd = st_rd[top]
        bound = hd[0] if hd[0] < r2 else r2
        # the bound may have shrunk since the cell was stacked; tiny relative slack so that
        # rounding never prunes an exactly tied point
        if rd * eps_fac > bound * (1.0 + 1e-9):
            continue
        # the exact box distance, against the current (tighter) bound, only for cells that
        # survive the cheap test: most stacked cells are pruned by then
        if _box_dist(q, blo, bhi, node, d) * eps_fac > bound * (1.0 + 1e-9):
            continue
        for j in range(d):
            cur_off[j] = st_off[top, j]
        inc = rd
        descended = False
        lim = bound * (1.0 + 1e-9)
        while left[node] >= 0:
            dim = sdim[node]
            diff = q[dim] - np.float64(sval[node])
            if diff < 0.0:
                near, far = left[node], right[node]
            else:
                near, far = right[node], left[node]
            old = cur_off[dim]
            rd_far = inc - old * old + diff * diff
            if rd_far * eps_fac <= lim:
                st_node[top] = far
                st_rd[top] = rd_far
                for j in range(d):
                    st_off[top, j] = cur_off[j]
                st_off[top, dim] = diff
                top += 1
            node = near
            descended = True
        if descended and _box_dist(q, blo, bhi, node, d) * eps_fac > lim:
            continue  # a bucket reached by descending: skip it if its box is out of reach
        for t in range(start[node], end[node]):
            if excl >= 0 and groups[t] == qg and abs(frames[t] - qf) <= excl:
                continue
            bound = hd[0] if hd[0] < r2 else r2
            acc = 0.0
            for j in range(d):  # no early exit: branch-free, and most rows fail only late
                diff = np.float64(data[t, j]) - q[j]
                acc += diff * diff
            if acc <= bound and _before(acc, perm[t], hd[0], hi_[0]):
                _heap_replace(hd, hi_, acc, perm[t])


@njit(cache=True)
def _seed_bound(
    q: np.ndarray,
    prev: np.ndarray,
    shift: int,
    data: np.ndarray,
    inv: np.ndarray,
    groups: np.ndarray,
    frames: np.ndarray,
    qg: int,
    qf: int,
    excl: int,
) -> float:
    """Largest squared distance from ``q`` to the rows ``prev + shift`` (input ids), or inf.

    ``prev`` holds the k distinct neighbours of the previous query; if all ``k`` shifted
    rows exist and none is excluded, at least ``k`` rows lie within the returned value, so
    it bounds the k-th nearest distance from above and can prune an exact search.
    """
    n, d = data.shape
    worst = 0.0
    for a in range(prev.shape[0]):
        row = prev[a] + shift
        if prev[a] < 0 or row >= n:
            return np.inf
        t = inv[row]
        if excl >= 0 and groups[t] == qg and abs(frames[t] - qf) <= excl:
            return np.inf
        acc = 0.0
        for j in range(d):  # summed exactly as in _search: the seeds themselves pass the bound
            diff = np.float64(data[t, j]) - q[j]
            acc += diff * diff
        if acc > worst:
            worst = acc
    return worst


@njit(cache=True)
def _query_rows(
    r0: int,
    r1: int,
    queries: np.ndarray,
    k: int,
    eps_fac: float,
    r2: float,
    tree: tuple[np.ndarray, ...],
    qgroups: np.ndarray,
    qframes: np.ndarray,
    excl: int,
    max_depth: int,
    out_d: np.ndarray,
    out_i: np.ndarray,
    inv: np.ndarray,
) -> None:
    data, groups, frames = tree[0], tree[10], tree[11]
    d = queries.shape[1]
    hd = np.empty(k)
    hi_ = np.empty(k, np.int64)
    st_node = np.empty(max_depth + 2, np.int64)
    st_rd = np.empty(max_depth + 2)
    st_off = np.empty((max_depth + 2, d))
    cur_off = np.empty(d)
    q = np.empty(d)
    for r in range(r0, r1):
        hd[:] = np.inf
        hi_[:] = _IMAX
        for j in range(d):
            q[j] = queries[r, j]
        bound = r2
        if inv.shape[0] > 0 and r > r0:  # exact searches of consecutive queries: seed the bound
            for shift in (1, 0):  # the successors of the previous neighbours, then themselves
                b = _seed_bound(q, out_i[r - 1], shift, data, inv, groups, frames, qgroups[r], qframes[r], excl)
                if b < bound:
                    bound = b
        _search(q, tree, qgroups[r], qframes[r], excl, hd, hi_, eps_fac, bound, st_node, st_rd, st_off, cur_off)
        order = np.argsort(hd, kind="mergesort")
        for a in range(k):
            out_d[r, a] = hd[order[a]]
            out_i[r, a] = hi_[order[a]]
        # equal distances: ids ascending
        for a in range(1, k):
            b = a
            while b > 0 and out_d[r, b] == out_d[r, b - 1] and out_i[r, b] < out_i[r, b - 1]:
                out_i[r, b], out_i[r, b - 1] = out_i[r, b - 1], out_i[r, b]
                b -= 1
        for a in range(k):
            if out_i[r, a] == _IMAX:
                out_i[r, a] = -1
                out_d[r, a] = np.inf


@njit(cache=True, parallel=True)
def query_tree(
    queries: np.ndarray,
    k: int,
    eps: float,
    r2: float,
    tree: tuple[np.ndarray, ...],
    qgroups: np.ndarray,
    qframes: np.ndarray,
    excl: int,
    max_depth: int,
    n_chunks: int,
    inv: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """kNN of every query row; returns squared distances (float64) and row ids, sorted.

    ``tree``: the arrays of :meth:`.kdtree.KDTreeIndex._tree_args`. ``n_chunks <= 1`` runs on
    the calling thread (single queries: no thread wake-up). ``inv`` (input id -> tree position;
    empty to disable, and it must be empty for ``eps > 0``) lets each query after the first of
    its chunk start from the bound of :func:`_seed_bound` (exact: consecutive query frames have
    nearby neighbours).
    """
    m = queries.shape[0]
    out_d = np.full((m, k), np.inf)
    out_i = np.full((m, k), -1, np.int64)
    eps_fac = (1.0 + eps) * (1.0 + eps)
    if n_chunks <= 1:
        _query_rows(np.int64(0), m, queries, k, eps_fac, r2, tree, qgroups, qframes, excl, max_depth, out_d, out_i, inv)
        return out_d, out_i
    t0, t1, t2, t3, t4, t5, t6, t7, t8, t9, t10, t11 = tree  # a parallel loop cannot capture a tuple
    for c in prange(n_chunks):
        tr = (t0, t1, t2, t3, t4, t5, t6, t7, t8, t9, t10, t11)
        a, b = c * m // n_chunks, (c + 1) * m // n_chunks
        _query_rows(a, b, queries, k, eps_fac, r2, tr, qgroups, qframes, excl, max_depth, out_d, out_i, inv)
    return out_d, out_i


def set_threads(workers: int | None) -> int:
    """Set numba's thread count for the next parallel call; returns the previous one."""
    prev = numba.get_num_threads()
    most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]  # set at import, absent from its stub
    n = most if workers is None or workers < 1 else min(workers, most)
    if n != prev:  # setting takes locks: skip it on the (usual) unchanged path
        numba.set_num_threads(n)
    return prev


def threads() -> int:
    return numba.get_num_threads()


@njit(cache=True)
def tree_work(
    queries: np.ndarray,
    r2: np.ndarray,
    start: np.ndarray,
    end: np.ndarray,
    left: np.ndarray,
    right: np.ndarray,
    blo: np.ndarray,
    bhi: np.ndarray,
    max_depth: int,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Work a search with known k-th distances cannot avoid: per query, the nodes whose
    bounding box lies within ``r2[q]`` (the squared k-th neighbour distance) and the points
    of the buckets among them.

    Any exact search must open every bucket whose box is closer than the k-th neighbour
    (it may hold a closer point), so these counts are the search's work up to the share
    wasted while its bound is still loose; they depend on the data only (the ``method:
    auto`` cost model counts them instead of timing the search). Returns
    ``(points, nodes)``, int64 (m,) each.
    """
    m, d = queries.shape
    points = np.zeros(m, np.int64)
    nodes = np.zeros(m, np.int64)
    stack = np.empty(max_depth + 2, np.int64)
    for r in range(m):
        q = queries[r]
        top = 1
        stack[0] = 0
        while top > 0:
            top -= 1
            node = stack[top]
            nodes[r] += 1
            if _box_dist(q, blo, bhi, node, d) > r2[r]:
                continue
            if left[node] < 0:
                points[r] += end[node] - start[node]
            else:
                stack[top] = left[node]
                stack[top + 1] = right[node]
                top += 2
    return points, nodes
