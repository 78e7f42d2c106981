"""Numba kernels of the lazy neighborhood graph (Krüger 2010, §4.1; no validation, see :mod:`.lng`).

Nodes are the reported neighbours ``h`` (database rows) of each query frame ``i``, stored
layer by layer, each layer sorted by row id. Edges (never from row ``h-1`` to ``h`` when
``h`` starts a clip, ``continues[h]`` false):

* diagonal   ``(i-1, h-1) -> (i, h)``
* vertical   ``(i,   h-1) -> (i, h)``   database advances, query stays
* horizontal ``(i-1, h)   -> (i, h)``   query advances, database stays

An edge costs the distance of the node it points at; a super-source points at every node
of layer 0. Layers in order, rows ascending within a layer, is a topological order, so
one relaxation pass over nodes and edges solves single-source shortest paths in
O(k m) (the two-pointer merge of adjacent layers finds each node's predecessors). Ties go
to diagonal, vertical, horizontal in that order, as in :mod:`._dtw_kernels`.
Reference: ``tests/naive/dtw.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def lng_forward(
    ids: np.ndarray, dist: np.ndarray, count: np.ndarray, continues: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Shortest paths from the super-source to every node.

    Parameters
    ----------
    ids : int64 (m, k)
        Neighbour rows per query frame, ascending within each layer (first ``count[i]``
        entries valid).
    dist : float32 or float64 (m, k)
        Their distances to the query frame.
    count : int64 (m,)
    continues : bool (n,)
        Row ``h`` continues row ``h-1`` in the same clip.

    Returns
    -------
    cost : float64 (m, k)   accumulated cost (inf where unreachable or padding)
    start : int64 (m, k)    database row where the best path enters layer 0
    pred : int64 (m, k)     flat index ``i*k + a`` of the predecessor (-1 for layer 0)
    length : int32 (m, k)   nodes on the best path
    """
    m, k = ids.shape
    inf = np.inf
    cost = np.full((m, k), inf)
    start = np.full((m, k), -1, np.int64)
    pred = np.full((m, k), -1, np.int64)
    length = np.zeros((m, k), np.int32)
    # layer 0: the super-source edge (cost d) always beats a vertical step (cost >= d)
    for a in range(count[0]):
        cost[0, a] = dist[0, a]
        start[0, a] = ids[0, a]
        length[0, a] = 1
    for i in range(1, m):
        p = 0  # pointer into layer i-1, only moves forward
        cp = count[i - 1]
        for a in range(count[i]):
            h = ids[i, a]
            while p < cp and ids[i - 1, p] < h - 1:
                p += 1
            best = inf
            bi = -1
            bj = -1
            linked = continues[h] if h > 0 else False
            # diagonal from (i-1, h-1)
            q = p
            if q < cp and ids[i - 1, q] == h - 1:
                if linked and cost[i - 1, q] < best:
                    best = cost[i - 1, q]
                    bi = i - 1
                    bj = q
                q += 1
            # vertical from (i, h-1): the previous node of this layer, if it is row h-1
            if linked and a > 0 and ids[i, a - 1] == h - 1 and cost[i, a - 1] < best:
                best = cost[i, a - 1]
                bi = i
                bj = a - 1
            # horizontal from (i-1, h)
            if q < cp and ids[i - 1, q] == h and cost[i - 1, q] < best:
                best = cost[i - 1, q]
                bi = i - 1
                bj = q
            if bi >= 0:
                cost[i, a] = best + dist[i, a]
                start[i, a] = start[bi, bj]
                pred[i, a] = bi * k + bj
                length[i, a] = length[bi, bj] + 1
    return cost, start, pred, length


@njit(cache=True)
def lng_backtrack(
    ids: np.ndarray, pred: np.ndarray, i_end: int, a_end: int
) -> np.ndarray:  # pragma: no cover - compiled
    """Warping path ending in node ``(i_end, a_end)``: int64 (p, 2) of (query frame, row)."""
    m, k = ids.shape
    out = np.empty((m * k, 2), np.int64)
    p = 0
    node = i_end * k + a_end
    while node >= 0:
        i = node // k
        a = node - i * k
        out[p, 0] = i
        out[p, 1] = ids[i, a]
        p += 1
        node = pred[i, a]
    path: np.ndarray = out[:p][::-1].copy()
    return path


@njit(cache=True)
def propagate_layer(
    q: np.ndarray,
    prev_ids: np.ndarray,
    prev_count: np.ndarray,
    x: np.ndarray,
    continues: np.ndarray,
    k: int,
    r2: float,
    out_ids: np.ndarray,
    out_dist: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Approximate ``S(q_i)`` from ``S(q_{i-1})``: the ``k`` nearest of the candidate rows
    ``h - 1, h, h + 1, h + 2`` for every ``h`` of the previous layer (within ``h``'s clip),
    within squared radius ``r2``; ties by ascending row.

    The candidates are every row a warping path through ``h`` can reach in one query frame
    with at most two database frames per query frame (diagonal, horizontal, and vertical
    steps), plus ``h - 1`` so that a vertical step into the kept rows has its predecessor.
    Linear in the candidates: ``prev_ids`` ascending gives them sorted and distinct with no
    sort, and a partition finds the k-th distance.

    Parameters
    ----------
    q : float32 (d,)
    prev_ids : int64 (k_prev,), ascending; the first ``prev_count`` valid
    x : float32 (n, d), the database rows
    continues : bool (n,)
    k : int
    r2 : float, squared radius (inf: none)
    out_ids : int64 (k,), out_dist : float32 (k,)
        Filled: rows ascending, Euclidean distances; -1 / inf past the count.

    Returns
    -------
    count : int
    """
    n, d = x.shape
    cand = np.empty(4 * prev_count, np.int64)
    c = 0
    last = -1
    for a in range(prev_count):
        h = prev_ids[a]
        lo = h - 1 if h > 0 and continues[h] else h
        hi = h
        if h + 1 < n and continues[h + 1]:
            hi = h + 1
            if h + 2 < n and continues[h + 2]:
                hi = h + 2
        for r in range(max(lo, last + 1), hi + 1):
            cand[c] = r
            c += 1
        if hi > last:
            last = hi
    d2 = np.empty(c)
    for a in range(c):
        acc = 0.0
        for j in range(d):
            diff = np.float64(x[cand[a], j]) - np.float64(q[j])
            acc += diff * diff
        d2[a] = acc
    kth = r2
    if c > k:
        kth = min(r2, np.partition(d2.copy(), k - 1)[k - 1])
    kept = 0
    for a in range(c):  # strictly closer first ...
        if d2[a] < kth:
            kept += 1
    room = k - kept
    for a in range(c):  # ... then rows at the k-th distance, ascending, while room is left
        take = d2[a] < kth
        if not take and d2[a] == kth and d2[a] <= r2 and room > 0:
            take = True
            room -= 1
        if take:
            d2[a] = -1.0 - d2[a]  # mark (distances are >= 0)
    b = 0
    for a in range(c):
        if d2[a] < 0.0:
            out_ids[b] = cand[a]
            out_dist[b] = np.float32(np.sqrt(-1.0 - d2[a]))
            b += 1
    for a in range(b, out_ids.shape[0]):
        out_ids[a] = -1
        out_dist[a] = np.inf
    return b


@njit(cache=True)
def propagate_sets(
    query: np.ndarray,
    ids: np.ndarray,
    dist: np.ndarray,
    count: np.ndarray,
    every: int,
    x: np.ndarray,
    continues: np.ndarray,
    r2: float,
) -> None:  # pragma: no cover - compiled
    """Fill the layers ``i`` with ``i % every != 0`` of ``ids / dist / count`` (m, k) by
    :func:`propagate_layer` from layer ``i - 1`` (the others hold the index's sets)."""
    m, k = ids.shape
    for i in range(1, m):
        if i % every != 0:
            count[i] = propagate_layer(query[i], ids[i - 1], count[i - 1], x, continues, k, r2, ids[i], dist[i])
