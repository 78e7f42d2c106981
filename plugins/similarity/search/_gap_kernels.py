"""Numba kernels of the gap-tolerant lazy neighborhood graph (our extension; see :mod:`.lng`).

The paper's graph has a node ``(i, h)`` only where row ``h`` is among the ``k`` neighbours
of query frame ``i``: one query frame without a neighbour in a clip cuts every path through
that clip. The gap-tolerant graph adds *gap cells*: a row ``h`` is a node of layer ``i``
also when it lies at most ``gaps`` query frames after a neighbour cell along steps of at
most two database frames per query frame (the forward band), or at most ``gaps`` query
frames before one (the backward band). Each gap cell's cost is computed exactly on demand
(one feature-space distance), so every path in the graph is a real warping path with its
exact subsequence-DTW cost; only the set of paths searched is smaller. A path may thus
cross up to ``2 * gaps`` consecutive query frames without a neighbour cell (``gaps`` after
the last one it left, ``gaps`` before the next), or start or end with ``gaps`` of them.

``gap_layers`` returns the layers as ``lng_forward`` takes them (rows ascending per
layer, padded with -1 / inf), so the path search is unchanged.
Reference: ``tests/naive/gaps.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _step_rows(
    rows: np.ndarray,
    depth: np.ndarray,
    n_in: int,
    gaps: int,
    continues: np.ndarray,
    forward: bool,
    out_rows: np.ndarray,
    out_depth: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Rows one query frame after (``forward``) or before a layer, with their depth.

    Every row ``h`` of depth < ``gaps`` gives ``h .. h + 2`` (forward) or ``h - 2 .. h``
    (backward), within ``h``'s clip, at depth + 1; a row reached twice keeps the smaller
    depth. ``rows`` ascending gives ascending, distinct output without a sort.

    Returns
    -------
    int : rows written to ``out_rows`` / ``out_depth``
    """
    n = continues.shape[0]
    b = 0
    last = -1
    for a in range(n_in):
        dep = depth[a]
        if dep >= gaps:
            continue
        h = rows[a]
        lo = h
        hi = h
        if forward:
            if h + 1 < n and continues[h + 1]:
                hi = h + 1
                if h + 2 < n and continues[h + 2]:
                    hi = h + 2
        elif continues[h]:
            lo = h - 1
            if continues[h - 1]:
                lo = h - 2
        for r in range(lo, hi + 1):
            if r <= last:  # already written: rows are distinct and ascending, so scan back
                p = b - 1
                while p > 0 and out_rows[p] > r:
                    p -= 1
                if out_rows[p] == r and dep + 1 < out_depth[p]:
                    out_depth[p] = dep + 1
            else:
                out_rows[b] = r
                out_depth[b] = dep + 1
                b += 1
        if hi > last:
            last = hi
    return b


@njit(cache=True)
def _merge(
    ra: np.ndarray,
    da: np.ndarray,
    na: int,
    rb: np.ndarray,
    db: np.ndarray,
    nb: int,
    out_rows: np.ndarray,
    out_depth: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Union of two ascending row lists, smaller depth on common rows; returns its size."""
    a = 0
    b = 0
    c = 0
    while a < na or b < nb:
        if b >= nb or (a < na and ra[a] < rb[b]):
            out_rows[c] = ra[a]
            out_depth[c] = da[a]
            a += 1
        elif a >= na or rb[b] < ra[a]:
            out_rows[c] = rb[b]
            out_depth[c] = db[b]
            b += 1
        else:
            out_rows[c] = ra[a]
            out_depth[c] = min(da[a], db[b])
            a += 1
            b += 1
        c += 1
    return c


@njit(cache=True)
def _band(
    ids: np.ndarray, count: np.ndarray, gaps: int, continues: np.ndarray, forward: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Neighbour rows plus the forward (or backward) band of every layer, flat.

    Returns ``(rows, depth, offsets)``: layer ``i`` is ``rows[offsets[i]:offsets[i+1]]``
    ascending, depth 0 for neighbour rows.
    """
    m, k = ids.shape
    cap = max(16, 4 * int(count.sum()))
    rows = np.empty(cap, np.int64)
    depth = np.empty(cap, np.int32)
    offsets = np.zeros(m + 1, np.int64)
    zero = np.zeros(k, np.int32)
    order = np.arange(m) if forward else np.arange(m - 1, -1, -1)
    sizes = np.zeros(m, np.int64)
    starts = np.zeros(m, np.int64)
    prev_start = 0
    prev_n = 0
    pos = 0
    for t in range(m):
        i = order[t]
        need = count[i] + 3 * prev_n
        if pos + 2 * need > cap:
            while pos + 2 * need > cap:
                cap *= 2
            r2 = np.empty(cap, np.int64)
            d2 = np.empty(cap, np.int32)
            r2[:pos] = rows[:pos]
            d2[:pos] = depth[:pos]
            rows = r2
            depth = d2
        # step rows from the previous layer into scratch space after pos + need
        s0 = pos + need
        ns = 0
        if t > 0:
            ns = _step_rows(
                rows[prev_start:], depth[prev_start:], prev_n, gaps, continues, forward, rows[s0:], depth[s0:]
            )
        c = _merge(ids[i], zero, count[i], rows[s0:], depth[s0:], ns, rows[pos:], depth[pos:])
        starts[i] = pos
        sizes[i] = c
        prev_start = pos
        prev_n = c
        pos += c
    # compact into layer order
    out_r = np.empty(pos, np.int64)
    out_d = np.empty(pos, np.int32)
    p = 0
    for i in range(m):
        offsets[i] = p
        out_r[p : p + sizes[i]] = rows[starts[i] : starts[i] + sizes[i]]
        out_d[p : p + sizes[i]] = depth[starts[i] : starts[i] + sizes[i]]
        p += sizes[i]
    offsets[m] = p
    return out_r, out_d, offsets


@njit(cache=True)
def gap_layers(
    query: np.ndarray,
    ids: np.ndarray,
    dist: np.ndarray,
    count: np.ndarray,
    x: np.ndarray,
    continues: np.ndarray,
    gaps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:  # pragma: no cover - compiled
    """Layers of the gap-tolerant graph: neighbour cells plus the forward and backward bands.

    Parameters
    ----------
    query : float32 (m, d)
    ids : int64 (m, k)
        Neighbour rows per query frame, ascending, first ``count[i]`` valid.
    dist : float32 (m, k)
        Their distances.
    count : int64 (m,)
    x : float32 (n, d)
        The database rows (gap cells' distances are computed from them).
    continues : bool (n,)
    gaps : int
        Band depth in query frames (0: the neighbour cells alone, the paper's graph).

    Returns
    -------
    out_ids : int64 (m, w), out_dist : float32 (m, w), out_count : int64 (m,)
        Rows ascending per layer, padded with -1 / inf.
    gap_cells : int
        Cells whose distance was computed here (not among the neighbours).
    """
    m, k = ids.shape
    d = x.shape[1]
    fr, fd, fo = _band(ids, count, gaps, continues, True)
    br, bd, bo = _band(ids, count, gaps, continues, False)
    w = 1
    for i in range(m):
        w = max(w, (fo[i + 1] - fo[i]) + (bo[i + 1] - bo[i]))
    out_ids = np.full((m, w), -1, np.int64)
    out_dist = np.full((m, w), np.inf, np.float32)
    out_count = np.zeros(m, np.int64)
    scratch = np.empty(w, np.int32)
    gap_cells = 0
    for i in range(m):
        c = _merge(
            fr[fo[i] : fo[i + 1]],
            fd[fo[i] : fo[i + 1]],
            fo[i + 1] - fo[i],
            br[bo[i] : bo[i + 1]],
            bd[bo[i] : bo[i + 1]],
            bo[i + 1] - bo[i],
            out_ids[i],
            scratch,
        )
        out_count[i] = c
        p = 0  # pointer into the neighbour rows (ascending, a subset of the layer)
        for a in range(c):
            h = out_ids[i, a]
            if p < count[i] and ids[i, p] == h:
                out_dist[i, a] = dist[i, p]
                p += 1
            else:
                acc = 0.0
                for j in range(d):
                    t = np.float64(x[h, j]) - np.float64(query[i, j])
                    acc += t * t
                out_dist[i, a] = np.float32(np.sqrt(acc))
                gap_cells += 1
    return out_ids, out_dist, out_count, gap_cells
