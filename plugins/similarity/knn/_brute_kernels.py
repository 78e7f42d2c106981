"""Numba kernels of the exact brute force (:mod:`._brute`; no validation).

The blocked scan over GEMM results (:func:`scan_block`), and the lean path for small
databases: one compiled call per interactive query (:func:`lean_query`), a k-th selection
from a sampled threshold (:func:`lean_rank`, per block row in parallel by
:func:`lean_rank_rows`) and the exact float64 re-ranking of the candidates
(:func:`exact_rank`), ties ordered by id as in the kd-tree (:mod:`._knn_kernels`).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _maxheap_replace(h: np.ndarray, v: float) -> None:
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
def _scan_row(
    r: int,
    g: np.ndarray,
    sqn: np.ndarray,
    const: np.ndarray,
    y0: int,
    heap: np.ndarray,
    cand_i: np.ndarray,
    cand_v: np.ndarray,
    cand_n: np.ndarray,
    overflow: np.ndarray,
    tol2: np.ndarray,
    r2tol: np.ndarray,
    excl: int,
    groups: np.ndarray,
    frames: np.ndarray,
    qg: np.ndarray,
    qf: np.ndarray,
) -> None:
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
def scan_block(
    g: np.ndarray,
    sqn: np.ndarray,
    const: np.ndarray,
    y0: int,
    heap: np.ndarray,
    cand_i: np.ndarray,
    cand_v: np.ndarray,
    cand_n: np.ndarray,
    overflow: np.ndarray,
    tol2: np.ndarray,
    r2tol: np.ndarray,
    excl: int,
    groups: np.ndarray,
    frames: np.ndarray,
    qg: np.ndarray,
    qf: np.ndarray,
) -> None:
    """One data block of the blocked brute force (see :mod:`._brute`), fused in one pass.

    ``g (nq, B)`` holds ``q_c . y`` for rows ``y0 .. y0 + B``; the approximate squared
    distance is ``sqn[y] - 2 g + const[q]``. ``heap (nq, k)`` (max-heap of approximate
    values) keeps the running k-th value; a row enters the candidate buffer when it is
    within ``tol2`` of it. A full buffer is compacted; if that frees less than half of it the
    query is flagged in ``overflow`` and the caller retries it with a larger buffer.
    """
    for r in prange(g.shape[0]):
        if not overflow[r]:
            _scan_row(
                r, g, sqn, const, y0, heap, cand_i, cand_v, cand_n, overflow, tol2, r2tol, excl, groups, frames, qg, qf
            )


@njit(cache=True)
def exact_rank(
    q: np.ndarray, data: np.ndarray, cand: np.ndarray, ids: np.ndarray, k: int, r2: float
) -> tuple[np.ndarray, np.ndarray]:
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
    # sort the few candidates by distance, then ids ascending within equal distances
    order = np.argsort(dist)
    sd = dist[order]
    si = np.empty(c, np.int64)
    for a in range(c):
        si[a] = ids[cand[order[a]]]
    for a in range(1, c):
        b = a
        while b > 0 and sd[b] == sd[b - 1] and si[b] < si[b - 1]:
            si[b], si[b - 1] = si[b - 1], si[b]
            b -= 1
    kept = 0
    while kept < c and kept < k and sd[kept] <= r2:
        kept += 1
    out_d = sd[:kept].copy()
    out_i = si[:kept].copy()
    return out_d, out_i


@njit(cache=True)
def _kth_smallest(vals: np.ndarray, c: int, k: int) -> float:
    """The ``k``-th smallest of ``vals[:c]`` by a bounded max-heap, float64 (inf when ``c < k``)."""
    h = np.full(k, np.inf)
    for t in range(c):
        v = np.float64(vals[t])
        if v < h[0]:
            _maxheap_replace(h, v)
    kth: float = h[0]
    return kth


@njit(cache=True)
def lean_rank(
    a: np.ndarray,
    lim: float,
    slack: float,
    k: int,
    q: np.ndarray,
    data: np.ndarray,
    ids: np.ndarray,
    r2: float,
    excl: int,
    groups: np.ndarray,
    frames: np.ndarray,
    qg: int,
    qf: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact top ``k`` of one query from approximate squared distances ``a`` (n,), float32.

    Excluded rows are set to +inf. The approximate k-th value is then found without a heap
    pass over all rows: a strided sample (about 1,024 values) gives a
    threshold expected to keep about ``2 k`` rows; one vectorisable pass keeps the rows at
    or below it, and a bounded max-heap over those few gives the exact approximate k-th.
    Should the sample mislead (fewer than ``k`` rows kept), the heap runs over all rows, so
    the answer never depends on the sample, only the time. The rows within
    ``min(lim, kth + slack)`` are re-ranked exactly by :func:`exact_rank` (see
    :func:`._brute.lean_knn` for the bounds).
    """
    n = a.shape[0]
    if excl >= 0:
        for t in range(n):
            if groups[t] == qg and abs(frames[t] - qf) <= excl:
                a[t] = np.inf
    if n > 8 * k:
        stride = max(1, n // 1024)
        m = (n + stride - 1) // stride
        sample = np.empty(m)
        for i in range(m):
            sample[i] = a[i * stride]
        # rank of the threshold in the sample: twice the expected share of k, plus a margin
        r = min(m, 2 * (k * m) // n + 16)
        tau = _kth_smallest(sample, m, r)
        # one pass keeps every row that can matter: the k-th is <= tau when at least k rows
        # are <= tau, so every candidate (<= kth + slack) is <= tau + slack
        keep = min(lim, tau + slack)
        # small buffers (large fresh ones cost page faults on every call); overflow -> heap
        cap = max(8 * k + 256, 4 * r * stride)  # the sample's r-th stands for rank ~ r * stride
        cand = np.empty(cap, np.int64)
        vals = np.empty(cap)
        c = 0
        below = 0
        for t in range(n):
            v = np.float64(a[t])
            if v <= keep:
                if c == cap:
                    below = -1
                    break
                cand[c] = t
                vals[c] = v
                c += 1
                if v <= tau:
                    below += 1
        if below >= k:
            kth = _kth_smallest(vals, c, k)
            if kth + slack < lim:
                lim = kth + slack
            b = 0
            for i in range(c):
                if vals[i] <= lim:
                    cand[b] = cand[i]
                    b += 1
            return exact_rank(q, data, cand[:b], ids, k, r2)
    kth = _kth_smallest(a, n, k)
    if kth + slack < lim:
        lim = kth + slack
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


@njit(cache=True)
def lean_query(
    q: np.ndarray,
    data: np.ndarray,
    mean: np.ndarray,
    sqnorms: np.ndarray,
    ymax: float,
    yraw: float,
    k: int,
    r2: float,
    excl: int,
    groups: np.ndarray,
    frames: np.ndarray,
    qg: int,
    qf: int,
    ids: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One query of :func:`._brute.lean_knn` in one call (the per-call work is the point).

    The same arithmetic as the batched path: centred query, float32 matrix-vector product
    (BLAS), approximate squared distances ``|y_c|^2 - 2 q_c.y`` in float32, the error bound
    ``tol2`` of :mod:`._brute`, then :func:`lean_rank`.
    """
    d = data.shape[1]
    qc = np.empty(d, np.float32)
    qn = 0.0
    qm = 0.0
    for j in range(d):
        qc[j] = q[j] - mean[j]
        c64 = np.float64(qc[j])
        qn += c64 * c64
        qm += c64 * np.float64(mean[j])
    const = qn + 2.0 * qm
    tol2 = 4.0 * (d + 4) * 2.0**-24 * (qn + ymax + 2.0 * np.sqrt(qn * yraw)) + 1e-30
    a = np.dot(data, qc)
    two = np.float32(2.0)
    for t in range(a.shape[0]):
        a[t] = sqnorms[t] - two * a[t]
    return lean_rank(a, r2 - const + tol2, 2.0 * tol2, k, q, data, ids, r2, excl, groups, frames, qg, qf)


@njit(cache=True, parallel=True)
def lean_rank_rows(
    a: np.ndarray,
    lim: np.ndarray,
    slack: np.ndarray,
    k: int,
    queries: np.ndarray,
    q0: int,
    data: np.ndarray,
    ids: np.ndarray,
    r2: float,
    excl: int,
    groups: np.ndarray,
    frames: np.ndarray,
    qgroups: np.ndarray,
    qframes: np.ndarray,
    out_d: np.ndarray,
    out_i: np.ndarray,
) -> None:
    """:func:`lean_rank` of every row of a GEMM block ``a`` (b, n), rows spread over threads;
    results go to ``out_d / out_i[q0 + r]``."""
    for r in prange(a.shape[0]):
        dd, ii = lean_rank(
            a[r],
            lim[r],
            slack[r],
            k,
            queries[q0 + r],
            data,
            ids,
            r2,
            excl,
            groups,
            frames,
            qgroups[q0 + r],
            qframes[q0 + r],
        )
        for c in range(dd.shape[0]):
            out_d[q0 + r, c] = dd[c]
            out_i[q0 + r, c] = ii[c]
