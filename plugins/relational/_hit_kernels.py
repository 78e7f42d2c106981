"""Numba kernels that turn ``matchers.template``'s end-frame costs into hits, and range helpers.

No validation here (the API validates); each kernel has a slow reference in
``tests/naive/templates.py``. The DTW kernels themselves are in ``_template_kernels.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def select_hits(
    cost: np.ndarray, start: np.ndarray, threshold: float, min_gap: float
) -> np.ndarray:  # pragma: no cover - compiled
    """Hits from end-frame costs: local minima with cost <= threshold, cheapest first, a
    candidate dropped when it overlaps an accepted hit by more than ``min_gap`` of the
    shorter span. Returns the end frames (h,) int64 (inclusive) by ascending cost.
    """
    n = cost.shape[0]
    lo = np.zeros(1, np.int64)
    hi = np.full(1, n, np.int64)
    return greedy_hits(range_minima(cost, lo, hi, threshold), cost, start, min_gap, n)


@njit(cache=True)
def range_minima(
    cost: np.ndarray, lo: np.ndarray, hi: np.ndarray, threshold: float
) -> np.ndarray:  # pragma: no cover - compiled
    """Frames ``j`` inside the ranges ``[lo, hi)`` with ``cost[j] <= threshold``, not above
    the previous frame and below the next (frames outside the range count as inf)."""
    total = 0
    for r in range(lo.shape[0]):
        total += hi[r] - lo[r]
    cand = np.empty(total, np.int64)
    m = 0
    for r in range(lo.shape[0]):
        for j in range(lo[r], hi[r]):
            c = cost[j]
            if not c <= threshold:  # also rejects NaN and inf
                continue
            if j > lo[r] and cost[j - 1] < c:
                continue
            if j + 1 < hi[r] and cost[j + 1] <= c:
                continue
            cand[m] = j
            m += 1
    return cand[:m]


@njit(cache=True)
def greedy_hits(
    cand: np.ndarray, cost: np.ndarray, start: np.ndarray, min_gap: float, n: int
) -> np.ndarray:  # pragma: no cover - compiled
    """The greedy overlap suppression of :func:`select_hits` over given candidate ends
    (ascending frames); ``n`` frames in all. Returns the accepted ends by ascending cost."""
    m = cand.shape[0]
    order = np.argsort(cost[cand], kind="mergesort")
    # accepted hits by first frame: with min_gap < 1 two accepted hits never share a start,
    # and any accepted hit overlapping [s, e) starts in [s - longest, e)
    by_start = np.full(n + 1, -1, np.int64)
    acc_s = np.empty(m, np.int64)
    acc_e = np.empty(m, np.int64)
    out = np.empty(m, np.int64)
    h = 0
    longest = 0
    for r in range(m):
        j = cand[order[r]]
        s, e = start[j], j + 1
        ok = True
        for f in range(max(s - longest, 0), e):
            o = by_start[f]
            if o >= 0:
                ov = min(e, acc_e[o]) - max(s, acc_s[o])
                if ov > min_gap * min(e - s, acc_e[o] - acc_s[o]):
                    ok = False
                    break
        if ok:
            acc_s[h] = s
            acc_e[h] = e
            by_start[s] = h
            longest = max(longest, e - s)
            out[h] = j
            h += 1
    return out[:h]


@njit(cache=True)
def window_minima(cost: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Least ``cost`` over each frame window ``[lo_i, hi_i)`` (inf for an empty one), (n,)."""
    out = np.full(lo.shape[0], np.inf)
    for i in range(lo.shape[0]):
        m = np.inf
        for j in range(lo[i], hi[i]):
            if cost[j] < m:
                m = cost[j]
        out[i] = m
    return out
