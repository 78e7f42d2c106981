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
def block_boxes(
    x: np.ndarray, continues: np.ndarray, size: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
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
def coarse_bounds(
    qt: np.ndarray, lo: np.ndarray, hi: np.ndarray, link: np.ndarray, branges: np.ndarray, shrink: float
) -> np.ndarray:  # pragma: no cover - compiled
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
    through it stays in it): 1.1-1.6x the float64 kernel (docs/global-matching.md, "How the default
    was chosen"). Still admissible: a float32 sum of ``m`` non-negative terms, and ``F + G -
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
    return _coarse(qt, lo, hi, _NO_BOX, _NO_BASIS, _NO_BOX, _NO_BOX, _NO_RAD, link, branges, shrink, False)


@njit(cache=True, fastmath=_FAST)
def subspace_bounds(
    qt: np.ndarray,
    cen: np.ndarray,
    basis: np.ndarray,
    alo: np.ndarray,
    ahi: np.ndarray,
    rad: np.ndarray,
    link: np.ndarray,
    branges: np.ndarray,
    shrink: float,
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`coarse_bounds` with each block's *local subspace cell* in place of its box.

    A block is described by its centre ``c`` (the rows' mean), an orthonormal basis ``U``
    (``p`` principal directions of its rows), the box ``[alo, ahi]`` of its rows'
    coordinates ``U (x_j - c)`` and the radius ``rho`` of their residuals ``||(I - U^T U)(x_j
    - c)||`` (:func:`._subspace_kernels.block_subspaces`). For a query frame with ``r = q -
    c``, the decomposition of ``q - x_j`` into its parts in and orthogonal to the subspace
    gives, for every row of the block,
    ``||q - x_j||^2 >= boxdist(U r, [alo, ahi])^2 + max(0, ||(I - U^T U) r|| - rho)^2``:
    the cell cost. Box cells are the case ``p = 0`` with a box about every axis; along the
    few directions a block of 4-16 rows of motion actually spans, the subspace cell is far
    tighter (docs/global-matching.md: alive rows at 16-row blocks 30-45 %
    against 60 % with boxes on the slow 90-frame queries).

    Float32, admissible by margins: the coordinates widen the box by ``delta = mu (||r|| +
    S)`` (``S`` the block's radius ``max ||x_j - c||``; ``mu = 4 (d + 2p + 4) u``, ``u =
    2^-24``, covers the rounding of ``r`` and of the dot products, and the float32 basis
    being orthonormal only to ``sqrt(p) u``), the residual is ``sqrt(kappa ||r||^2 -
    ||U r||^2)`` (``1 - kappa = 2 (d + 5p + 2) u``: the cancellation, one-sided) less
    ``rho + delta``; ``rho`` and the boxes are rounded outwards when built. Then the costs
    are shrunk as the box costs. Reference: ``naive_subspace_bounds`` in
    ``tests/naive/coarse.py``.

    Parameters
    ----------
    qt : float32 (d, m)
    cen : float32 (nb, d); basis : float32 (nb, 3, d); alo, ahi : float32 (nb, 3)
                              three directions (``p`` <= 3 of them nonzero)
    rad : float32 (nb, 2)     ``rho`` and ``S`` per block
    link, branges, shrink : as :func:`coarse_bounds`
    """
    return _coarse(qt, _NO_BOX, _NO_BOX, cen, basis, alo, ahi, rad, link, branges, shrink, True)


_NO_BOX = np.zeros((0, 0), np.float32)
_NO_BASIS = np.zeros((0, 3, 0), np.float32)
_NO_RAD = np.zeros((0, 2), np.float32)


@njit(cache=True, fastmath=_FAST, inline="always")
def _box_costs(
    qp: np.ndarray, lo: np.ndarray, hi: np.ndarray, b: int, sh: np.float32, out: np.ndarray, acc: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Block ``b``'s box cell costs of every (padded) query frame into ``out``.

    The dimensions are taken five at a time, so that the accumulator is loaded and stored
    once per five (one at a time, ``coarse_bounds`` on the levels' real calls ran 0.87 / 0.97 /
    0.95x as fast for 30 / 64 / 90 query frames: A/B of the two kernels, commit 578a799).
    """
    d, mp = qp.shape
    zero = np.float32(0.0)
    for i in range(mp):
        acc[i] = 0.0
    k = 0
    while k + 5 <= d:
        l0, l1, l2, l3, l4 = lo[b, k], lo[b, k + 1], lo[b, k + 2], lo[b, k + 3], lo[b, k + 4]
        h0, h1, h2, h3, h4 = hi[b, k], hi[b, k + 1], hi[b, k + 2], hi[b, k + 3], hi[b, k + 4]
        for i in range(mp):
            v0 = qp[k, i]
            v1 = qp[k + 1, i]
            v2 = qp[k + 2, i]
            v3 = qp[k + 3, i]
            v4 = qp[k + 4, i]
            e0 = max(l0 - v0, v0 - h0, zero)
            e1 = max(l1 - v1, v1 - h1, zero)
            e2 = max(l2 - v2, v2 - h2, zero)
            e3 = max(l3 - v3, v3 - h3, zero)
            e4 = max(l4 - v4, v4 - h4, zero)
            acc[i] += e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3 + e4 * e4
        k += 5
    while k < d:
        lk = lo[b, k]
        hk = hi[b, k]
        for i in range(mp):
            v = qp[k, i]
            e = max(lk - v, v - hk, zero)
            acc[i] += e * e
        k += 1
    for i in range(mp):
        out[i] = np.sqrt(acc[i]) * sh


@njit(cache=True, fastmath=_FAST, inline="always")
def _subspace_costs(
    qp: np.ndarray,
    cen: np.ndarray,
    basis: np.ndarray,
    alo: np.ndarray,
    ahi: np.ndarray,
    rad: np.ndarray,
    b: int,
    sh: np.float32,
    out: np.ndarray,
    rr: np.ndarray,
    aa: np.ndarray,
    mu: np.float32,
    kappa: np.float32,
) -> None:  # pragma: no cover - compiled
    """Block ``b``'s subspace cell costs of every (padded) query frame into ``out`` (see :func:`subspace_bounds`).

    Vectorised over the query frames, as the box costs; the dimensions are taken five at a
    time so that the four accumulators (``||r||^2`` and three coordinates) are loaded and
    stored once per five dimensions (one dimension at a time: 5.5-5.7 ns a cell against
    4.7-5.3).
    """
    d, mp = qp.shape
    zero = np.float32(0.0)
    a0 = aa[0]
    a1 = aa[1]
    a2 = aa[2]
    for i in range(mp):
        rr[i] = 0.0
        a0[i] = 0.0
        a1[i] = 0.0
        a2[i] = 0.0
    k = 0
    while k + 5 <= d:
        c0, c1, c2, c3, c4 = cen[b, k], cen[b, k + 1], cen[b, k + 2], cen[b, k + 3], cen[b, k + 4]
        u00, u01, u02, u03, u04 = (
            basis[b, 0, k],
            basis[b, 0, k + 1],
            basis[b, 0, k + 2],
            basis[b, 0, k + 3],
            basis[b, 0, k + 4],
        )
        u10, u11, u12, u13, u14 = (
            basis[b, 1, k],
            basis[b, 1, k + 1],
            basis[b, 1, k + 2],
            basis[b, 1, k + 3],
            basis[b, 1, k + 4],
        )
        u20, u21, u22, u23, u24 = (
            basis[b, 2, k],
            basis[b, 2, k + 1],
            basis[b, 2, k + 2],
            basis[b, 2, k + 3],
            basis[b, 2, k + 4],
        )
        for i in range(mp):
            v0 = qp[k, i] - c0
            v1 = qp[k + 1, i] - c1
            v2 = qp[k + 2, i] - c2
            v3 = qp[k + 3, i] - c3
            v4 = qp[k + 4, i] - c4
            rr[i] += v0 * v0 + v1 * v1 + v2 * v2 + v3 * v3 + v4 * v4
            a0[i] += u00 * v0 + u01 * v1 + u02 * v2 + u03 * v3 + u04 * v4
            a1[i] += u10 * v0 + u11 * v1 + u12 * v2 + u13 * v3 + u14 * v4
            a2[i] += u20 * v0 + u21 * v1 + u22 * v2 + u23 * v3 + u24 * v4
        k += 5
    while k < d:
        ck = cen[b, k]
        w0, w1, w2 = basis[b, 0, k], basis[b, 1, k], basis[b, 2, k]
        for i in range(mp):
            v = qp[k, i] - ck
            rr[i] += v * v
            a0[i] += w0 * v
            a1[i] += w1 * v
            a2[i] += w2 * v
        k += 1
    rho = rad[b, 0]
    big_s = rad[b, 1]
    l0, l1, l2 = alo[b, 0], alo[b, 1], alo[b, 2]
    h0, h1, h2 = ahi[b, 0], ahi[b, 1], ahi[b, 2]
    for i in range(mp):
        r2 = rr[i]
        delta = mu * (np.sqrt(r2) + big_s)
        v0 = a0[i]
        v1 = a1[i]
        v2 = a2[i]
        e0 = max(max(l0 - v0, v0 - h0) - delta, zero)
        e1 = max(max(l1 - v1, v1 - h1) - delta, zero)
        e2 = max(max(l2 - v2, v2 - h2) - delta, zero)
        res = np.sqrt(max(r2 * kappa - v0 * v0 - v1 * v1 - v2 * v2, zero))
        e = max(res - rho - delta, zero)
        out[i] = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2 + e * e) * sh


@njit(cache=True, fastmath=_FAST, inline="always")
def _through(f: np.ndarray, g: np.ndarray, c: np.ndarray, b: int, m: int) -> np.float32:  # pragma: no cover - compiled
    """``min_i F(i, b) + G(i, b) - c(i, b)``: block ``b``'s bound from its two chains."""
    low: np.float32 = np.float32(np.inf)
    for i in range(m):
        low = min(low, f[b, i] + g[b, i] - c[b, i])
    return low


@njit(cache=True, fastmath=_FAST)
def _coarse(
    qt: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    cen: np.ndarray,
    basis: np.ndarray,
    alo: np.ndarray,
    ahi: np.ndarray,
    rad: np.ndarray,
    link: np.ndarray,
    branges: np.ndarray,
    shrink: float,
    sub: bool,
) -> np.ndarray:  # pragma: no cover - compiled
    """The bound of :func:`coarse_bounds` (``sub`` false: box cells) or :func:`subspace_bounds`."""
    d, m = qt.shape
    mp = -(-m // 16) * 16  # query frames padded to whole vectors: no scalar remainder loops
    qp = np.empty((d, mp), np.float32)
    for k in range(d):
        for i in range(mp):
            qp[k, i] = qt[k, min(i, m - 1)]
    nb = link.shape[0]
    inf = np.inf
    lb = np.full(nb, inf)
    acc = np.empty(mp, np.float32)
    tf = np.empty(mp, np.float32)
    tg = np.empty(mp, np.float32)
    p = 3  # the subspace cells' basis: three directions (fewer: zero rows)
    aa = np.empty((p, mp), np.float32)  # the subspace costs' scratch: the frames' coordinates in the basis
    u = 2.0**-24
    mu = np.float32(4.0 * (d + 2 * p + 4) * u)  # the subspace margins (subspace_bounds docstring)
    kappa = np.float32(1.0 - 2.0 * (d + 5 * p + 2) * u)
    inf32 = np.float32(np.inf)
    sh = np.float32(shrink * (1.0 - 4.0 * m * 2.0**-24))  # float32 rounding margin (docstring)
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
                if sub:
                    _subspace_costs(qp, cen, basis, alo, ahi, rad, b, sh, c[bb], acc, aa, mu, kappa)
                    continue
                _box_costs(qp, lo, hi, b, sh, c[bb], acc)
            if nr == 1:  # an isolated block: every path stays in it, F + G - c is the row sum
                low = np.float32(0.0)
                for i in range(m):
                    low += c[0, i]
                lb[b0] = low
                b0 += 1
                continue
            # forward F over blocks 0, 1, .. and backward G over blocks nr-1, nr-2, .. two blocks
            # a step each: four serial chains along the query in flight (the second block's
            # chain takes the first's values as they come, so it trails it by a frame: the
            # out-of-order core overlaps them); one block a step, two chains, the chains' latency
            # was a third of a box cell's time
            for step in range(0, nr, 2):
                bf = step
                bg = nr - 1 - step
                pair = step + 1 < nr
                if bf > 0:  # inside a linked stretch every block continues the one before
                    tf[0] = inf32
                    for i in range(1, m):  # diagonal and vertical: no dependency along i
                        tf[i] = min(f[bf - 1, i - 1], f[bf - 1, i])
                else:
                    for i in range(m):
                        tf[i] = inf32
                if bg + 1 < nr:
                    for i in range(m - 1):
                        tg[i] = min(g[bg + 1, i + 1], g[bg + 1, i])
                else:
                    for i in range(m - 1):
                        tg[i] = inf32
                vf = c[bf, 0]
                f[bf, 0] = vf
                vg = c[bg, m - 1]  # a free end: going on vertically only adds cost
                g[bg, m - 1] = vg
                if pair:
                    bf2 = bf + 1
                    bg2 = bg - 1
                    wf = c[bf2, 0]
                    f[bf2, 0] = wf
                    wg = c[bg2, m - 1]
                    g[bg2, m - 1] = wg
                    pf = vf
                    pg = vg
                    for i in range(1, m):  # horizontal: the serial chains
                        vf = min(vf, tf[i]) + c[bf, i]
                        f[bf, i] = vf
                        wf = min(wf, min(pf, vf)) + c[bf2, i]
                        f[bf2, i] = wf
                        pf = vf
                        j = m - 1 - i
                        vg = min(vg, tg[j]) + c[bg, j]
                        g[bg, j] = vg
                        wg = min(wg, min(pg, vg)) + c[bg2, j]
                        g[bg2, j] = wg
                        pg = vg
                    top = bf2
                    bottom = bg2
                else:
                    for i in range(1, m):
                        vf = min(vf, tf[i]) + c[bf, i]
                        f[bf, i] = vf
                        j = m - 1 - i
                        vg = min(vg, tg[j]) + c[bg, j]
                        g[bg, j] = vg
                    top = bf
                    bottom = bg
                # a block's bound as soon as both its chains are in (the buffers are still in L1):
                # F is in for blocks <= top, G for blocks >= bottom; only this step's blocks are new
                for bb in range(max(bf, bottom), top + 1):  # this step's F blocks whose G is in
                    lb[b0 + bb] = _through(f, g, c, bb, m)
                for bb in range(bottom, min(bg, bf - 1) + 1):  # its G blocks whose F was in before
                    lb[b0 + bb] = _through(f, g, c, bb, m)
            b0 += nr
    return lb


@njit(cache=True)
def alive_runs(
    lb: np.ndarray, branges: np.ndarray, scale: float, tau: float
) -> np.ndarray:  # pragma: no cover - compiled
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
    runs: np.ndarray = out[:k].copy()
    return runs
