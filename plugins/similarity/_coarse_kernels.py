"""Numba kernels of the certified-exact search: a coarse DP over row blocks bounds the fine one.

Rows are cut into *blocks*: at most ``B`` consecutive rows of one run (``continues``), each
with the bounding box of its feature vectors. The distance of a query frame to a block's
box is at most its distance to any row of the block, so subsequence DTW on blocks (same
steps; block ``b`` follows ``b - 1`` when its first row continues ``b - 1``'s last) with
box distances as cell costs is a lower bound: a fine path projected onto blocks, cells of
one (query frame, block) merged, is a coarse path of no larger cost. With ``F`` the coarse
forward DP (paths from a free start) and ``G`` the backward one (paths to a free end),
every fine path through a cell of block ``b`` at query frame ``i`` costs at least
``F(i, b) + G(i, b) - c(i, b)``; blocks where that exceeds ``tau`` for every ``i`` hold no
cell of any path of cost <= ``tau``. The search uses :func:`coarse_bounds` (the bound per
block over block ranges, for a hierarchy of levels) and then the fine DP over the remaining
blocks only, :func:`._dtw_kernels.sdtw_ranges_compact` (the columns of
:func:`._dtw_kernels.sdtw_forward`). References written from the definitions (full
matrices, brute-force boxes): ``tests/naive/coarse.py``; proof in ``docs/global-matching.md``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ._dtw_kernels import _FAST  # the fine DP's fastmath flags: the same float32 box arithmetic


@njit(cache=True)
def block_boxes(x, continues, size):  # pragma: no cover - compiled
    """Blocks of at most ``size`` consecutive rows within runs, and their boxes.

    Returns
    -------
    bstart : int64 (nb + 1,)   block ``b`` is rows ``bstart[b] .. bstart[b+1] - 1``
    lo, hi : float32 (nb, d)   per-dimension minimum and maximum of its rows
    link : bool (nb,)          block ``b`` continues block ``b - 1`` (same run)
    """
    n, d = x.shape
    nb = 0
    run = 0
    for j in range(n):
        if j == 0 or not continues[j] or run == size:
            nb += 1
            run = 0
        run += 1
    bstart = np.empty(nb + 1, np.int64)
    link = np.zeros(nb, np.bool_)
    b = -1
    run = 0
    for j in range(n):
        if j == 0 or not continues[j] or run == size:
            b += 1
            bstart[b] = j
            link[b] = j > 0 and continues[j]
            run = 0
        run += 1
    bstart[nb] = n
    lo = np.empty((nb, d), np.float32)
    hi = np.empty((nb, d), np.float32)
    for b in range(nb):
        for k in range(d):
            a = x[bstart[b], k]
            z = a
            for j in range(bstart[b] + 1, bstart[b + 1]):
                v = x[j, k]
                a = min(a, v)
                z = max(z, v)
            lo[b, k] = a
            hi[b, k] = z
    return bstart, lo, hi, link


@njit(cache=True, fastmath=_FAST)
def coarse_bounds(qt, lo, hi, link, branges, shrink):  # pragma: no cover - compiled
    """Lower bound ``min_i F(i, b) + G(i, b) - c(i, b)`` of every path through block ``b``.

    Over the block ranges ``[a, b)`` of ``branges`` only, each started afresh (its first
    block is taken as unlinked: no path of cost <= ``tau`` enters it from a block ruled out
    at a coarser level); the bound itself is returned (so blocks can be ranked, and tested
    against any ``tau``). Reference: ``naive_coarse_bounds`` in ``tests/naive/coarse.py``
    (float64, cell by cell). Same recursion as the fine DP; each column
    update is split, as in ``sdtw_forward``, into a vectorisable min over the previous
    block and the serial chain along the query.

    Float32 throughout (box distances, chains, bound), the box distances over the query
    padded to whole 16-lane vectors, an isolated block's bound as its row sum (every path
    through it stays in it): 1.1-1.6x the float64 kernel (docs/global-matching.md, "Issue 13,
    fourth round"). Still admissible: a float32 sum of ``m`` non-negative terms, and ``F + G -
    c`` (>= max(F, G)), exceed their exact values by at most ``(2m + 3) u`` relative (``u`` =
    2^-24), so the box distances are shrunk by a further ``1 - 4 m u`` on top of ``shrink``.

    Parameters
    ----------
    qt : float32 (d, m)
    lo, hi, link : from :func:`block_boxes`
    branges : int64 (r, 2)   block index ranges, ascending and disjoint
    shrink : float           box distances are multiplied by it (just below 1: a margin for float rounding)

    Returns
    -------
    lb : float64 (nb,)       inf for blocks outside every range
    """
    d, m = qt.shape
    mp = -(-m // 16) * 16  # query frames padded to whole vectors: no scalar remainder loops
    qp = np.empty((d, mp), np.float32)
    for k in range(d):
        for i in range(mp):
            qp[k, i] = qt[k, min(i, m - 1)]
    nb = lo.shape[0]
    inf = np.inf
    lb = np.full(nb, inf)
    acc = np.empty(mp, np.float32)
    tf = np.empty(mp, np.float32)
    tg = np.empty(mp, np.float32)
    inf32 = np.float32(np.inf)
    sh = np.float32(shrink * (1.0 - 4.0 * m * 2.0 ** -24))  # float32 rounding margin (docstring)
    # the chains never cross a block that does not continue the one before: each range runs as
    # its linked stretches (clips, at most), in buffers sized for the longest, which stay in
    # cache (one buffer per range cost 2-3x the time at 380 k rows: page faults, cache misses)
    big = 0
    for r in range(branges.shape[0]):
        s0 = branges[r, 0]
        for bb in range(s0 + 1, branges[r, 1]):
            if not link[bb]:
                big = max(big, bb - s0)
                s0 = bb
        big = max(big, branges[r, 1] - s0)
    c = np.empty((big, mp), np.float32)
    f = np.empty((big, mp), np.float32)
    g = np.empty((big, mp), np.float32)
    for r in range(branges.shape[0]):
        b0 = branges[r, 0]
        while b0 < branges[r, 1]:
            nr = 1
            while b0 + nr < branges[r, 1] and link[b0 + nr]:
                nr += 1
            for bb in range(nr):
                b = b0 + bb
                for i in range(mp):
                    acc[i] = 0.0
                for k in range(d):
                    lk = lo[b, k]
                    hk = hi[b, k]
                    for i in range(mp):
                        v = qp[k, i]
                        e = max(lk - v, v - hk, np.float32(0.0))
                        acc[i] += e * e
                for i in range(mp):
                    c[bb, i] = np.sqrt(acc[i]) * sh
            if nr == 1:  # an isolated block: every path stays in it, F + G - c is the row sum
                low = np.float32(0.0)
                for i in range(m):
                    low += c[0, i]
                lb[b0] = low
                b0 += 1
                continue
            # forward F over blocks 0, 1, .. and backward G over blocks nr-1, nr-2, .. in one
            # loop: two independent serial chains along the query run side by side
            for step in range(nr):
                bf = step
                bg = nr - 1 - step
                if bf > 0 and link[b0 + bf]:
                    tf[0] = inf32
                    for i in range(1, m):  # diagonal and vertical: no dependency along i
                        tf[i] = min(f[bf - 1, i - 1], f[bf - 1, i])
                else:
                    for i in range(m):
                        tf[i] = inf32
                if bg + 1 < nr and link[b0 + bg + 1]:
                    for i in range(m - 1):
                        tg[i] = min(g[bg + 1, i + 1], g[bg + 1, i])
                else:
                    for i in range(m - 1):
                        tg[i] = inf32
                vf = c[bf, 0]
                f[bf, 0] = vf
                vg = c[bg, m - 1]  # a free end: going on vertically only adds cost
                g[bg, m - 1] = vg
                for i in range(1, m):  # horizontal: the serial chains
                    vf = min(vf, tf[i]) + c[bf, i]
                    f[bf, i] = vf
                    j = m - 1 - i
                    vg = min(vg, tg[j]) + c[bg, j]
                    g[bg, j] = vg
                # a block's bound as soon as both its chains are in (the buffers are still in L1)
                if bf >= bg:
                    low = inf32
                    for i in range(m):
                        low = min(low, f[bf, i] + g[bf, i] - c[bf, i])
                    lb[b0 + bf] = low
                if bg < bf:
                    low = inf32
                    for i in range(m):
                        low = min(low, f[bg, i] + g[bg, i] - c[bg, i])
                    lb[b0 + bg] = low
            b0 += nr
    return lb


@njit(cache=True)
def alive_runs(lb, branges, scale, tau):  # pragma: no cover - compiled
    """Maximal runs ``[a, b)`` (int64 (r, 2)) of blocks with ``lb * scale <= tau``, inside ``branges``.

    What ``exact.block_ranges(lb * scale <= tau)`` returns when ``lb`` is inf outside the
    ranges (as :func:`coarse_bounds` leaves it), scanning only the ranges: no (nb,) temporaries
    (at 1 M rows the 4-row level has 262 k blocks, of which a query evaluates a few thousand).
    Runs of adjacent ranges that touch are merged, so every run is maximal (the next level
    starts each run afresh: a path may not cross a run's ends). Reference: ``block_ranges``.
    """
    cap = 1
    for r in range(branges.shape[0]):
        cap += (branges[r, 1] - branges[r, 0] + 1) // 2
    out = np.empty((cap, 2), np.int64)
    k = 0
    for r in range(branges.shape[0]):
        j = branges[r, 0]
        z = branges[r, 1]
        while j < z:
            if lb[j] * scale <= tau:
                a = j
                while j < z and lb[j] * scale <= tau:
                    j += 1
                if k > 0 and out[k - 1, 1] == a:
                    out[k - 1, 1] = j
                else:
                    out[k, 0] = a
                    out[k, 1] = j
                    k += 1
            else:
                j += 1
    return out[:k].copy()
