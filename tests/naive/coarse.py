"""Whole-array forms of the certified search's kernels, kept as oracles of the ranged ones in
:mod:`mocapflow.plugins.similarity._coarse_kernels` (same arithmetic, so the tests compare
bit for bit): ``coarse_alive`` (blocks that may hold a cell of a path of cost <= tau, over all
blocks) and ``sdtw_ranges`` (the fine DP over row ranges, with O(n) outputs)."""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapflow.plugins.similarity._coarse_kernels import _FAST


@njit(cache=True, fastmath=_FAST)
def coarse_alive(qt, lo, hi, link, tau, shrink):  # pragma: no cover - compiled
    """Blocks that may hold a cell of a path of cost <= ``tau`` (see module doc).

    Parameters
    ----------
    qt : float32 (d, m)   the query, transposed
    lo, hi, link : from :func:`block_boxes`
    tau : float
    shrink : float
        Box distances are multiplied by it (below 1: float32 rounding of these and of the
        fine DP's distances must not lift the bound above a fine cell).

    Returns
    -------
    alive : bool (nb,)
    """
    d, m = qt.shape
    nb = lo.shape[0]
    inf = np.inf
    c = np.empty((nb, m), np.float32)
    acc = np.empty(m, np.float32)
    for b in range(nb):
        for i in range(m):
            acc[i] = 0.0
        for k in range(d):
            lk = lo[b, k]
            hk = hi[b, k]
            for i in range(m):
                v = qt[k, i]
                t = max(lk - v, v - hk, np.float32(0.0))
                acc[i] += t * t
        for i in range(m):
            c[b, i] = np.sqrt(acc[i]) * shrink
    f = np.empty((nb, m))
    for b in range(nb):
        f[b, 0] = c[b, 0]
        linked = link[b]
        for i in range(1, m):
            best = f[b, i - 1]
            if linked:
                best = min(best, f[b - 1, i - 1], f[b - 1, i])
            f[b, i] = best + c[b, i]
    alive = np.zeros(nb, np.bool_)
    g_next = np.full(m, inf)
    g = np.empty(m)
    for b in range(nb - 1, -1, -1):
        linked_next = b + 1 < nb and link[b + 1]
        g[m - 1] = c[b, m - 1]  # a free end: going on vertically only adds cost
        for i in range(m - 2, -1, -1):
            best = g[i + 1]
            if linked_next:
                best = min(best, g_next[i + 1], g_next[i])
            g[i] = best + c[b, i]
        for i in range(m):
            if f[b, i] + g[i] - c[b, i] <= tau:
                alive[b] = True
                break
        for i in range(m):
            g_next[i] = g[i]
    return alive


@njit(cache=True, fastmath=_FAST)
def sdtw_ranges(qt, x, clip_start, ranges):  # pragma: no cover - compiled
    """:func:`._dtw_kernels.sdtw_forward` over the row ranges ``[a, b)`` of ``ranges`` only.

    Each range starts afresh (no path enters it from before); rows outside every range get
    cost inf, start -1, length 0. Same arithmetic and tie order as ``sdtw_forward``, so an
    end row whose best path lies inside its range gets exactly ``sdtw_forward``'s values.

    Returns
    -------
    cost : float64 (n,), start : int64 (n,), length : int64 (n,)
    """
    d, m = qt.shape
    n = x.shape[0]
    inf = np.inf
    cost = np.full(n, inf)
    start = np.full(n, -1, np.int64)
    length = np.zeros(n, np.int64)
    prev_c = np.full(m, inf)
    prev_s = np.zeros(m, np.int64)
    prev_l = np.zeros(m, np.int64)
    cur_c = np.empty(m)
    cur_s = np.empty(m, np.int64)
    cur_l = np.empty(m, np.int64)
    col = np.empty(m, np.float32)
    for r in range(ranges.shape[0]):
        for i in range(m):
            prev_c[i] = inf
        for j in range(ranges[r, 0], ranges[r, 1]):
            for i in range(m):
                col[i] = 0.0
            for k in range(d):
                xk = x[j, k]
                for i in range(m):
                    t = qt[k, i] - xk
                    col[i] += t * t
            for i in range(m):
                col[i] = np.sqrt(col[i])
            if clip_start[j]:
                for i in range(m):
                    prev_c[i] = inf
            cur_c[0] = col[0]
            cur_s[0] = j
            cur_l[0] = 1
            for i in range(1, m):
                a = prev_c[i - 1]
                b = prev_c[i]
                v = b < a
                cur_c[i] = b if v else a
                cur_s[i] = prev_s[i] if v else prev_s[i - 1]
                cur_l[i] = prev_l[i] if v else prev_l[i - 1]
            c = cur_c[0]
            s = cur_s[0]
            ln = cur_l[0]
            for i in range(1, m):
                b = cur_c[i]
                h = c < b
                s = s if h else cur_s[i]
                ln = (ln if h else cur_l[i]) + 1
                c = (c if h else b) + np.float64(col[i])
                cur_c[i] = c
                cur_s[i] = s
                cur_l[i] = ln
            cost[j] = c
            start[j] = s
            length[j] = ln
            prev_c, cur_c = cur_c, prev_c
            prev_s, cur_s = cur_s, prev_s
            prev_l, cur_l = cur_l, prev_l
    return cost, start, length
