"""The oracle of ``benchmarks/certified_ceiling.py``: the best sDTW path through every cell.

Float64 forward and backward subsequence-DTW recurrences (the step pattern of
``plugins/similarity/_dtw_kernels.py``; reference ``tests/naive/dtw.py::naive_through_cell``),
run clip by clip (no path crosses a row that does not continue the one before), so memory is
three ``(run length, m)`` float64 matrices of the longest run, not ``(n, m)``::

    F(i, j) = d(i, j) + min(F(i-1, j), F(i-1, j-1), F(i, j-1))   F(0, j) = d(0, j)   (free start)
    G(i, j) = d(i, j) + min(G(i+1, j), G(i+1, j+1), G(i, j+1))   G(m-1, j) = d(m-1, j) (free end)

(the ``j``-steps only within a run). ``F + G - d`` at ``(i, j)`` is the cost of the best path
through that cell, so a row ``j`` lies on some path of cost <= ``tau`` exactly when
``min_i F(i, j) + G(i, j) - d(i, j) <= tau``: the rows (and cells) every exact method that
verifies by DP must compute. Benchmark support, not part of the package.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def through_cell_rows(q, x, continues, tau):  # pragma: no cover - compiled
    """Per database row: the cost of the best path through it, and its cells on paths <= ``tau``.

    Parameters
    ----------
    q : float64 (m, d)        the query
    x : float32 or float64 (n, d)   database rows (distances computed in float64)
    continues : bool (n,)     row ``j`` continues row ``j - 1`` (same clip, next frame)
    tau : float               cost threshold

    Returns
    -------
    row_min : float64 (n,)    ``min_i F(i, j) + G(i, j) - d(i, j)``
    cells : int32 (n,)        number of ``i`` with ``F(i, j) + G(i, j) - d(i, j) <= tau``
    end_cost : float64 (n,)   ``F(m - 1, j)``: sDTW's cost of the best path ending in row ``j``
    """
    m, dim = q.shape
    n = x.shape[0]
    row_min = np.empty(n)
    cells = np.zeros(n, np.int32)
    end_cost = np.empty(n)
    a = 0
    while a < n:
        b = a + 1
        while b < n and continues[b]:
            b += 1
        L = b - a
        d = np.empty((L, m))
        for r in range(L):
            for i in range(m):
                s = 0.0
                for k in range(dim):
                    t = q[i, k] - np.float64(x[a + r, k])
                    s += t * t
                d[r, i] = np.sqrt(s)
        F = np.empty((L, m))
        for r in range(L):
            F[r, 0] = d[r, 0]
            for i in range(1, m):
                best = F[r, i - 1]
                if r > 0:
                    best = min(best, F[r - 1, i - 1], F[r - 1, i])
                F[r, i] = best + d[r, i]
        G = np.empty((L, m))
        for r in range(L - 1, -1, -1):
            G[r, m - 1] = d[r, m - 1]
            for i in range(m - 2, -1, -1):
                best = G[r, i + 1]
                if r < L - 1:
                    best = min(best, G[r + 1, i + 1], G[r + 1, i])
                G[r, i] = best + d[r, i]
        for r in range(L):
            lo = np.inf
            c = 0
            for i in range(m):
                v = F[r, i] + G[r, i] - d[r, i]
                lo = min(lo, v)
                if v <= tau:
                    c += 1
            row_min[a + r] = lo
            cells[a + r] = c
            end_cost[a + r] = F[r, m - 1]
        a = b
    return row_min, cells, end_cost
