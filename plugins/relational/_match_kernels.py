"""Numba kernels of ``matchers.relational``: no validation here (the API validates).

Each kernel has a slow reference in ``tests/naive/relational.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def mismatch_scan(
    codes: np.ndarray, clip: np.ndarray, member: np.ndarray, allowed: np.ndarray, m: int
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """m-mismatch hits by dynamic programming over the segment sequence.

    For every start ``k`` the number of unsatisfied equalities ``w_{k+l} in V_l`` is counted
    left to right (the DP state is the mismatch count so far), abandoning a start as soon
    as it exceeds ``m`` or a mismatch falls on a position where none is allowed.

    ``codes`` (M,) segment codes, ``clip`` (M,) their clip positions (a hit never spans two
    clips), ``member`` (L, C) bool: code ``c`` is in the query's l-th fuzzy set, ``allowed``
    (L,) positions where a mismatch may occur, at most ``m``. Returns ``starts, mismatches``
    (n,) int64.
    """
    n_seg = codes.shape[0]
    n_q = member.shape[0]
    starts = np.empty(max(n_seg - n_q + 1, 0), dtype=np.int64)
    counts = np.empty_like(starts)
    n = 0
    for k in range(n_seg - n_q + 1):
        if clip[k] != clip[k + n_q - 1]:
            continue
        bad = 0
        ok = True
        for q in range(n_q):
            if not member[q, codes[k + q]]:
                if not allowed[q]:
                    ok = False
                    break
                bad += 1
                if bad > m:
                    ok = False
                    break
        if ok:
            starts[n] = k
            counts[n] = bad
            n += 1
    return starts[:n], counts[:n]


@njit(cache=True)
def banded_dtw(
    a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> tuple[float, np.ndarray, int]:  # pragma: no cover - compiled
    """DTW between ``a (n, d)`` and ``b (m, d)`` restricted to a band.

    Row ``i`` may only use columns ``lo[i] <= j < hi[i]``; local cost is the Euclidean
    distance; steps (1,0), (0,1), (1,1) from (0, 0) to (n-1, m-1). Returns the cost (inf when
    the band admits no path), the path int64 (P, 2) (empty then) and the cells evaluated.
    """
    n, d = a.shape
    m = b.shape[0]
    inf = np.inf
    acc = np.full((n, m), inf)
    cells = 0
    for i in range(n):
        for j in range(max(lo[i], 0), min(hi[i], m)):
            s = 0.0
            for c in range(d):
                diff = a[i, c] - b[j, c]
                s += diff * diff
            cost = np.sqrt(s)
            cells += 1
            if i == 0 and j == 0:
                acc[i, j] = cost
                continue
            best = inf
            if i > 0 and acc[i - 1, j] < best:
                best = acc[i - 1, j]
            if j > 0 and acc[i, j - 1] < best:
                best = acc[i, j - 1]
            if i > 0 and j > 0 and acc[i - 1, j - 1] < best:
                best = acc[i - 1, j - 1]
            acc[i, j] = best + cost
    total = acc[n - 1, m - 1]
    if not np.isfinite(total):
        return total, np.zeros((0, 2), dtype=np.int64), cells
    path = np.empty((n + m, 2), dtype=np.int64)
    i, j, p = n - 1, m - 1, 0
    path[0, 0] = i
    path[0, 1] = j
    while i > 0 or j > 0:
        best = inf
        bi, bj = i, j
        if i > 0 and j > 0 and acc[i - 1, j - 1] <= best:
            best = acc[i - 1, j - 1]
            bi, bj = i - 1, j - 1
        if i > 0 and acc[i - 1, j] < best:
            best = acc[i - 1, j]
            bi, bj = i - 1, j
        if j > 0 and acc[i, j - 1] < best:
            best = acc[i, j - 1]
            bi, bj = i, j - 1
        i, j = bi, bj
        p += 1
        path[p, 0] = i
        path[p, 1] = j
    return total, path[: p + 1][::-1].copy(), cells


@njit(cache=True)
def adaptive_chain(
    starts: np.ndarray, ends: np.ndarray, code: np.ndarray, first: np.ndarray, member: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """Extend maximal runs of ``V_1`` (``[starts, ends)``) through ``V_2 .. V_L`` (§5.2).

    Level ``l`` must begin exactly where level ``l-1`` ended, inside the same clip
    (``first[k]`` marks a clip's first segment), and is extended while the codes stay in
    ``V_l`` (``member[l, code]``). Work is proportional to the candidates' run lengths.
    Returns the segment boundaries ``k_1 < ... < k_{L+1}`` (n, L + 1) int64 of each hit.
    """
    n_levels = member.shape[0]
    n_seg = code.shape[0]
    out = np.empty((starts.shape[0], n_levels + 1), dtype=np.int64)
    n = 0
    for c in range(starts.shape[0]):
        out[n, 0] = starts[c]
        pos = ends[c]
        ok = True
        for level in range(1, n_levels):
            out[n, level] = pos
            if pos >= n_seg or first[pos] or not member[level, code[pos]]:
                ok = False
                break
            pos += 1
            while pos < n_seg and not first[pos] and member[level, code[pos]]:
                pos += 1
        if ok:
            out[n, n_levels] = pos
            n += 1
    return out[:n]
