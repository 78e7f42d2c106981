"""Numba kernels of the exact brute force (:mod:`._brute`; no validation).

The blocked scan over GEMM results (:func:`scan_block`), and the lean path for small
databases: a one-pass k-th selection (:func:`lean_rank`) and the exact float64 re-ranking
of the candidates (:func:`exact_rank`), ties ordered by id as in the kd-tree
(:mod:`._knn_kernels`).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._knn_kernels import _IMAX, _before, _heap_replace


@njit(cache=True)
def _maxheap_replace(h, v):
    k = h.shape[0]
    pos = 0
    while True:
        c = 2 * pos + 1
        if c >= k:
            break
        if c + 1 < k and h[c + 1] > h[c]:
            c += 1
        if h[c] > v:
            h[pos] = h[c]
            pos = c
        else:
            break
    h[pos] = v


@njit(cache=True)
def _scan_row(r, g, sqn, const, y0, heap, cand_i, cand_v, cand_n, overflow, tol2, r2tol,
              excl, groups, frames, qg, qf):
    b = g.shape[1]
    cap = cand_i.shape[1]
    h = heap[r]
    n = cand_n[r]
    for j in range(b):
        a = np.float64(sqn[y0 + j]) - 2.0 * np.float64(g[r, j]) + const[r]
        if a > h[0] + tol2[r] or a > r2tol[r]:
            continue
        if excl >= 0 and groups[y0 + j] == qg[r] and abs(frames[y0 + j] - qf[r]) <= excl:
            continue
        if a < h[0]:
            _maxheap_replace(h, a)
        if n == cap:
            lim = h[0] + tol2[r]
            m = 0
            for t in range(n):
                if cand_v[r, t] <= lim:
                    cand_i[r, m] = cand_i[r, t]
                    cand_v[r, m] = cand_v[r, t]
                    m += 1
            n = m
            if n > cap // 2:  # compaction freed little: stop before it turns quadratic
                overflow[r] = True
                break
        cand_i[r, n] = y0 + j
        cand_v[r, n] = a
        n += 1
    cand_n[r] = n


@njit(cache=True, parallel=True)
def scan_block(g, sqn, const, y0, heap, cand_i, cand_v, cand_n, overflow, tol2, r2tol,
               excl, groups, frames, qg, qf):
    """One data block of the blocked brute force (see :mod:`._brute`), fused in one pass.

    ``g (nq, B)`` holds ``q_c . y`` for rows ``y0 .. y0 + B``; the approximate squared
    distance is ``sqn[y] - 2 g + const[q]``. ``heap (nq, k)`` (max-heap of approximate
    values) keeps the running k-th value; a row enters the candidate buffer when it is
    within ``tol2`` of it. A full buffer is compacted; if that frees less than half of it the
    query is flagged in ``overflow`` and the caller retries it with a larger buffer.
    """
    for r in prange(g.shape[0]):
        if not overflow[r]:
            _scan_row(r, g, sqn, const, y0, heap, cand_i, cand_v, cand_n, overflow, tol2, r2tol,
                      excl, groups, frames, qg, qf)


@njit(cache=True)
def scan_block_serial(g, sqn, const, y0, heap, cand_i, cand_v, cand_n, overflow, tol2, r2tol,
                      excl, groups, frames, qg, qf):
    """:func:`scan_block` on one thread (few queries: waking threads costs more than it saves)."""
    for r in range(g.shape[0]):
        if not overflow[r]:
            _scan_row(r, g, sqn, const, y0, heap, cand_i, cand_v, cand_n, overflow, tol2, r2tol,
                      excl, groups, frames, qg, qf)


@njit(cache=True)
def exact_rank(q, data, cand, ids, k, r2):
    """The ``k`` nearest of the rows ``cand`` to ``q``: exact float64 squared distances
    (summed in dimension order, like the kd-tree's search) and ``ids``, ordered by (distance, id);
    rows beyond ``r2`` dropped. Returns arrays of length ``min(k, number kept)``."""
    d = data.shape[1]
    c = cand.shape[0]
    dist = np.empty(c)
    for a in range(c):
        t = cand[a]
        acc = 0.0
        for j in range(d):
            diff = np.float64(data[t, j]) - np.float64(q[j])
            acc += diff * diff
        dist[a] = acc
    hd = np.full(k, np.inf)
    hi = np.full(k, _IMAX, np.int64)
    for a in range(c):
        if dist[a] <= r2 and _before(dist[a], ids[cand[a]], hd[0], hi[0]):
            _heap_replace(hd, hi, dist[a], ids[cand[a]])
    kept = 0
    for a in range(k):
        if hi[a] != _IMAX:
            kept += 1
    out_d = np.empty(kept)
    out_i = np.empty(kept, np.int64)
    b = 0
    for a in range(k):
        if hi[a] != _IMAX:
            out_d[b] = hd[a]
            out_i[b] = hi[a]
            b += 1
    order = np.argsort(out_d, kind="mergesort")
    out_d = out_d[order]
    out_i = out_i[order]
    for a in range(1, kept):  # equal distances: ids ascending
        b = a
        while b > 0 and out_d[b] == out_d[b - 1] and out_i[b] < out_i[b - 1]:
            out_i[b], out_i[b - 1] = out_i[b - 1], out_i[b]
            b -= 1
    return out_d, out_i


@njit(cache=True)
def lean_rank(a, lim, slack, k, q, data, ids, r2, excl, groups, frames, qg, qf):
    """Exact top ``k`` of one query from approximate squared distances ``a`` (n,), float32.

    Excluded rows are dropped, the approximate k-th value is found with a bounded max-heap
    (one pass, few insertions), and the rows within ``min(lim, kth + slack)`` are re-ranked
    exactly by :func:`exact_rank` (see :func:`._brute.lean_knn` for the bounds).
    """
    n = a.shape[0]
    h = np.full(k, np.inf)
    for t in range(n):
        if excl >= 0 and groups[t] == qg and abs(frames[t] - qf) <= excl:
            a[t] = np.inf
            continue
        v = np.float64(a[t])
        if v < h[0]:
            _maxheap_replace(h, v)
    if h[0] + slack < lim:
        lim = h[0] + slack
    c = 0
    for t in range(n):
        if a[t] <= lim:
            c += 1
    cand = np.empty(c, np.int64)
    c = 0
    for t in range(n):
        if a[t] <= lim:
            cand[c] = t
            c += 1
    return exact_rank(q, data, cand, ids, k, r2)
