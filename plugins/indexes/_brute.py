"""Exact brute-force kNN in blocks with BLAS (for feature sets of high intrinsic dimension).

Squared distances are first computed in float32 with one GEMM per block
(``|q|^2 + |y|^2 - 2 q.y``, data centred to keep the norms small). That shortcut has a
rounding error bounded by ``tol = 2 (d + 2) u (|q|^2 + max|y|^2)`` (``u = 2^-24``), so
every row whose approximate distance is within ``2 tol`` of the approximate k-th one is kept
as a candidate and re-ranked with exact float64 distances: the result equals an exact
search (no silent approximation), at BLAS speed.
"""
from __future__ import annotations

import numpy as np

_U32 = 2.0 ** -24


def brute_knn(queries: np.ndarray, data: np.ndarray, mean: np.ndarray, sqnorms: np.ndarray, k: int, r2: float,
              groups: np.ndarray, frames: np.ndarray, qgroups: np.ndarray, qframes: np.ndarray,
              excl: int, ids: np.ndarray | None = None, block_rows: int = 32768, block_queries: int = 128) -> tuple[np.ndarray, np.ndarray]:
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

    Returns
    -------
    sqdist : ndarray of shape (m, k), float64, ascending (inf where missing)
    ids : ndarray of shape (m, k), int64 (-1 where missing)
    """
    m, d = queries.shape
    n = data.shape[0]
    out_d = np.full((m, k), np.inf)
    out_i = np.full((m, k), -1, np.int64)
    ymax = float(sqnorms.max()) if n else 0.0
    yraw = float(np.einsum("ij,ij->i", data[:: max(n // 4096, 1)], data[:: max(n // 4096, 1)]).max()) if n else 0.0
    yraw = max(yraw, float((np.abs(data).max(0).astype(np.float64) ** 2).sum()) if n else 0.0)  # bound on |y|^2
    for q0 in range(0, m, block_queries):
        q_orig = queries[q0:q0 + block_queries]
        q = q_orig - mean
        nq = len(q)
        qn = np.einsum("ij,ij->i", q, q)
        # |q_c - y_c|^2 = |y_c|^2 - 2 q_c.y + (|q_c|^2 + 2 q_c.mean): the GEMM runs on the raw
        # rows (no centred copy); its rounding is bounded through |q_c| |y|
        const = (qn + 2.0 * (q @ mean)).astype(np.float32)
        qn64 = qn.astype(np.float64)
        tol2 = 4.0 * (d + 4) * _U32 * (qn64 + ymax + 2.0 * np.sqrt(qn64 * yraw)) + 1e-30
        kth = np.full(nq, np.inf)  # k-th smallest approximate distance among the candidates
        cr = np.zeros(0, np.int64)  # candidates: query row, stored row, approximate distance
        cc = np.zeros(0, np.int64)
        cv = np.zeros(0, np.float32)
        for y0 in range(0, n, block_rows):
            a = q @ data[y0:y0 + block_rows].T
            a *= -2.0
            a += sqnorms[y0:y0 + block_rows][None, :]
            a += const[:, None]
            if excl >= 0:
                bad = (groups[None, y0:y0 + block_rows] == qgroups[q0:q0 + nq, None]) & (
                    np.abs(frames[None, y0:y0 + block_rows] - qframes[q0:q0 + nq, None]) <= excl)
                a[bad] = np.inf
            thr = kth + tol2
            need = ~np.isfinite(kth)
            # rows still short of k candidates: the block's k-th value bounds the k-th overall
            if need.any() and a.shape[1] >= k:
                part = np.partition(a[need], k - 1, axis=1)[:, k - 1]
                thr[need] = np.minimum(thr[need], part + tol2[need])
            thr = np.minimum(thr, r2 + tol2)
            rr, col = np.nonzero(a <= thr[:, None].astype(np.float32))
            cr = np.concatenate([cr, rr])
            cc = np.concatenate([cc, col + y0])
            cv = np.concatenate([cv, a[rr, col]])
            # new k-th approximate value per row, then drop candidates that cannot make it
            order = np.lexsort((cv, cr))
            cr, cc, cv = cr[order], cc[order], cv[order]
            counts = np.bincount(cr, minlength=nq)
            first = np.concatenate([[0], np.cumsum(counts)[:-1]])
            has = counts >= k
            kth[has] = cv[first[has] + k - 1]
            keep = cv <= (kth + tol2)[cr]
            cr, cc, cv = cr[keep], cc[keep], cv[keep]
        counts = np.bincount(cr, minlength=nq)
        width = int(counts.max()) if len(cr) else 0
        if width == 0:
            continue
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
        out_d[q0:q0 + nq, :w] = ex
        out_i[q0:q0 + nq, :w] = rid
    return out_d, out_i
