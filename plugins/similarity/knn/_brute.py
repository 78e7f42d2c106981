"""Exact brute-force kNN in blocks with BLAS (for feature sets of high intrinsic dimension).

Squared distances are first computed in float32 with one GEMM per block of raw rows, as
``|y_c|^2 - 2 q_c.y + (|q_c|^2 + 2 q_c.mean)`` (``_c``: centred on the data mean, which keeps
the terms small without a centred copy of the data). Its rounding error is below
``tol = 2 (d + 4) u (|q_c|^2 + max|y_c|^2 + 2 |q_c| max|y|)`` (``u = 2^-24``, generous
constant), so every row whose approximate distance is within ``2 tol`` of the approximate
k-th one is kept as a candidate and re-ranked with exact float64 distances: the result
equals an exact search (no silent approximation), at BLAS speed.
"""

from __future__ import annotations

import numpy as np

from . import _brute_kernels as kern

_U32 = 2.0**-24


def brute_knn(
    queries: np.ndarray,
    data: np.ndarray,
    mean: np.ndarray,
    sqnorms: np.ndarray,
    k: int,
    r2: float,
    groups: np.ndarray,
    frames: np.ndarray,
    qgroups: np.ndarray,
    qframes: np.ndarray,
    excl: int,
    ids: np.ndarray | None = None,
    raw_bound: float | None = None,
    cap: int | None = None,
    block_rows: int = 32768,
    block_queries: int = 128,
    sqnorm_max: float | None = None,
    lean_max_rows: int = 262144,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact kNN by blocks (see module doc).

    Parameters
    ----------
    queries, data : ndarrays of shape (m, d) and (n, d), float32
    mean : ndarray of shape (d,), float32
        Subtracted from both (block by block) before the GEMM; exact re-ranking uses the
        original values, so centring never changes a result.
    sqnorms : ndarray of shape (n,), float32, ``|data - mean|^2``
    ids : ndarray of shape (n,), int64, optional
        Id returned for each stored row (the kd-tree stores rows permuted); ties are
        ordered by these ids. Default: the row numbers.
    raw_bound : float, optional
        :func:`raw_sqnorm_bound` of ``data`` (computed once at build time).
    sqnorm_max : float, optional
        ``sqnorms.max()``, likewise computed once (an O(n) pass per call otherwise).
    cap : int, optional
        Candidate buffer per query (default ``4 k + 256``); queries that overflow it (dense
        neighbourhoods, massive ties) are answered again with a 4x larger one.

    Returns
    -------
    sqdist : ndarray of shape (m, k), float64, ascending (inf where missing)
    ids : ndarray of shape (m, k), int64 (-1 where missing)
    """
    m, d = queries.shape
    n = data.shape[0]
    if n <= lean_max_rows and cap is None:
        args = (queries, data, mean, sqnorms, k, r2, groups, frames, qgroups, qframes, excl, ids, raw_bound)
        return lean_knn(*args, sqnorm_max=sqnorm_max)
    out_d = np.full((m, k), np.inf)
    out_i = np.full((m, k), -1, np.int64)
    ymax = sqnorm_max if sqnorm_max is not None else (float(sqnorms.max()) if n else 0.0)
    yraw = raw_bound if raw_bound is not None else (float(raw_sqnorm_bound(data)) if n else 0.0)
    for q0 in range(0, m, block_queries):
        q_orig = queries[q0 : q0 + block_queries]
        q = q_orig - mean
        nq = len(q)
        qn = np.einsum("ij,ij->i", q, q).astype(np.float64)
        # |q_c - y_c|^2 = |y_c|^2 - 2 q_c.y + (|q_c|^2 + 2 q_c.mean): the GEMM runs on the raw
        # rows (no centred copy); its rounding is bounded through |q_c| |y|
        const = qn + 2.0 * (q.astype(np.float64) @ mean.astype(np.float64))
        tol2 = 4.0 * (d + 4) * _U32 * (qn + ymax + 2.0 * np.sqrt(qn * yraw)) + 1e-30
        heap = np.full((nq, k), np.inf)
        cap = cap or 4 * k + 256
        cand_i = np.empty((nq, cap), np.int64)
        cand_v = np.empty((nq, cap))
        cand_n = np.zeros(nq, np.int64)
        overflow = np.zeros(nq, np.bool_)
        qg = np.ascontiguousarray(qgroups[q0 : q0 + nq])
        qf = np.ascontiguousarray(qframes[q0 : q0 + nq])
        for y0 in range(0, n, block_rows):
            g = q @ data[y0 : y0 + block_rows].T
            state = (heap, cand_i, cand_v, cand_n, overflow, tol2, r2 + tol2, excl, groups, frames, qg, qf)
            kern.scan_block(g, sqnorms, const, y0, *state)
        keep = (np.arange(cap)[None, :] < cand_n[:, None]) & (cand_v <= (heap[:, 0] + tol2)[:, None])
        cr, col = np.nonzero(keep)
        cc = cand_i[cr, col]
        if overflow.any():
            bad = overflow[cr]
            cr, cc = cr[~bad], cc[~bad]
        counts = np.bincount(cr, minlength=nq)
        width = max(int(counts.max()) if len(cr) else 0, 1)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rows = np.full((nq, width), -1, np.int64)
        rows[cr, np.arange(len(cr)) - first[cr]] = cc
        diff = data[np.maximum(rows, 0)].astype(np.float64) - q_orig[:, None, :].astype(np.float64)
        ex = np.einsum("ijk,ijk->ij", diff, diff)
        ex[rows < 0] = np.inf
        ex[ex > r2] = np.inf
        mapped = rows if ids is None else np.where(rows < 0, -1, ids[np.maximum(rows, 0)])
        ids_sort = np.where(mapped < 0, np.iinfo(np.int64).max, mapped)
        order = np.lexsort((ids_sort, ex), axis=1)
        ex = np.take_along_axis(ex, order, 1)[:, :k]
        rid = np.take_along_axis(mapped, order, 1)[:, :k]
        rid[~np.isfinite(ex)] = -1
        w = ex.shape[1]
        out_d[q0 : q0 + nq, :w] = ex
        out_i[q0 : q0 + nq, :w] = rid
        redo = np.flatnonzero(overflow)
        if redo.size:  # a buffer of n rows never overflows, so this terminates
            args = (q_orig[redo], data, mean, sqnorms, k, r2, groups, frames, qg[redo], qf[redo], excl, ids, yraw)
            d2, i2 = brute_knn(*args, min(4 * cap, n + 1), block_rows, block_queries, sqnorm_max=ymax)
            out_d[q0 + redo], out_i[q0 + redo] = d2, i2
    return out_d, out_i


def lean_knn(
    queries: np.ndarray,
    data: np.ndarray,
    mean: np.ndarray,
    sqnorms: np.ndarray,
    k: int,
    r2: float,
    groups: np.ndarray,
    frames: np.ndarray,
    qgroups: np.ndarray,
    qframes: np.ndarray,
    excl: int,
    ids: np.ndarray | None = None,
    raw_bound: float | None = None,
    block_queries: int | None = None,
    sqnorm_max: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`brute_knn` over a small database, with little per-call work.

    One GEMM per block of queries gives the approximate squared distances of all rows (same
    error bound as the blocked path); one kernel per query (:func:`.lean_rank`) finds the
    approximate k-th and re-ranks the rows within ``2 tol`` of it with exact float64
    distances (summed in dimension order like the kd-tree), ties ordered by id.
    Exact, like :func:`brute_knn`; memory ``block_queries x n`` float32 (default: about
    16 MB, 16 to 128 queries); the rows of a block are ranked on numba's threads.
    """
    m, d = queries.shape
    n = data.shape[0]
    if block_queries is None:
        block_queries = int(min(128, max(16, (1 << 22) // max(n, 1))))
    out_d = np.full((m, k), np.inf)
    out_i = np.full((m, k), -1, np.int64)
    ymax = sqnorm_max if sqnorm_max is not None else float(sqnorms.max())
    yraw = raw_bound if raw_bound is not None else float(raw_sqnorm_bound(data))
    ids = np.arange(n, dtype=np.int64) if ids is None else ids
    if m <= 2:  # interactive queries: one compiled call each, no per-call numpy work
        for r in range(m):
            dd, ii = kern.lean_query(
                queries[r], data, mean, sqnorms, ymax, yraw, k, r2, excl, groups, frames, qgroups[r], qframes[r], ids
            )
            out_d[r, : len(dd)] = dd
            out_i[r, : len(ii)] = ii
        return out_d, out_i
    for q0 in range(0, m, block_queries):
        qc = queries[q0 : q0 + block_queries] - mean
        qc64 = qc.astype(np.float64)
        qn = np.einsum("ij,ij->i", qc64, qc64)
        const = qn + 2.0 * (qc64 @ mean.astype(np.float64))
        tol2 = 4.0 * (d + 4) * _U32 * (qn + ymax + 2.0 * np.sqrt(qn * yraw)) + 1e-30
        a = qc @ data.T  # float32 GEMM, (block, n)
        a *= -2.0
        a += sqnorms
        lim = r2 - const + tol2
        kern.lean_rank_rows(
            a, lim, 2.0 * tol2, k, queries, q0, data, ids, r2, excl, groups, frames, qgroups, qframes, out_d, out_i
        )
    return out_d, out_i


def raw_sqnorm_bound(data: np.ndarray, block: int = 65536) -> float:
    """An upper bound on ``max |y|^2`` over the rows (float64 norms, with a rounding margin)."""
    best = 0.0
    for a in range(0, len(data), block):
        y = data[a : a + block].astype(np.float64)
        best = max(best, float(np.einsum("ij,ij->i", y, y).max()))
    return best * (1.0 + 1e-6)
