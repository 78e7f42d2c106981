"""Seed windows ranked by votes: the certified search's threshold from a few DP windows.

:func:`.exact._seed_tau` runs the fine DP around every neighbour of its seed frames (5 frames
x 60 neighbours, windows of about ``4 m`` rows); at 1 M rows those windows rarely merge and
their DP was a fifth of a 90-frame query's time (docs/global-matching.md, "certified
ceiling"). A match through row ``h`` at query frame ``i`` starts near ``h - i``; neighbours of
different seed frames that agree on the start (same run of rows, starts within ``gap`` rows
of each other, chained) vote for one alignment. Each cluster is scored by the sum over the
seed frames of its nearest member's distance to that frame, a frame without a member
counting its ``k``-th neighbour distance (no row outside the frame's exact neighbours is closer);
the DP then runs over the windows of the ``top`` lowest scores first. Any threshold is safe
(the certified pass verifies it): ranking only decides which windows are tried first.
"""
from __future__ import annotations

import numpy as np


def voted_windows(frames, ids, dist, run_of, m, n, slope, gap, top):
    """Windows around the neighbours of the ``top`` best-scored seed clusters (merge them with
    :func:`.exact.merged_ranges`).

    Parameters
    ----------
    frames : int64 (s,)       the seed query frames
    ids : int64 (s, k)        their neighbours' rows (-1: none)
    dist : float (s, k)       the neighbours' distances (ascending per frame)
    run_of : int64 (n,)       run number of every row (rows that continue each other share one)
    m, n : int                query frames, database rows
    slope : float             database rows per query frame a window allows on either side
    gap : int                 cluster members' estimated starts chain within this many rows
    top : int                 clusters kept

    Returns
    -------
    lo, hi : int64 (p,)       window ``[lo, hi)`` of every neighbour in a kept cluster
    """
    s, k = ids.shape
    fi = np.broadcast_to(np.arange(s)[:, None], ids.shape)
    ok = ids >= 0
    h, fi, dd = ids[ok].astype(np.int64), fi[ok], np.asarray(dist, np.float64)[ok]
    if not len(h):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    f = frames[fi]
    est = h - f  # the alignment's start if it were diagonal
    run = run_of[h]
    o = np.lexsort((est, run))
    h, fi, dd, f, est, run = h[o], fi[o], dd[o], f[o], est[o], run[o]
    new = np.r_[True, (run[1:] != run[:-1]) | (est[1:] - est[:-1] > gap)]
    cl = np.cumsum(new) - 1
    nc = int(cl[-1]) + 1
    # per (cluster, seed frame) the nearest member's distance, else the frame's k-th distance
    far = np.full(s, np.inf)
    for i in range(s):
        row = np.asarray(dist[i], np.float64)[ids[i] >= 0]
        far[i] = row.max() if len(row) else np.inf
    best = np.broadcast_to(far, (nc, s)).copy()
    np.minimum.at(best, (cl, fi), dd)
    score = best.sum(axis=1)
    keep = np.argsort(score, kind="stable")[:top]
    sel = np.isin(cl, keep)
    lo = np.maximum(h[sel] - (slope * f[sel]).astype(np.int64) - 2, 0)
    hi = np.minimum(h[sel] + (slope * (m - 1 - f[sel])).astype(np.int64) + 3, n)
    return lo, hi
