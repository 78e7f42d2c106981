"""Compiled constrained DTW over motion-words (Aristidou et al. 2018, Appendix; the
convention is in :mod:`._mdm_kernels`): ``cdtw`` (any slope run r), ``cdtw_cost_r2``
(cost only, two rows, the default r = 2) and ``cdtw_path``. No validation here.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_INF = np.inf


@njit(cache=True)
def cdtw(
    d: np.ndarray, i0: int, j0: int, n: int, ln: int, r: int, cum: np.ndarray, plen: np.ndarray, back: np.ndarray
) -> tuple[float, int, int, int, int]:  # pragma: no cover - compiled
    """Constrained DTW of the source word at row ``i0`` against the target word at column
    ``j0`` (see module doc). Work arrays cum (n, M, 2r+1) float64, plen and back int64.

    Returns (cumulative cost, path length, end i, end j, end state).
    """
    n_s = 2 * r + 1
    for i in range(n):
        for j in range(ln):
            c = np.float64(d[i0 + i, j0 + j])
            for s in range(n_s):
                cum[i, j, s] = _INF
                plen[i, j, s] = 0
                back[i, j, s] = -1
            if i == 0 and j == 0:
                cum[0, 0, 0] = c
                plen[0, 0, 0] = 1
                continue
            # diagonal: from any state of (i-1, j-1)
            if i > 0 and j > 0:
                bc = _INF
                bl = 0
                bs = -1
                for s in range(n_s):
                    v = cum[i - 1, j - 1, s]
                    if v < bc or (v == bc and bs >= 0 and plen[i - 1, j - 1, s] < bl):
                        bc = v
                        bl = plen[i - 1, j - 1, s]
                        bs = s
                if bs >= 0 and bc < _INF:
                    cum[i, j, 0] = bc + c
                    plen[i, j, 0] = bl + 1
                    back[i, j, 0] = bs
            # horizontal (target advances) from (i, j-1), never out of a last-row cell
            if j > 0 and i < n - 1:
                bc = _INF
                bl = 0
                bs = -1
                for s in range(n_s):
                    if 1 <= s <= r:
                        continue
                    v = cum[i, j - 1, s]
                    if v < bc or (v == bc and bs >= 0 and plen[i, j - 1, s] < bl):
                        bc = v
                        bl = plen[i, j - 1, s]
                        bs = s
                if bs >= 0 and bc < _INF:
                    cum[i, j, 1] = bc + c
                    plen[i, j, 1] = bl + 1
                    back[i, j, 1] = bs
                for s in range(2, r + 1):
                    v = cum[i, j - 1, s - 1]
                    if v < _INF:
                        cum[i, j, s] = v + c
                        plen[i, j, s] = plen[i, j - 1, s - 1] + 1
                        back[i, j, s] = s - 1
            # vertical (source advances) from (i-1, j), never out of a last-column cell
            if i > 0 and j < ln - 1:
                bc = _INF
                bl = 0
                bs = -1
                for s in range(n_s):
                    if s > r:
                        continue
                    v = cum[i - 1, j, s]
                    if v < bc or (v == bc and bs >= 0 and plen[i - 1, j, s] < bl):
                        bc = v
                        bl = plen[i - 1, j, s]
                        bs = s
                if bs >= 0 and bc < _INF:
                    cum[i, j, r + 1] = bc + c
                    plen[i, j, r + 1] = bl + 1
                    back[i, j, r + 1] = bs
                for s in range(r + 2, 2 * r + 1):
                    v = cum[i - 1, j, s - 1]
                    if v < _INF:
                        cum[i, j, s] = v + c
                        plen[i, j, s] = plen[i - 1, j, s - 1] + 1
                        back[i, j, s] = s - 1
    # end cells: last row (j < ln) then last column (i < n - 1)
    bc = _INF
    bl = 0
    be_i = -1
    be_j = -1
    be_s = -1
    for e in range(ln + n - 1):
        if e < ln:
            ei = n - 1
            ej = e
        else:
            ei = e - ln
            ej = ln - 1
        for s in range(n_s):
            v = cum[ei, ej, s]
            if v < bc or (v == bc and be_s >= 0 and plen[ei, ej, s] < bl):
                bc = v
                bl = plen[ei, ej, s]
                be_i = ei
                be_j = ej
                be_s = s
    return bc, bl, be_i, be_j, be_s


@njit(cache=True)
def cdtw_cost_r2(
    d: np.ndarray, i0: int, j0: int, n: int, ln: int, cost: np.ndarray, plen: np.ndarray
) -> tuple[float, int]:  # pragma: no cover - compiled
    """Cost and length of :func:`cdtw` for the paper's slope constraint ``r = 2``.

    Same recurrence, tie rules and result, keeping two rows only; the five states (diagonal, 1-2 horizontal,
    1-2 vertical) live in scalars per cell. Work arrays cost (2, 5, M) float64 and plen
    (2, 5, M) int64 (two rows alternate).
    """
    big = np.int64(2**62)
    bc_end = _INF
    bl_end = big
    for i in range(n):
        cr = i & 1
        # the slope constraint makes cells with j > 3 i + 2 or i > 3 j + 2 unreachable
        pr = 1 - cr
        j_lo = max(0, -((2 - i) // 3))
        j_hi = min(ln - 1, 3 * i + 2)
        for j in range(ln):
            if j < j_lo or j > j_hi:
                for s in range(5):
                    cost[cr, s, j] = _INF
                    plen[cr, s, j] = big
                continue
            c = np.float64(d[i0 + i, j0 + j])
            if i == 0 and j == 0:
                for s in range(5):
                    cost[cr, s, 0] = _INF
                    plen[cr, s, 0] = big
                cost[cr, 0, 0] = c
                plen[cr, 0, 0] = 1
            else:
                # diagonal from any state of (i-1, j-1)
                bc = _INF
                bl = big
                if i > 0 and j > 0:
                    for s in range(5):
                        v = cost[pr, s, j - 1]
                        lv = plen[pr, s, j - 1]
                        if v < bc or (v == bc and lv < bl):
                            bc = v
                            bl = lv
                cost[cr, 0, j] = bc + c
                plen[cr, 0, j] = bl + 1
                # horizontal from (i, j-1): diagonal or vertical states start a run
                if j > 0 and i < n - 1:
                    bc = cost[cr, 0, j - 1]
                    bl = plen[cr, 0, j - 1]
                    v = cost[cr, 3, j - 1]
                    lv = plen[cr, 3, j - 1]
                    if v < bc or (v == bc and lv < bl):
                        bc = v
                        bl = lv
                    v = cost[cr, 4, j - 1]
                    lv = plen[cr, 4, j - 1]
                    if v < bc or (v == bc and lv < bl):
                        bc = v
                        bl = lv
                    cost[cr, 1, j] = bc + c
                    plen[cr, 1, j] = bl + 1
                    cost[cr, 2, j] = cost[cr, 1, j - 1] + c
                    plen[cr, 2, j] = plen[cr, 1, j - 1] + 1
                else:
                    cost[cr, 1, j] = _INF
                    plen[cr, 1, j] = big
                    cost[cr, 2, j] = _INF
                    plen[cr, 2, j] = big
                # vertical from (i-1, j): diagonal or horizontal states start a run
                if i > 0 and j < ln - 1:
                    bc = cost[pr, 0, j]
                    bl = plen[pr, 0, j]
                    v = cost[pr, 1, j]
                    lv = plen[pr, 1, j]
                    if v < bc or (v == bc and lv < bl):
                        bc = v
                        bl = lv
                    v = cost[pr, 2, j]
                    lv = plen[pr, 2, j]
                    if v < bc or (v == bc and lv < bl):
                        bc = v
                        bl = lv
                    cost[cr, 3, j] = bc + c
                    plen[cr, 3, j] = bl + 1
                    cost[cr, 4, j] = cost[pr, 3, j] + c
                    plen[cr, 4, j] = plen[pr, 3, j] + 1
                else:
                    cost[cr, 3, j] = _INF
                    plen[cr, 3, j] = big
                    cost[cr, 4, j] = _INF
                    plen[cr, 4, j] = big
            if i == n - 1 or j == ln - 1:
                for s in range(5):
                    v = cost[cr, s, j]
                    lv = plen[cr, s, j]
                    if v < _INF and (v < bc_end or (v == bc_end and lv < bl_end)):
                        bc_end = v
                        bl_end = lv
    return bc_end, bl_end


@njit(cache=True)
def cdtw_path(
    d: np.ndarray, i0: int, j0: int, n: int, ln: int, r: int
) -> tuple[float, np.ndarray]:  # pragma: no cover - compiled
    """Constrained DTW with the optimal path.

    Returns (mean cost, path (p, 2) int64 of (source row, target column) pairs).
    """
    m = max(ln, 1)
    cum = np.empty((n, m, 2 * r + 1))
    plen = np.empty((n, m, 2 * r + 1), np.int64)
    back = np.empty((n, m, 2 * r + 1), np.int64)
    c, p, ei, ej, es = cdtw(d, i0, j0, n, ln, r, cum, plen, back)
    path = np.empty((p, 2), np.int64)
    i, j, s = ei, ej, es
    for k in range(p - 1, -1, -1):
        path[k, 0] = i
        path[k, 1] = j
        ps = back[i, j, s]
        if s == 0:
            i -= 1
            j -= 1
        elif s <= r:
            j -= 1
        else:
            i -= 1
        s = ps
    return c / p, path
