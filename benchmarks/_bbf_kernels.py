"""Best-bin-first kd-tree search with a scan budget (Beis & Lowe 1997; FLANN's ``checks``).

A benchmark-only design (``benchmarks/ann_tuning.py``, issue 13 §3): an approximate k-NN
search over ``indexes.kdtree``'s own tree and node boxes. Cells are visited in order of
their box distance to the query (a min-heap), each bucket's points scanned into a max-heap
of the k best; the search stops once ``checks`` points have been scanned, or when the
nearest unvisited cell lies beyond the current k-th distance (then the answer is exact).
Measured in docs/knn.md and dropped: in 15 dimensions the 256 neighbours of a motion frame
are spread over many buckets, so a budget small enough to beat the exact tree tenfold
keeps only half of them.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapflow.plugins.similarity.knn._knn_kernels import _box_dist, _heap_replace


@njit(cache=True)
def _push(pq_d, pq_n, size, dist, node):
    pos = size
    while pos > 0:
        parent = (pos - 1) // 2
        if pq_d[parent] <= dist:
            break
        pq_d[pos] = pq_d[parent]
        pq_n[pos] = pq_n[parent]
        pos = parent
    pq_d[pos] = dist
    pq_n[pos] = node
    return size + 1


@njit(cache=True)
def _pop(pq_d, pq_n, size):
    """Remove the root of the min-heap; returns the new size."""
    size -= 1
    last_d, last_n = pq_d[size], pq_n[size]
    pos = 0
    while True:
        c = 2 * pos + 1
        if c >= size:
            break
        if c + 1 < size and pq_d[c + 1] < pq_d[c]:
            c += 1
        if pq_d[c] >= last_d:
            break
        pq_d[pos] = pq_d[c]
        pq_n[pos] = pq_n[c]
        pos = c
    if size > 0:
        pq_d[pos] = last_d
        pq_n[pos] = last_n
    return size


@njit(cache=True)
def bbf_query(q, k, checks, data, perm, start, end, left, right, blo, bhi):
    """Row ids (int64 (k,), unsorted) of the approximate k nearest rows of ``q`` (float64 (d,)).

    ``data`` .. ``bhi`` are :meth:`KDTreeIndex._tree_args`'s tree arrays and node boxes.
    """
    d = data.shape[1]
    hd = np.full(k, np.inf)
    hi = np.full(k, np.iinfo(np.int64).max, np.int64)
    cap = left.shape[0] + 1
    pq_d = np.empty(cap)
    pq_n = np.empty(cap, np.int64)
    size = _push(pq_d, pq_n, 0, 0.0, 0)
    scanned = 0
    while size > 0 and scanned < checks:
        rd, node = pq_d[0], pq_n[0]
        size = _pop(pq_d, pq_n, size)
        if rd > hd[0]:
            break  # every unvisited cell is beyond the k-th distance: exact from here
        while left[node] >= 0:  # descend to the nearer child, queue the farther one
            a, b = left[node], right[node]
            da, db = _box_dist(q, blo, bhi, a, d), _box_dist(q, blo, bhi, b, d)
            if db < da:
                a, b, da, db = b, a, db, da
            if db <= hd[0]:
                size = _push(pq_d, pq_n, size, db, b)
            if da > hd[0]:
                node = -1
                break
            node = a
        if node < 0:
            continue
        for t in range(start[node], end[node]):
            acc = 0.0
            for j in range(d):
                diff = np.float64(data[t, j]) - q[j]
                acc += diff * diff
            if acc < hd[0]:
                _heap_replace(hd, hi, acc, perm[t])
        scanned += end[node] - start[node]
    return hi
