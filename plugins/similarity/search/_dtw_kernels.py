"""Numba kernels of exact subsequence DTW (no validation; see :mod:`.sdtw`).

Step pattern and costs are those of the lazy neighborhood graph (Krüger 2010, §4.1), so
the two matchers are comparable cell for cell. With ``d(i, j)`` the Euclidean distance of
query frame ``i`` and database row ``j``::

    D(0, j) = d(0, j)                                     (free start: the super-source)
    D(i, j) = d(i, j) + min(D(i-1, j-1),  # diagonal
                            D(i,   j-1),  # vertical: database advances, query stays
                            D(i-1, j))    # horizontal: query advances, database stays

Ties go to the first of diagonal, vertical, horizontal (the LNG kernel uses the same
order). Steps that advance the database (diagonal, vertical) are forbidden from row
``j-1`` to ``j`` when ``j`` starts a new clip (``clip_start[j]``), so no path crosses a
clip boundary. Reference: ``tests/naive/dtw.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

# reassociation lets the distance loops vectorise; no "nnan"/"ninf": the DP relies on inf
_FAST = {"reassoc", "contract", "nsz", "arcp"}


@njit(cache=True, inline="always")
def column_buffers(
    m: int,
) -> tuple[
    np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray
]:  # pragma: no cover - compiled
    """The two DP columns of :func:`sdtw_column` and its distance scratch, for a query of ``m`` frames.

    Returns ``prev_c, prev_s, prev_l`` (column ``j - 1``: inf, as before the first row),
    ``cur_c, cur_s, cur_l`` (filled by the column) and ``col``: float64 / int64 / int64 (m,)
    each, ``col`` float32 (m,).
    """
    return (
        np.full(m, np.inf),
        np.zeros(m, np.int64),
        np.zeros(m, np.int64),
        np.empty(m),
        np.empty(m, np.int64),
        np.empty(m, np.int64),
        np.empty(m, np.float32),
    )


@njit(cache=True, fastmath=_FAST, inline="always")
def sdtw_column(
    qt: np.ndarray,
    x: np.ndarray,
    j: int,
    fresh: bool,
    prev_c: np.ndarray,
    prev_s: np.ndarray,
    prev_l: np.ndarray,
    cur_c: np.ndarray,
    cur_s: np.ndarray,
    cur_l: np.ndarray,
    col: np.ndarray,
) -> tuple[float, int, int]:  # pragma: no cover - compiled
    """One column of the DP: database row ``j`` from column ``j - 1`` (the recurrence above).

    Shared by :func:`sdtw_forward` and :func:`._coarse_kernels.sdtw_ranges_compact`, so the
    two run the same arithmetic and tie order bit for bit. Inlined at the Numba IR level
    (``inline="always"``): the callers keep their loops and buffers in registers as if the
    column were written out in them.

    Parameters
    ----------
    qt : float32 (d, m)   the query, transposed
    x : float32 (n, d)    database rows
    j : int               the row of this column
    fresh : bool          no path enters row ``j`` from row ``j - 1`` (clip start, range start)
    prev_c, prev_s, prev_l : float64 / int64 / int64 (m,)
        Column ``j - 1``: cost, first row and number of cells of the best path into each
        cell. ``prev_c`` is overwritten with inf when ``fresh``.
    cur_c, cur_s, cur_l : same, (m,)   receive column ``j``
    col : float32 (m,)    scratch: the local distances of row ``j``

    Returns
    -------
    cost : float64, start : int64, length : int64
        ``D(m-1, j)``, the first row and the number of cells of its path.

    The update is split into a vectorisable diagonal-vs-vertical pass and the serial
    horizontal chain, both written as selects (no data-dependent branches: about 1.5x
    faster). Local distances are float32 (like the index's), accumulated in float64.
    """
    d, m = qt.shape
    for i in range(m):
        col[i] = 0.0
    for k in range(d):
        xk = x[j, k]
        for i in range(m):
            t = qt[k, i] - xk
            col[i] += t * t
    for i in range(m):
        col[i] = np.sqrt(col[i])
    if fresh:
        for i in range(m):
            prev_c[i] = np.inf
    cur_c[0] = col[0]
    cur_s[0] = j
    cur_l[0] = 1
    # diagonal vs vertical (ties to diagonal): selects, no dependency along i
    for i in range(1, m):
        a = prev_c[i - 1]
        b = prev_c[i]
        v = b < a
        cur_c[i] = b if v else a
        cur_s[i] = prev_s[i] if v else prev_s[i - 1]
        cur_l[i] = prev_l[i] if v else prev_l[i - 1]
    # horizontal: the only serial chain, branch-free
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
    return c, s, ln


@njit(cache=True, fastmath=_FAST)
def sdtw_forward(
    qt: np.ndarray, x: np.ndarray, clip_start: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Accumulated cost of the best path ending in every database row.

    Parameters
    ----------
    qt : float32 (d, m)
        The query, transposed (so the distance column vectorises over query frames).
    x : float32 (n, d)
        Database rows.
    clip_start : bool (n,)
        Row ``j`` does not continue row ``j-1`` (first frame of a clip).

    Returns
    -------
    cost : float64 (n,)  ``D(m-1, j)``
    start : int64 (n,)   first database row of that path
    length : int64 (n,)  number of cells of that path

    Memory is O(m + n): two columns of the DP and the three outputs; each column is
    :func:`sdtw_column`.
    """
    m = qt.shape[1]
    n = x.shape[0]
    cost = np.empty(n, np.float64)
    start = np.empty(n, np.int64)
    length = np.empty(n, np.int64)
    prev_c, prev_s, prev_l, cur_c, cur_s, cur_l, col = column_buffers(m)
    for j in range(n):
        cost[j], start[j], length[j] = sdtw_column(
            qt, x, j, clip_start[j], prev_c, prev_s, prev_l, cur_c, cur_s, cur_l, col
        )
        prev_c, cur_c = cur_c, prev_c
        prev_s, cur_s = cur_s, prev_s
        prev_l, cur_l = cur_l, prev_l
    return cost, start, length


@njit(cache=True, fastmath=_FAST)
def sdtw_ranges_compact(
    qt: np.ndarray, x: np.ndarray, clip_start: np.ndarray, ranges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """The fine DP over row ranges, returning only the rows inside them (no O(n) arrays).

    Each range ``[a, b)`` of ``ranges`` (int64 (r, 2), ascending and disjoint) starts afresh:
    no path enters it from before. The columns are :func:`sdtw_column`, the
    whole-array DP's, so an end row whose best path lies inside its range gets exactly
    ``sdtw_forward``'s values (bit for bit; ``tests/plugins/similarity/test_exact_search.py``). Used by the
    certified search (:mod:`.certified`) on the rows its coarse bound keeps. It lives here, in
    ``sdtw_column``'s module, because Numba's cache invalidates on the caller's file only:
    an inlined column edited in another module would leave a stale compiled caller.

    Returns
    -------
    rows : int64 (p,)   the rows of the ranges, in order
    cost : float64 (p,), start : int64 (p,), length : int64 (p,)
        the best path ending in each of those rows, inside its range
    """
    m = qt.shape[1]
    p = 0
    for r in range(ranges.shape[0]):
        p += ranges[r, 1] - ranges[r, 0]
    rows = np.empty(p, np.int64)
    cost = np.empty(p)
    start = np.empty(p, np.int64)
    length = np.empty(p, np.int64)
    prev_c, prev_s, prev_l, cur_c, cur_s, cur_l, col = column_buffers(m)
    o = 0
    for r in range(ranges.shape[0]):
        a = ranges[r, 0]
        for j in range(a, ranges[r, 1]):
            rows[o] = j
            cost[o], start[o], length[o] = sdtw_column(
                qt, x, j, j == a or clip_start[j], prev_c, prev_s, prev_l, cur_c, cur_s, cur_l, col
            )
            o += 1
            prev_c, cur_c = cur_c, prev_c
            prev_s, cur_s = cur_s, prev_s
            prev_l, cur_l = cur_l, prev_l
    return rows, cost, start, length


@njit(cache=True)
def dtw_window_path(q: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, float]:  # pragma: no cover - compiled
    """Warping path of the best alignment of ``q`` onto all of ``w``.

    The path starts in cell (0, 0) and ends in cell (m-1, L-1) of the window; the
    recursion, start rule and tie order are those of :func:`sdtw_forward` restricted to
    paths that start at the window's first row, so with ``w`` the rows
    ``start .. end`` found by the forward pass it reproduces that pass's path and cost.

    Parameters
    ----------
    q : float32 (m, d)
    w : float32 (L, d)  contiguous rows of one clip

    Returns
    -------
    path : int64 (p, 2)  (query frame, window row) pairs in order
    cost : float64
    """
    m, d = q.shape
    n = w.shape[0]
    inf = np.inf
    acc = np.full((m, n), inf)
    step = np.zeros((m, n), np.int8)  # 0 diagonal, 1 vertical, 2 horizontal, 3 start
    for j in range(n):
        for i in range(m):
            s = np.float32(0.0)  # same float32 arithmetic as sdtw_forward
            for k in range(d):
                t = q[i, k] - w[j, k]
                s += t * t
            c = np.float64(np.sqrt(s))
            if i == 0:
                if j == 0:
                    acc[0, 0] = c
                    step[0, 0] = 3
                # the forward pass never takes a vertical step in row 0 (a fresh start
                # there is always at least as cheap), so neither does the window
                continue
            b = inf
            st = 0
            if j > 0:
                b = acc[i - 1, j - 1]
                st = 0
                if acc[i, j - 1] < b:
                    b = acc[i, j - 1]
                    st = 1
            if acc[i - 1, j] < b:
                b = acc[i - 1, j]
                st = 2
            acc[i, j] = b + c
            step[i, j] = st
    out = np.empty((m + n, 2), np.int64)
    i = m - 1
    j = n - 1
    p = 0
    while True:
        out[p, 0] = i
        out[p, 1] = j
        p += 1
        st = step[i, j]
        if st == 3:
            break
        if st == 0:
            i -= 1
            j -= 1
        elif st == 1:
            j -= 1
        else:
            i -= 1
    return out[:p][::-1].copy(), acc[m - 1, n - 1]


@njit(cache=True, fastmath=_FAST, parallel=True)
def sdtw_ranges_parallel(
    qt: np.ndarray, x: np.ndarray, clip_start: np.ndarray, ranges: np.ndarray, groups: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """:func:`sdtw_ranges_compact` with the ranges of each group ``groups[g] .. groups[g + 1]``
    on its own numba thread: the same columns, so the same values bit for bit (each range
    starts afresh in both). ``groups``: int64 (g + 1,), ascending range positions, 0 .. r."""
    m = qt.shape[1]
    nr = ranges.shape[0]
    off = np.zeros(nr + 1, np.int64)
    for r in range(nr):
        off[r + 1] = off[r] + ranges[r, 1] - ranges[r, 0]
    p = off[nr]
    rows = np.empty(p, np.int64)
    cost = np.empty(p)
    start = np.empty(p, np.int64)
    length = np.empty(p, np.int64)
    for g in prange(groups.shape[0] - 1):
        prev_c, prev_s, prev_l, cur_c, cur_s, cur_l, col = column_buffers(m)
        for r in range(groups[g], groups[g + 1]):
            a = ranges[r, 0]
            o = off[r]
            for j in range(a, ranges[r, 1]):
                rows[o] = j
                cost[o], start[o], length[o] = sdtw_column(
                    qt, x, j, j == a or clip_start[j], prev_c, prev_s, prev_l, cur_c, cur_s, cur_l, col
                )
                o += 1
                prev_c, cur_c = cur_c, prev_c
                prev_s, cur_s = cur_s, prev_s
                prev_l, cur_l = cur_l, prev_l
    return rows, cost, start, length
