"""Compiled kernels of the MDM cleaner: pose-distance blocks, constrained DTW, exact KNN.

No validation here (:mod:`.knn` checks inputs); each kernel has a slow reference in
``tests/naive/cleaning.py``; the cDTW kernels are in :mod:`._cdtw_kernels`.

Constrained DTW (paper Appendix): source rows ``i < N``, target columns ``j < L <= M``, cost
``D[i0+i, j0+j]``; the path starts at (0, 0) and ends at the first cell where either word
ends. Steps (1, 1), (0, 1), (1, 0), at most ``R`` non-diagonal steps in a row; a cell's DP
state is how it was entered: 0 diagonal (or the start), ``1..R`` horizontal run length,
``R+1..2R`` vertical. The optimum minimises the cumulative cost over the end cells (ties:
shorter path, then end cell order); the word distance is cost / path length.

Lower bound: a path ending on the last source row holds 1 to ``R+1`` cells of every other
row and one of the last, so its mean cost is a weighted mean of the row minima
``W[i] = min_j D[i0+i, j0+j]`` with weights in ``[1, R+1]``; the least such mean (weights
``R+1`` on the rows below the optimum, 1 above: a linear-fractional programme over a box)
bounds it. Column minima bound the paths ending on the last column; the distance is at
least the smaller bound.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

# re-exported for the callers (explicitly: `x as x`)
from ._cdtw_kernels import cdtw as cdtw
from ._cdtw_kernels import cdtw_cost_r2 as cdtw_cost_r2
from ._cdtw_kernels import cdtw_path as cdtw_path

_INF = np.inf


@njit(cache=True, parallel=True)
def pose_distance_block(
    src: np.ndarray, ctx: np.ndarray, mask: np.ndarray, drop: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
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
                d = abs(
                    src[i, k, 0] * ctx[c, k, 0]
                    + src[i, k, 1] * ctx[c, k, 1]
                    + src[i, k, 2] * ctx[c, k, 2]
                    + src[i, k, 3] * ctx[c, k, 3]
                )
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
def sliding_row_min(d: np.ndarray, tlen: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
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
def word_column_min(d: np.ndarray, starts: np.ndarray, n: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
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
def _min_weighted_mean(vals: np.ndarray, n_free: int, last: float, wmax: float) -> float:  # pragma: no cover - compiled
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
def lower_bounds(
    w_rows: np.ndarray,
    v_cols: np.ndarray,
    starts: np.ndarray,
    row0: int,
    n: int,
    tlen: np.ndarray,
    r: int,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
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
def _insert_topk(
    best_d: np.ndarray, best_t: np.ndarray, k: int, v: float, t: int
) -> None:  # pragma: no cover - compiled
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
def _excluded(
    t: int, clip_of: np.ndarray, self_clip: int, self_pos: int, radius: int
) -> bool:  # pragma: no cover - compiled
    return self_clip >= 0 and clip_of[t] == self_clip and abs(t - self_pos) <= radius


@njit(cache=True)
def _word_distance(
    d: np.ndarray,
    i0: int,
    t: int,
    n: int,
    tlen: np.ndarray,
    r: int,
    cum: np.ndarray,
    plen: np.ndarray,
    back: np.ndarray,
    cost2: np.ndarray,
    plen2: np.ndarray,
    memo: np.ndarray,
) -> float:  # pragma: no cover
    if math.isnan(memo[t]):
        if r == 2:
            c, p = cdtw_cost_r2(d, i0, t, n, tlen[t], cost2, plen2)
        else:
            c, p, _, _, _ = cdtw(d, i0, t, n, tlen[t], r, cum, plen, back)
        memo[t] = c / p
    mean: float = memo[t]
    return mean


@njit(cache=True, parallel=True)
def knn_pruned(
    d: np.ndarray,
    lb: np.ndarray,
    starts: np.ndarray,
    row0: int,
    n: int,
    tlen: np.ndarray,
    clip_of: np.ndarray,
    self_clip: int,
    self_off: int,
    radius: int,
    r: int,
    k: int,
    out_t: np.ndarray,
    out_d: np.ndarray,
    out_n: np.ndarray,
) -> None:  # pragma: no cover
    """Exact KNN with lower-bound pruning; same answer as the brute force (``knn_brute`` in
    ``tests/naive/cleaning.py``).

    Target starts are visited in increasing lower bound; the search stops once the bound
    exceeds the k-th best local minimum found. A start is a local minimum when its distance
    is below its left neighbour's and not above its right neighbour's: a neighbour whose
    bound already exceeds the start's distance needs no DTW (its distance is larger still).
    d (G, rows, C), lb (G, S, C); outputs out_t (G, S, k) int64 (-1 = none), out_d (G, S, k)
    float64 (inf = none) and out_n (G, S), the DTWs computed per word.
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
        nr = 0 if r == 2 else n  # cdtw's work arrays, for r != 2 only
        cum = np.empty((nr, m, 2 * r + 1))
        plen = np.empty((nr, m, 2 * r + 1), np.int64)
        back = np.empty((nr, m, 2 * r + 1), np.int64)
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
            v = _word_distance(dg, i0, t, n, tlen, r, cum, plen, back, cost2, plen2, memo)
            if v > best_d[k - 1]:
                continue
            u = t - 1
            if (
                u >= 0
                and tlen[u] > 0
                and clip_of[u] == clip_of[t]
                and not lbw[u] * slack > v
                and not v < _word_distance(dg, i0, u, n, tlen, r, cum, plen, back, cost2, plen2, memo)
            ):
                continue
            u = t + 1
            if (
                u < n_c
                and tlen[u] > 0
                and clip_of[u] == clip_of[t]
                and not lbw[u] * slack > v
                and not v <= _word_distance(dg, i0, u, n, tlen, r, cum, plen, back, cost2, plen2, memo)
            ):
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
