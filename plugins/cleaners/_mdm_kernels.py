"""Compiled kernels of the MDM cleaner: pose-distance blocks, constrained DTW, exact KNN.

No validation here; :mod:`.knn` and :mod:`.motion_words` check inputs and call these.
Each kernel has a slow reference in ``tests/naive/cleaning.py``.

Constrained DTW (paper Appendix), the convention every kernel shares
--------------------------------------------------------------------
Source word rows ``i < N``, target word columns ``j < L`` (``L <= M``), cost ``D[i0+i, j0+j]``.
The path starts at (0, 0) and ends at the *first* cell where ``i == N-1`` or ``j == L-1``
(either word ends). Steps are (1, 1) "diagonal", (0, 1) "horizontal" (the target advances)
and (1, 0) "vertical" (the source advances); the slope constraint allows at most ``R``
consecutive horizontal or vertical steps. The DP state of a cell is how it was entered:
0 = diagonal (or the start), ``1..R`` = ``r`` horizontal steps in a row, ``R+1..2R`` = ``r``
vertical steps in a row. The optimal path minimises the cumulative cost over all end cells
(ties: shorter path, then end cell order); the word distance is cumulative cost / path
length (mean cost along the path).

Lower bound used for pruning
----------------------------
A path ending on the last source row visits every row ``i``; rows ``i < N-1`` hold between
1 and ``R+1`` of its cells (a horizontal run is at most ``R`` long) and the last row exactly
one. Its mean cost is thus a weighted mean of per-row costs, each at least the row minimum
``W[i] = min_{j<L} D[i0+i, j0+j]``, with weights in ``[1, R+1]``; the smallest such weighted
mean (weights ``R+1`` on the rows below the optimum, 1 above: a linear-fractional programme
over a box) bounds it from below. Paths ending on the last target column are bounded the
same way with column minima. The word distance is at least the smaller of the two bounds.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_INF = np.inf


@njit(cache=True, parallel=True)
def pose_distance_block(src, ctx, mask, drop, out):  # pragma: no cover - compiled
    """Eq. 1 for every (source frame, context frame) pair and every group.

    src (S, m, 4), ctx (C, m, 4) float64; mask (G, m) uint8; drop (G,) int64;
    out (G, S, C) float32, written in place.
    """
    n_s, m = src.shape[0], src.shape[1]
    n_c = ctx.shape[0]
    n_g = mask.shape[0]
    max_drop = 0
    for g in range(n_g):
        max_drop = max(max_drop, drop[g])
    for i in prange(n_s):
        terms = np.empty(m)
        top = np.empty(max_drop + 1)
        for c in range(n_c):
            for k in range(m):
                d = abs(src[i, k, 0] * ctx[c, k, 0] + src[i, k, 1] * ctx[c, k, 1]
                        + src[i, k, 2] * ctx[c, k, 2] + src[i, k, 3] * ctx[c, k, 3])
                if d > 1.0:
                    d = 1.0
                a = math.acos(d)
                terms[k] = a * a
            for g in range(n_g):
                nd = drop[g]
                total = 0.0
                nt = 0
                for k in range(m):
                    if mask[g, k]:
                        v = terms[k]
                        total += v
                        if nd > 0:
                            # keep the nd largest terms, sorted descending, by insertion
                            p = nt if nt < nd else nd
                            if nt < nd or v > top[nd - 1]:
                                while p > 0 and top[p - 1] < v:
                                    if p < nd:
                                        top[p] = top[p - 1]
                                    p -= 1
                                top[p] = v
                                if nt < nd:
                                    nt += 1
                for r in range(nt):
                    total -= top[r]
                out[g, i, c] = total if total > 0.0 else 0.0


@njit(cache=True, parallel=True)
def sliding_row_min(d, tlen, out):  # pragma: no cover - compiled
    """out[g, i, t] = min_{j < tlen[t]} d[g, i, t + j] (inf where tlen[t] == 0); d (G, rows, C)."""
    n_g, n_r, n_c = d.shape
    for gi in prange(n_g * n_r):
        g = gi // n_r
        i = gi % n_r
        for t in range(n_c):
            ln = tlen[t]
            if ln == 0:
                out[g, i, t] = _INF
                continue
            best = _INF
            for j in range(ln):
                v = d[g, i, t + j]
                if v < best:
                    best = v
            out[g, i, t] = best


@njit(cache=True, parallel=True)
def word_column_min(d, starts, n, out):  # pragma: no cover - compiled
    """out[g, w, c] = min_{i < n} d[g, starts[w] + i, c]; d (G, rows, C)."""
    n_g = d.shape[0]
    n_w = starts.shape[0]
    n_c = d.shape[2]
    for gw in prange(n_g * n_w):
        g = gw // n_w
        w = gw % n_w
        s = starts[w]
        for c in range(n_c):
            best = _INF
            for i in range(n):
                v = d[g, s + i, c]
                if v < best:
                    best = v
            out[g, w, c] = best


@njit(cache=True)
def _min_weighted_mean(vals, n_free, last, wmax):  # pragma: no cover - compiled
    """min over w_i in [1, wmax] of (sum w_i vals_i + last) / (sum w_i + 1); vals[:n_free]
    is sorted in place."""
    # insertion sort (n_free <= 20)
    for a in range(1, n_free):
        v = vals[a]
        b = a - 1
        while b >= 0 and vals[b] > v:
            vals[b + 1] = vals[b]
            b -= 1
        vals[b + 1] = v
    total = last
    for a in range(n_free):
        total += vals[a]
    best = total / (n_free + 1)
    num = total
    den = n_free + 1.0
    for k in range(n_free):
        num += (wmax - 1.0) * vals[k]
        den += wmax - 1.0
        v = num / den
        if v < best:
            best = v
    return best


@njit(cache=True, parallel=True)
def lower_bounds(w_rows, v_cols, starts, row0, n, tlen, r, out):  # pragma: no cover - compiled
    """Lower bound of the word distance for every (group, word, target start).

    w_rows (G, rows, C): sliding row minima of the block whose first row is source frame
    ``row0``; v_cols (G, S, C): column minima per word; out (G, S, C) float64.
    """
    n_g = w_rows.shape[0]
    n_w = starts.shape[0]
    n_c = tlen.shape[0]
    wmax = r + 1.0
    m = n
    for t in range(n_c):
        m = max(m, tlen[t])
    for gw in prange(n_g * n_w):
        g = gw // n_w
        w = gw % n_w
        buf = np.empty(m + 1)
        i0 = starts[w] - row0
        for t in range(n_c):
            ln = tlen[t]
            if ln == 0:
                out[g, w, t] = _INF
                continue
            for i in range(n - 1):
                buf[i] = w_rows[g, i0 + i, t]
            lb_a = _min_weighted_mean(buf, n - 1, w_rows[g, i0 + n - 1, t], wmax)
            for j in range(ln - 1):
                buf[j] = v_cols[g, w, t + j]
            lb_b = _min_weighted_mean(buf, ln - 1, v_cols[g, w, t + ln - 1], wmax)
            out[g, w, t] = lb_a if lb_a < lb_b else lb_b


@njit(cache=True)
def cdtw(d, i0, j0, n, ln, r, cum, plen, back):  # pragma: no cover - compiled
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
def _better(v, ln_v, bc, bl):  # pragma: no cover - compiled
    """Whether (cost v, length ln_v) beats the current best (bc, bl): lower cost, then shorter."""
    return v < bc or (v == bc and ln_v < bl)


@njit(cache=True)
def cdtw_cost(d, i0, j0, n, ln, r, cur, prev, lcur, lprev):  # pragma: no cover - compiled
    """Cost and length of the optimal constrained-DTW path, keeping two rows only.

    Same recurrence and tie rules as :func:`cdtw` (which also keeps back pointers for the
    path); work arrays cur, prev (M, 2r+1) float64 and lcur, lprev (M, 2r+1) int64.
    Returns (cumulative cost, path length).
    """
    n_s = 2 * r + 1
    big = np.int64(2**62)
    bc_end = _INF
    bl_end = big
    for i in range(n):
        # the slope constraint makes cells with j > (r+1) i + r or i > (r+1) j + r unreachable
        j_lo = max(0, -((r - i) // (r + 1)))
        j_hi = min(ln - 1, (r + 1) * i + r)
        for j in range(ln):
            if j < j_lo or j > j_hi:
                for s in range(n_s):
                    cur[j, s] = _INF
                    lcur[j, s] = big
                continue
            c = np.float64(d[i0 + i, j0 + j])
            if i == 0 and j == 0:
                for s in range(n_s):
                    cur[0, s] = _INF
                    lcur[0, s] = big
                cur[0, 0] = c
                lcur[0, 0] = 1
            else:
                # diagonal
                bc = _INF
                bl = big
                if i > 0 and j > 0:
                    for s in range(n_s):
                        if _better(prev[j - 1, s], lprev[j - 1, s], bc, bl):
                            bc = prev[j - 1, s]
                            bl = lprev[j - 1, s]
                cur[j, 0] = bc + c
                lcur[j, 0] = bl + 1
                # horizontal: from diagonal or vertical states of (i, j-1); runs continue
                bc = _INF
                bl = big
                if j > 0 and i < n - 1:
                    if _better(cur[j - 1, 0], lcur[j - 1, 0], bc, bl):
                        bc = cur[j - 1, 0]
                        bl = lcur[j - 1, 0]
                    for s in range(r + 1, n_s):
                        if _better(cur[j - 1, s], lcur[j - 1, s], bc, bl):
                            bc = cur[j - 1, s]
                            bl = lcur[j - 1, s]
                cur[j, 1] = bc + c
                lcur[j, 1] = bl + 1
                for s in range(2, r + 1):
                    if j > 0 and i < n - 1:
                        cur[j, s] = cur[j - 1, s - 1] + c
                        lcur[j, s] = lcur[j - 1, s - 1] + 1
                    else:
                        cur[j, s] = _INF
                        lcur[j, s] = big
                # vertical: from diagonal or horizontal states of (i-1, j)
                bc = _INF
                bl = big
                if i > 0 and j < ln - 1:
                    for s in range(0, r + 1):
                        if _better(prev[j, s], lprev[j, s], bc, bl):
                            bc = prev[j, s]
                            bl = lprev[j, s]
                cur[j, r + 1] = bc + c
                lcur[j, r + 1] = bl + 1
                for s in range(r + 2, n_s):
                    if i > 0 and j < ln - 1:
                        cur[j, s] = prev[j, s - 1] + c
                        lcur[j, s] = lprev[j, s - 1] + 1
                    else:
                        cur[j, s] = _INF
                        lcur[j, s] = big
            # end cells: the last row, then the last column (same order as cdtw)
            if i == n - 1 or j == ln - 1:
                for s in range(n_s):
                    if cur[j, s] < _INF and _better(cur[j, s], lcur[j, s], bc_end, bl_end):
                        bc_end = cur[j, s]
                        bl_end = lcur[j, s]
        for j in range(ln):
            for s in range(n_s):
                prev[j, s] = cur[j, s]
                lprev[j, s] = lcur[j, s]
    return bc_end, bl_end


@njit(cache=True)
def cdtw_cost_r2(d, i0, j0, n, ln, cost, plen):  # pragma: no cover - compiled
    """:func:`cdtw_cost` specialised to the paper's slope constraint ``r = 2``.

    Same recurrence, tie rules and result; the five states (diagonal, 1-2 horizontal,
    1-2 vertical) live in scalars per cell. Work arrays cost (2, 5, M) float64 and plen
    (2, 5, M) int64 (two rows alternate).
    """
    big = np.int64(2**62)
    bc_end = _INF
    bl_end = big
    for i in range(n):
        cr = i & 1
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
def cdtw_path(d, i0, j0, n, ln, r):  # pragma: no cover - compiled
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


@njit(cache=True)
def _insert_topk(best_d, best_t, k, v, t):  # pragma: no cover - compiled
    """Insert (v, t) into the sorted top-k lists (ordered by value, then start)."""
    if v > best_d[k - 1] or (v == best_d[k - 1] and t >= best_t[k - 1]):
        return
    p = k - 1
    while p > 0 and (best_d[p - 1] > v or (best_d[p - 1] == v and best_t[p - 1] > t)):
        best_d[p] = best_d[p - 1]
        best_t[p] = best_t[p - 1]
        p -= 1
    best_d[p] = v
    best_t[p] = t


@njit(cache=True)
def _excluded(t, clip_of, self_clip, self_pos, radius):  # pragma: no cover - compiled
    return self_clip >= 0 and clip_of[t] == self_clip and abs(t - self_pos) <= radius


@njit(cache=True, parallel=True)
def knn_brute(d, starts, row0, n, tlen, clip_of, self_clip, self_off, radius, r, k, out_t, out_d):  # pragma: no cover
    """Reference KNN: the word distance at every target start, its local minima (within each
    clip), those farther than ``radius`` frames from the source word, the ``k`` smallest.

    ``self_clip`` is the source clip's position in the context (-1: not in it) and
    ``self_off`` the context frame of its first frame. d (G, rows, C) float32; out_t
    (G, S, k) int64 (-1 = none), out_d (G, S, k) float64 (inf = none).
    """
    n_g = d.shape[0]
    n_w = starts.shape[0]
    n_c = tlen.shape[0]
    m = 1
    for t in range(n_c):
        m = max(m, tlen[t])
    for gw in prange(n_g * n_w):
        g = gw // n_w
        w = gw % n_w
        dg = d[g]
        cur = np.empty((m, 2 * r + 1))
        prev = np.empty((m, 2 * r + 1))
        lcur = np.empty((m, 2 * r + 1), np.int64)
        lprev = np.empty((m, 2 * r + 1), np.int64)
        cost2 = np.empty((2, 5, m))
        plen2 = np.empty((2, 5, m), np.int64)
        f = np.full(n_c, _INF)
        i0 = starts[w] - row0
        for t in range(n_c):
            if tlen[t] > 0:
                if r == 2:
                    c, p = cdtw_cost_r2(dg, i0, t, n, tlen[t], cost2, plen2)
                else:
                    c, p = cdtw_cost(dg, i0, t, n, tlen[t], r, cur, prev, lcur, lprev)
                f[t] = c / p
        best_d = np.full(k, _INF)
        best_t = np.full(k, np.int64(2**62))
        self_pos = self_off + starts[w]
        for t in range(n_c):
            if tlen[t] == 0 or _excluded(t, clip_of, self_clip, self_pos, radius):
                continue
            if t > 0 and tlen[t - 1] > 0 and clip_of[t - 1] == clip_of[t] and not f[t] < f[t - 1]:
                continue
            if t + 1 < n_c and tlen[t + 1] > 0 and clip_of[t + 1] == clip_of[t] and not f[t] <= f[t + 1]:
                continue
            _insert_topk(best_d, best_t, k, f[t], t)
        for a in range(k):
            out_d[g, w, a] = best_d[a]
            out_t[g, w, a] = best_t[a] if best_d[a] < _INF else -1


@njit(cache=True)
def _word_distance(d, i0, t, n, tlen, r, cur, prev, lcur, lprev, cost2, plen2, memo):  # pragma: no cover
    if math.isnan(memo[t]):
        if r == 2:
            c, p = cdtw_cost_r2(d, i0, t, n, tlen[t], cost2, plen2)
        else:
            c, p = cdtw_cost(d, i0, t, n, tlen[t], r, cur, prev, lcur, lprev)
        memo[t] = c / p
    return memo[t]


@njit(cache=True, parallel=True)
def knn_pruned(d, lb, starts, row0, n, tlen, clip_of, self_clip, self_off, radius, r, k, out_t, out_d, out_n):  # pragma: no cover
    """Exact KNN with lower-bound pruning; same answer as :func:`knn_brute`.

    Target starts are visited in increasing lower bound; the search stops once the bound
    exceeds the k-th best local minimum found. A start is a local minimum when its distance
    is below its left neighbour's and not above its right neighbour's: a neighbour whose
    bound already exceeds the start's distance needs no DTW (its distance is larger still).
    d (G, rows, C), lb (G, S, C); outputs as :func:`knn_brute` plus out_n (G, S), the DTWs
    computed per word.
    """
    n_g = d.shape[0]
    n_w = starts.shape[0]
    n_c = tlen.shape[0]
    m = 1
    for t in range(n_c):
        m = max(m, tlen[t])
    slack = 1.0 - 1e-9  # bounds and distances sum the same terms in another order
    for gw in prange(n_g * n_w):
        g = gw // n_w
        w = gw % n_w
        dg = d[g]
        lbw = lb[g, w]
        cur = np.empty((m, 2 * r + 1))
        prev = np.empty((m, 2 * r + 1))
        lcur = np.empty((m, 2 * r + 1), np.int64)
        lprev = np.empty((m, 2 * r + 1), np.int64)
        cost2 = np.empty((2, 5, m))
        plen2 = np.empty((2, 5, m), np.int64)
        memo = np.full(n_c, np.nan)
        i0 = starts[w] - row0
        order = np.argsort(lbw)
        best_d = np.full(k, _INF)
        best_t = np.full(k, np.int64(2**62))
        self_pos = self_off + starts[w]
        for a in range(n_c):
            t = order[a]
            bound = lbw[t] * slack
            if bound == _INF or bound > best_d[k - 1]:
                break
            if _excluded(t, clip_of, self_clip, self_pos, radius):
                continue
            v = _word_distance(dg, i0, t, n, tlen, r, cur, prev, lcur, lprev, cost2, plen2, memo)
            if v > best_d[k - 1]:
                continue
            u = t - 1
            if u >= 0 and tlen[u] > 0 and clip_of[u] == clip_of[t] and not lbw[u] * slack > v:
                if not v < _word_distance(dg, i0, u, n, tlen, r, cur, prev, lcur, lprev, cost2, plen2, memo):
                    continue
            u = t + 1
            if u < n_c and tlen[u] > 0 and clip_of[u] == clip_of[t] and not lbw[u] * slack > v:
                if not v <= _word_distance(dg, i0, u, n, tlen, r, cur, prev, lcur, lprev, cost2, plen2, memo):
                    continue
            _insert_topk(best_d, best_t, k, v, t)
        computed = 0
        for t in range(n_c):
            if not math.isnan(memo[t]):
                computed += 1
        out_n[g, w] = computed
        for a in range(k):
            out_d[g, w, a] = best_d[a]
            out_t[g, w, a] = best_t[a] if best_d[a] < _INF else -1
