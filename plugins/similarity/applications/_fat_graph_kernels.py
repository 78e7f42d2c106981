"""Kernels of :mod:`.fat_graph`: greedy base-pose selection on capped neighbourhoods.

No validation here; :func:`mocapflow.plugins.similarity.applications.fat_graph.select_base_poses` checks
its inputs and calls :func:`greedy_cover`. This module imports numba, so
:mod:`.fat_graph` imports it only when a computation starts (never at CLI start-up).
The slow reference is ``tests/naive/fat_graph.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _sift_down(heap: np.ndarray, size: int, i: int) -> None:
    while True:
        left = 2 * i + 1
        if left >= size:
            return
        child = left
        if left + 1 < size and heap[left + 1] < heap[left]:
            child = left + 1
        if heap[child] < heap[i]:
            heap[i], heap[child] = heap[child], heap[i]
            i = child
        else:
            return


@njit(cache=True)
def _sift_up(heap: np.ndarray, i: int) -> None:
    while i > 0:
        parent = (i - 1) // 2
        if heap[i] < heap[parent]:
            heap[i], heap[parent] = heap[parent], heap[i]
            i = parent
        else:
            return


@njit(cache=True)
def _greedy(ids: np.ndarray, max_base: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n, k = ids.shape
    # neighbourhood N(f) = {f} + valid ids of row f other than f (self always included,
    # also when more than k exact duplicates pushed it out of the capped row)
    deg = np.ones(n, np.int64)
    for f in range(n):
        for j in range(k):
            g = ids[f, j]
            if g >= 0 and g != f:
                deg[f] += 1
    # reverse adjacency (CSR): rev[g] = every f with g in N(f); a frame's count drops
    # by one for each of its neighbours that gets covered
    rev_start = np.zeros(n + 1, np.int64)
    for f in range(n):
        rev_start[f + 1] += 1
        for j in range(k):
            g = ids[f, j]
            if g >= 0 and g != f:
                rev_start[g + 1] += 1
    for f in range(n):
        rev_start[f + 1] += rev_start[f]
    fill = rev_start[:-1].copy()
    rev = np.empty(rev_start[n], np.int64)
    for f in range(n):
        rev[fill[f]] = f
        fill[f] += 1
        for j in range(k):
            g = ids[f, j]
            if g >= 0 and g != f:
                rev[fill[g]] = f
                fill[g] += 1
    count = deg.copy()
    covered = np.zeros(n, np.bool_)
    cluster = np.full(n, -1, np.int64)
    bases = np.empty(min(n, max_base) if max_base > 0 else n, np.int64)
    # min-heap of keys (-count) * n + f: largest count first, then smallest frame id.
    # Counts only fall, so a stored key is never worse than the true one; a popped stale
    # key is pushed back with its true value (lazy update), keeping the heap <= n long.
    heap = np.empty(n, np.int64)
    for f in range(n):
        heap[f] = -count[f] * n + f
    size = n
    for i in range(n // 2 - 1, -1, -1):
        _sift_down(heap, size, i)
    n_base = 0
    n_covered = 0
    while size > 0 and n_covered < n and n_base < bases.shape[0]:
        key = heap[0]
        size -= 1
        heap[0] = heap[size]
        _sift_down(heap, size, 0)
        c = -((key - (key % n)) // n)
        f = key % n
        if covered[f]:
            continue
        if c != count[f]:
            heap[size] = -count[f] * n + f
            _sift_up(heap, size)
            size += 1
            continue
        bases[n_base] = f
        for j in range(-1, k):
            g = f if j < 0 else ids[f, j]
            if g < 0 or (j >= 0 and g == f) or covered[g]:
                continue
            covered[g] = True
            cluster[g] = n_base
            n_covered += 1
            for r in range(rev_start[g], rev_start[g + 1]):
                count[rev[r]] -= 1
        n_base += 1
    return bases[:n_base], cluster, deg


def greedy_cover(ids: np.ndarray, max_base_poses: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy base poses on capped neighbourhoods (see :func:`.fat_graph.select_base_poses`).

    Parameters
    ----------
    ids : ndarray of int64, shape (n, k)
        Neighbour rows (``-1`` padding), e.g. from a radius search capped at ``k``.
    max_base_poses : int
        Stop after this many base poses; ``0`` means until every frame is covered.

    Returns
    -------
    bases : ndarray of int64, shape (n_base,)
        Frame of each base pose, in selection order.
    cluster : ndarray of int64, shape (n,)
        Base pose (position in ``bases``) that covered each frame; ``-1`` if uncovered.
    degree : ndarray of int64, shape (n,)
        Neighbourhood size of every frame (itself included).
    """
    return _greedy(np.ascontiguousarray(ids), int(max_base_poses))
