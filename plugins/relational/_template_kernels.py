"""Numba kernels of ``matchers.template``: no validation here (the API validates).

Each kernel has a slow reference in ``tests/naive/templates.py``.

Subsequence DTW of a motion template against the database
--------------------------------------------------------
Template rows ``k = 0..K-1`` (template frames), database columns ``j`` (frames). The local
cost ``c[k, j]`` is looked up from the frame's 31-bit feature code split into the lower
(11 bits), upper (12) and mixed (8) parts: ``c = tab[lo, k] + tab[2048 + up, k] +
tab[6144 + mid, k]`` (the tables hold the template's per-part costs for every code, so
don't-care cells cost nothing whatever the frame's bits). Step sizes (1,1), (2,1), (1,2)
(Müller & Röder 2006) with weights 1, 2, 1 on the reached cell, so each template frame is
charged exactly once and ``D[K-1, j] / K`` is a mean local cost in [0, 1]; the database side
can stretch or compress the template by up to a factor 2. A path may start at any column
(at template frame 0, or at frame 1 by the (2,1) step) and never crosses a clip boundary.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: Offsets of the three code parts in the lookup table (lower 2**11, upper 2**12, mixed 2**8).
PART_OFFSETS = (0, 2048, 6144)
TABLE_ROWS = 6400


@njit(cache=True, inline="always")
def _fill_costs(code: int, table: np.ndarray, col: np.ndarray, lo: int, hi: int) -> None:  # pragma: no cover - compiled
    """Local costs ``col[k]`` of template rows ``lo <= k < hi`` for one frame code (module doc)."""
    a = code & 2047
    b = 2048 + ((code >> 11) & 4095)
    c = 6144 + ((code >> 23) & 255)
    for k in range(lo, hi):
        col[k] = table[a, k] + table[b, k] + table[c, k]


@njit(cache=True)
def dtw_path(a: np.ndarray, b: np.ndarray) -> tuple[float, np.ndarray]:  # pragma: no cover - compiled
    """Global DTW between ``a (n, f)`` and ``b (m, f)``, local cost mean |a - b| over features.

    Steps (1,0), (0,1), (1,1) from (0, 0) to (n-1, m-1). Returns the accumulated cost of the
    optimal path and the path, int64 (P, 2) (row of ``a``, row of ``b``) pairs in order.
    """
    n, f = a.shape
    m = b.shape[0]
    acc = np.empty((n, m))
    for i in range(n):
        for j in range(m):
            s = 0.0
            for c in range(f):
                s += abs(a[i, c] - b[j, c])
            s /= max(f, 1)
            if i == 0 and j == 0:
                acc[i, j] = s
                continue
            best = np.inf
            if i > 0 and j > 0:
                best = acc[i - 1, j - 1]
            if i > 0 and acc[i - 1, j] < best:
                best = acc[i - 1, j]
            if j > 0 and acc[i, j - 1] < best:
                best = acc[i, j - 1]
            acc[i, j] = best + s
    path = np.empty((n + m, 2), dtype=np.int64)
    i, j, p = n - 1, m - 1, 0
    path[0, 0] = i
    path[0, 1] = j
    while i > 0 or j > 0:
        if i == 0:
            j -= 1
        elif j == 0:
            i -= 1
        else:
            d, u, left = acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1]
            if d <= u and d <= left:
                i -= 1
                j -= 1
            elif u <= left:
                i -= 1
            else:
                j -= 1
        p += 1
        path[p, 0] = i
        path[p, 1] = j
    return acc[n - 1, m - 1], path[: p + 1][::-1].copy()


@njit(cache=True, inline="always")
def _best_step(
    a: float, sa: int, b: float, sb: int, c: float, sc: int
) -> tuple[float, int]:  # pragma: no cover - compiled
    """The least of three step costs with its path start; the first wins a tie (the
    order of the module doc's steps: (1,1), (2,1), (1,2))."""
    best, bs = a, sa
    if b < best:
        best, bs = b, sb
    if c < best:
        best, bs = c, sc
    return best, bs


@njit(cache=True)
def _sdtw_range(
    codes: np.ndarray,
    table: np.ndarray,
    lo_frame: int,
    hi_frame: int,
    cost: np.ndarray,
    start: np.ndarray,
    base: int = 0,
) -> None:  # pragma: no cover - compiled
    """Subsequence DTW over the frames ``[lo_frame, hi_frame)`` of one clip (module doc);
    the results of frame ``j`` go to ``cost[j - base]`` and ``start[j - base]``.

    Three accumulated-cost columns (j, j-1, j-2) in a ring buffer; the local-cost column is
    recomputed only when the frame code changes.
    """
    n_rows = table.shape[1]
    d = np.full((3, n_rows), np.inf)
    st = np.zeros((3, n_rows), np.int64)
    col = np.empty(n_rows)
    last_code = -1
    for j in range(lo_frame, hi_frame):
        code = codes[j]
        if code != last_code:  # runs of equal codes share their local-cost column
            _fill_costs(code, table, col, 0, n_rows)
            last_code = code
        r = j - lo_frame
        cur, p1, p2 = r % 3, (r + 2) % 3, (r + 1) % 3
        d0, s0, d1, s1, d2, s2 = d[cur], st[cur], d[p1], st[p1], d[p2], st[p2]
        if r == 0:
            for k in range(n_rows):
                d1[k] = np.inf
                d2[k] = np.inf
        elif r == 1:
            for k in range(n_rows):
                d2[k] = np.inf
        # template frame 0: a fresh start
        d0[0] = col[0]
        s0[0] = j
        if n_rows > 1:  # template frame 1: (1,1) from frame 0, (2,1) from the virtual row, (1,2)
            ck = col[1]
            best, bs = _best_step(d1[0] + ck, s1[0], 2.0 * ck, j, d2[0] + ck, s2[0])
            d0[1] = best
            s0[1] = bs
        for k in range(2, n_rows):
            ck = col[k]
            best, bs = _best_step(d1[k - 1] + ck, s1[k - 1], d1[k - 2] + 2.0 * ck, s1[k - 2], d2[k - 1] + ck, s2[k - 1])
            d0[k] = best
            s0[k] = bs
        cost[j - base] = d0[n_rows - 1] / n_rows
        start[j - base] = s0[n_rows - 1]


@njit(cache=True)
def _sdtw_range_bounded(
    codes: np.ndarray,
    table: np.ndarray,
    lo_frame: int,
    hi_frame: int,
    cost: np.ndarray,
    start: np.ndarray,
    bound: float,
) -> None:  # pragma: no cover - compiled
    """:func:`_sdtw_range` with early abandoning (the results of frame ``j`` go to
    ``cost[j]`` and ``start[j]``). ``bound`` (mean cost, ``inf``: none): cells above
    ``bound * K`` are abandoned and each column is computed only up to the highest row the
    live cells of the previous two can reach (as :func:`sdtw_cost`); costs and starts of
    the ends ``<= bound`` are exact (an abandoned cell is never on, nor tied with, a path
    ending there), the other ends are inf or exact.
    """
    n_rows = table.shape[1]
    finite = bound < np.inf
    limit = bound * n_rows * (1.0 + 1e-9) + 1e-12
    d0 = np.full(n_rows, np.inf)
    d1 = np.full(n_rows, np.inf)
    d2 = np.full(n_rows, np.inf)
    s0 = np.zeros(n_rows, np.int64)
    s1 = np.zeros(n_rows, np.int64)
    s2 = np.zeros(n_rows, np.int64)
    col = np.empty(n_rows)
    top0 = -1
    top1 = -1
    top2 = -1
    live1 = n_rows - 1 if not finite else -1
    live2 = live1
    last_code = -1
    valid = 0
    for j in range(lo_frame, hi_frame):
        code = codes[j]
        if code != last_code:  # runs of equal codes share their local-cost column
            last_code = code
            valid = 0
        reach = max(live1 + 2, live2 + 1, 1)
        if reach > n_rows - 1:
            reach = n_rows - 1
        if valid <= reach:
            _fill_costs(code, table, col, valid, reach + 1)
            valid = reach + 1
        # template frame 0: a fresh start
        v = col[0]
        d0[0] = v if v <= limit else np.inf
        s0[0] = j
        if reach >= 1:  # template frame 1: (1,1) from frame 0, (2,1) from the virtual row, (1,2)
            ck = col[1]
            best, bs = _best_step(d1[0] + ck, s1[0], 2.0 * ck, j, d2[0] + ck, s2[0])
            d0[1] = best if best <= limit else np.inf
            s0[1] = bs
        for k in range(2, reach + 1):
            ck = col[k]
            best, bs = _best_step(d1[k - 1] + ck, s1[k - 1], d1[k - 2] + 2.0 * ck, s1[k - 2], d2[k - 1] + ck, s2[k - 1])
            d0[k] = best if best <= limit else np.inf
            s0[k] = bs
        for k in range(reach + 1, top0 + 1):  # stale cells of this buffer's old column
            d0[k] = np.inf
        top0 = reach
        live = reach
        if finite:
            while live >= 0 and not d0[live] < np.inf:
                live -= 1
        cost[j] = d0[n_rows - 1] / n_rows if reach == n_rows - 1 else np.inf
        start[j] = s0[n_rows - 1]
        d0, d1, d2 = d2, d0, d1
        s0, s1, s2 = s2, s0, s1
        top0, top1, top2 = top2, top0, top1
        live2, live1 = live1, live


@njit(cache=True, parallel=True)
def template_sdtw(
    codes: np.ndarray,
    table: np.ndarray,
    chunk_lo: np.ndarray,
    chunk_hi: np.ndarray,
    cost: np.ndarray,
    start: np.ndarray,
    bound: float = np.inf,
) -> None:  # pragma: no cover - compiled
    """Subsequence DTW of one template over many clips, in parallel over clip ranges.

    ``codes`` (N,) int64: 31-bit feature code per frame (bit i = column i); ``table``
    (6400, K): per-part local costs (module doc); ``chunk_lo, chunk_hi`` (C,): frame ranges,
    each inside one clip. Writes ``cost`` (N,) = ``D[K-1, j] / K``, the mean local cost of the
    best path ending at frame j, and ``start`` (N,), its first frame (frames outside every
    range untouched). ``bound``: early abandoning above this mean cost; ``inf``: none.
    """
    for r in prange(chunk_lo.shape[0]):
        if bound < np.inf:
            _sdtw_range_bounded(codes, table, chunk_lo[r], chunk_hi[r], cost, start, bound)
        else:  # the plain kernel: no bookkeeping of live rows
            _sdtw_range(codes, table, chunk_lo[r], chunk_hi[r], cost, start, 0)


@njit(cache=True)
def _remaining_bound(
    codes: np.ndarray, table: np.ndarray, lo: int, hi: int, g: np.ndarray
) -> float:  # pragma: no cover - compiled
    """Lower bounds of the cost still to come for the frames ``[lo, hi)`` of one range.

    ``m[k]`` = least local cost of template row ``k`` over the codes of the range; ``g[k]``
    (out, (K,)) = least cost of finishing a path from row ``k`` (exclusive) to row ``K - 1``
    when every cell of row ``k'`` costs ``m[k']``: the recurrence of the search collapsed
    over frames (``g[k] = min(m[k+1] + g[k+1], 2 m[k+2] + g[k+2])``, a (2,1) step skips a
    row but charges the next twice). Returns the bound of a whole path (from a fresh start
    at row 0 or, by the virtual row, at row 1).
    """
    n_rows = table.shape[1]
    m = np.full(n_rows, np.inf)
    last = -1
    for j in range(lo, hi):
        code = codes[j]
        if code == last:
            continue
        last = code
        a = code & 2047
        b = 2048 + ((code >> 11) & 4095)
        c = 6144 + ((code >> 23) & 255)
        for k in range(n_rows):
            v = table[a, k] + table[b, k] + table[c, k]
            if v < m[k]:
                m[k] = v
    g[n_rows - 1] = 0.0
    if n_rows > 1:
        g[n_rows - 2] = m[n_rows - 1]
    for k in range(n_rows - 3, -1, -1):
        g[k] = min(m[k + 1] + g[k + 1], 2.0 * m[k + 2] + g[k + 2])
    total: float = m[0] + g[0]
    if n_rows > 1:
        total = min(total, 2.0 * m[1] + g[1])
    return total


@njit(cache=True)
def _cost_range_plain(
    codes: np.ndarray, table: np.ndarray, lo: int, hi: int, cost: np.ndarray
) -> None:  # pragma: no cover - compiled
    """:func:`sdtw_cost` of one range without a bound: every row of every column, branch-free."""
    n_rows = table.shape[1]
    d0 = np.empty(n_rows)
    d1 = np.full(n_rows, np.inf)
    d2 = np.full(n_rows, np.inf)
    col = np.empty(n_rows)
    last_code = -1
    for j in range(lo, hi):
        code = codes[j]
        if code != last_code:
            _fill_costs(code, table, col, 0, n_rows)
            last_code = code
        d0[0] = col[0]
        if n_rows > 1:
            ck = col[1]
            d0[1] = min(min(d1[0] + ck, 2.0 * ck), d2[0] + ck)
        for k in range(2, n_rows):
            ck = col[k]
            d0[k] = min(min(d1[k - 1] + ck, d1[k - 2] + 2.0 * ck), d2[k - 1] + ck)
        cost[j] = d0[n_rows - 1] / n_rows
        d0, d1, d2 = d2, d0, d1


@njit(cache=True, parallel=True)
def sdtw_cost(
    codes: np.ndarray,
    table: np.ndarray,
    chunk_lo: np.ndarray,
    chunk_hi: np.ndarray,
    cost: np.ndarray,
    bounds: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """End-frame costs only (no path starts), branch-free minima, early abandoning: the
    fast first pass of a search. Same recurrence as :func:`template_sdtw`.

    ``bounds`` (float64 (C,), a mean cost per range; ``inf``: none): accumulated costs only
    grow along a path, so a cell whose cost plus a lower bound of the rest of any path
    (:func:`_remaining_bound`) exceeds ``bound * K`` cannot lie on a path ending at or below
    the range's ``bound``: it is abandoned
    (inf), and a range whose whole-path bound exceeds it is skipped. Each column is
    computed only up to the highest row a live cell of the previous two columns can reach
    (+1 and +2 rows), and the local costs only for those rows. End costs ``<= bound`` are
    exact (the same minima, in the same order); the others are inf or exact.
    """
    n_rows = table.shape[1]
    for r in prange(chunk_lo.shape[0]):
        bound = bounds[r]
        finite = bound < np.inf
        if not finite:  # no bound: the plain kernel, no bookkeeping of live rows
            _cost_range_plain(codes, table, chunk_lo[r], chunk_hi[r], cost)
            continue
        limit = bound * n_rows * (1.0 + 1e-9) + 1e-12  # rounding slack: never abandon a cell on a path ending at bound
        g = np.zeros(n_rows)
        if finite and _remaining_bound(codes, table, chunk_lo[r], chunk_hi[r], g) > limit:
            for j in range(chunk_lo[r], chunk_hi[r]):
                cost[j] = np.inf
            continue
        d0 = np.full(n_rows, np.inf)
        d1 = np.full(n_rows, np.inf)
        d2 = np.full(n_rows, np.inf)
        col = np.empty(n_rows)
        top0, top1, top2 = -1, -1, -1  # highest row written (above it: inf) per buffer
        live1, live2 = -1, -1  # highest live row of the previous two columns
        last_code = -1
        valid = 0  # local costs of rows < valid are those of last_code
        for j in range(chunk_lo[r], chunk_hi[r]):
            code = codes[j]
            if code != last_code:
                last_code = code
                valid = 0
            reach = max(live1 + 2, live2 + 1, 1)
            if reach > n_rows - 1:
                reach = n_rows - 1
            if valid <= reach:
                _fill_costs(code, table, col, valid, reach + 1)
                valid = reach + 1
            # branch-free rows (a select, no jumps: vectorisable), the live top found afterwards
            v = col[0]
            d0[0] = v if v + g[0] <= limit else np.inf
            if reach >= 1:
                ck = col[1]
                v = min(min(d1[0] + ck, 2.0 * ck), d2[0] + ck)
                d0[1] = v if v + g[1] <= limit else np.inf
            for k in range(2, reach + 1):
                ck = col[k]
                v = min(min(d1[k - 1] + ck, d1[k - 2] + 2.0 * ck), d2[k - 1] + ck)
                d0[k] = v if v + g[k] <= limit else np.inf
            live = reach
            while live >= 0 and not d0[live] < np.inf:
                live -= 1
            if not finite:
                live = reach  # no bound: every row stays live (inf cells included), as without abandoning
            for k in range(reach + 1, top0 + 1):  # stale cells of this buffer's old column
                d0[k] = np.inf
            top0 = reach
            cost[j] = d0[n_rows - 1] / n_rows if reach == n_rows - 1 else np.inf
            d0, d1, d2 = d2, d0, d1
            top0, top1, top2 = top2, top0, top1
            live2, live1 = live1, live
