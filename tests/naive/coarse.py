"""Naive references of the certified search's kernels (:mod:`mocapflow.plugins.similarity.search._coarse_kernels`).

Written from the definitions, not from the kernels: full matrices in float64, the
textbook recurrences cell by cell, blocks and boxes found by brute force. They share no
code and no arithmetic with the kernels (which use float32 distances, fastmath and
column buffers), so the tests compare costs with a tolerance, and starts and lengths
exactly where no float rounding can change a decision (ties on integer-valued data, where
every sum is exact in both, or random data).

- :func:`naive_coarse_bounds`: the coarse lower bound ``min_i F(i, b) + G(i, b) - c(i, b)``
  of every block (``coarse_bounds``);
- :func:`naive_subspace_bounds`: the same bound with local subspace cells (``subspace_bounds``),
  the subspaces by pivoted Gram-Schmidt and orthogonal iteration (:func:`naive_subspaces`), and :func:`naive_min_cells`, the tightest
  cell costs there are (each query frame's distance to the block's nearest row);
- :func:`naive_sdtw_ranges`: subsequence DTW restricted to row ranges, each started afresh
  (``sdtw_ranges_compact``), by running the full-matrix DP of :mod:`naive.dtw` on each
  range's rows alone.
"""

from __future__ import annotations

import numpy as np

from naive.dtw import naive_blocks, naive_path, naive_subsequence_dtw


def naive_boxes(x, continues, size):
    """Blocks and their bounding boxes, by brute force.

    Returns
    -------
    block : int (n,)          block of every row (:func:`naive.dtw.naive_blocks`)
    lo, hi : float64 (nb, d)  minimum and maximum over the block's rows, per dimension
    link : bool (nb,)         the block's first row continues the previous block's last row
    """
    x = np.asarray(x, np.float64)
    block = naive_blocks(continues, size)
    nb = int(block.max()) + 1
    lo = np.array([x[block == b].min(axis=0) for b in range(nb)])
    hi = np.array([x[block == b].max(axis=0) for b in range(nb)])
    first = [int(np.flatnonzero(block == b)[0]) for b in range(nb)]
    link = np.array([j > 0 and bool(continues[j]) for j in first])
    return block, lo, hi, link


def naive_box_distance(q, lo, hi):
    """Euclidean distance of every query frame to every box, ``(m, nb)``: to the box's nearest point."""
    q = np.asarray(q, np.float64)
    nearest = np.clip(q[:, None, :], lo[None, :, :], hi[None, :, :])  # the box's point closest to q[i]
    return np.sqrt(((q[:, None, :] - nearest) ** 2).sum(axis=2))


def naive_coarse_bounds(q, x, continues, size, branges=None, shrink=1.0):
    """Coarse lower bound of the best path through each block, from the definition.

    Subsequence DTW on the (query frame, block) grid with box distances as cell costs:
    ``F`` the forward DP (free start in query frame 0), ``G`` the backward one (free end in
    the last query frame), block ``b`` following ``b - 1`` only when linked and in the same
    range (a range's first block starts afresh). The bound of block ``b`` is
    ``min_i F(i, b) + G(i, b) - c(i, b)``.

    Parameters
    ----------
    q : (m, d) query; x : (n, d) database rows; continues : bool (n,)
    size : int                 rows per block at most
    branges : (r, 2) or None   block ranges ``[a, b)``; None: all blocks, one range
    shrink : float             box distances are multiplied by it

    Returns
    -------
    lb : float64 (nb,)   inf for blocks outside every range
    """
    _, lo, hi, link = naive_boxes(x, continues, size)
    return naive_block_dp(naive_box_distance(q, lo, hi) * shrink, link, branges)


def naive_block_dp(c, link, branges=None):
    """``min_i F(i, b) + G(i, b) - c(i, b)`` per block for cell costs ``c`` (m, nb) (:func:`naive_coarse_bounds`)."""
    m, nb = c.shape
    if branges is None:
        branges = [(0, nb)]
    lb = np.full(nb, np.inf)
    for a, z in branges:
        F = np.full((m, z - a), np.inf)
        G = np.full((m, z - a), np.inf)
        for bb in range(z - a):  # forward, block by block
            after = bb > 0 and link[a + bb]
            for i in range(m):
                options = [0.0] if i == 0 else [F[i - 1, bb]]  # free start / horizontal
                if after and i > 0:
                    options += [F[i - 1, bb - 1], F[i, bb - 1]]  # diagonal, vertical
                F[i, bb] = min(options) + c[i, a + bb]
        for bb in range(z - a - 1, -1, -1):  # backward
            before = bb + 1 < z - a and link[a + bb + 1]
            for i in range(m - 1, -1, -1):
                options = [0.0] if i == m - 1 else [G[i + 1, bb]]  # free end / horizontal
                if before and i < m - 1:
                    options += [G[i + 1, bb + 1], G[i, bb + 1]]
                G[i, bb] = min(options) + c[i, a + bb]
        for bb in range(z - a):
            lb[a + bb] = min(F[i, bb] + G[i, bb] - c[i, a + bb] for i in range(m))
    return lb


def naive_subspaces(x, continues, size, p, iterations=4):
    """Per block: mean ``c``; a basis ``U`` of at most ``p`` directions, from pivoted Gram-Schmidt
    (the centred row of largest residual, normalised, then every residual projected off it)
    followed by ``iterations`` orthogonal iterations ``U <- orth((U S^T) S)`` (``numpy.linalg.qr``);
    the box of the rows' coordinates ``U (x_j - c)``; the largest residual norm
    ``||(I - U^T U)(x_j - c)||``. Float64."""
    x = np.asarray(x, np.float64)
    block = naive_blocks(continues, size)
    out = []
    for b in range(int(block.max()) + 1):
        rows = x[block == b]
        c = rows.mean(axis=0)
        s = rows - c
        res, u = s.copy(), []
        for _ in range(p):
            norms = (res**2).sum(axis=1)
            if norms.max() <= 1e-24:
                break
            v = res[norms.argmax()] / np.sqrt(norms.max())
            u.append(v)
            res = res - np.outer(res @ v, v)
        u = np.array(u).reshape(-1, x.shape[1])
        for _ in range(iterations if len(u) else 0):
            u = np.linalg.qr(((s @ u.T).T @ s).T)[0].T
        a = s @ u.T
        res = s - a @ u
        out.append((c, u, a.min(axis=0), a.max(axis=0), np.sqrt((res**2).sum(axis=1)).max()))
    return out


def naive_subspace_cells(q, subspaces):
    """Cell costs (m, nb): ``sqrt(boxdist(U r)^2 + max(0, ||(I - U^T U) r|| - rho)^2)``, ``r = q - c``."""
    q = np.asarray(q, np.float64)
    cells = np.empty((len(q), len(subspaces)))
    for b, (c, u, alo, ahi, rho) in enumerate(subspaces):
        r = q - c
        a = r @ u.T
        box = np.clip(a, alo, ahi) - a
        res = np.sqrt(((r - a @ u) ** 2).sum(axis=1))
        cells[:, b] = np.sqrt((box**2).sum(axis=1) + np.maximum(res - rho, 0.0) ** 2)
    return cells


def naive_subspace_bounds(q, x, continues, size, p, branges=None, shrink=1.0):
    """:func:`naive_coarse_bounds` with the subspace cells of :func:`naive_subspaces`."""
    _, _, _, link = naive_boxes(x, continues, size)
    return naive_block_dp(naive_subspace_cells(q, naive_subspaces(x, continues, size, p)) * shrink, link, branges)


def naive_min_cells(q, x, continues, size):
    """The tightest admissible cell costs (m, nb): each query frame's distance to the block's nearest row."""
    block = naive_blocks(continues, size)
    d = np.sqrt(((np.asarray(q, np.float64)[:, None] - np.asarray(x, np.float64)[None]) ** 2).sum(axis=2))
    return np.stack([d[:, block == b].min(axis=1) for b in range(int(block.max()) + 1)], axis=1)


def naive_sdtw_ranges(q, x, continues, ranges):
    """Subsequence DTW over the row ranges ``[a, b)`` only, each started afresh.

    Every range is cut out and searched on its own with the full-matrix DP
    :func:`naive.dtw.naive_subsequence_dtw` (its first row made a clip start), so no path
    enters a range from before it.

    Returns
    -------
    rows : int (p,)   the rows of the ranges, in order
    cost : float64 (p,), start : int (p,), length : int (p,)
        best path ending in each row: its cost, first row (database index), cells
    """
    rows, cost, start, length = [], [], [], []
    m = len(q)
    for a, z in ranges:
        cont = np.array(continues[a:z], bool)
        cont[0] = False
        D, S, P = naive_subsequence_dtw(q, x[a:z], cont)
        for j in range(z - a):
            rows.append(a + j)
            cost.append(D[m - 1, j])
            start.append(a + S[m - 1, j])
            length.append(len(naive_path(P, m - 1, j)))
    return np.array(rows), np.array(cost), np.array(start), np.array(length)


def naive_alive_runs(lb, scale, tau):
    """Maximal runs ``[a, b)`` of consecutive blocks with ``lb * scale <= tau``, one block at a time
    (``_coarse_kernels.alive_runs``, which scans only the evaluated ranges, outside of which ``lb`` is inf)."""
    runs = []
    for b, v in enumerate(lb):
        if v * scale <= tau:
            if runs and runs[-1][1] == b:
                runs[-1][1] = b + 1
            else:
                runs.append([b, b + 1])
    return np.array(runs, dtype=np.int64).reshape(-1, 2)
