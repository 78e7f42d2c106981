"""Slow, obviously correct references for fat-graph base poses (Krüger 2010 §5.3).

``all_pairs_neighbours`` is also the quadratic all-pairs construction the benchmark
compares the kd-tree search with (Shin & Oh 2006 compute a dense distance matrix).
"""

from __future__ import annotations

import numpy as np


def all_pairs_neighbours(x: np.ndarray, radius: float, k: int, block: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``k`` nearest frames within ``radius`` of every frame, from all pairwise distances.

    Ties in distance go to the smaller frame id. Returns ``(dist (n,k) float32, ids (n,k)
    int64)`` padded with inf / -1, like an Index query.
    """
    x = np.asarray(x, np.float64)
    n = len(x)
    dist = np.full((n, k), np.inf, np.float32)
    ids = np.full((n, k), -1, np.int64)
    sq = (x * x).sum(1)
    for s in range(0, n, block):
        d2 = sq[s : s + block, None] + sq[None, :] - 2.0 * x[s : s + block] @ x.T
        d = np.sqrt(np.maximum(d2, 0.0))
        order = np.argsort(d, axis=1, kind="stable")[:, :k]
        dd = np.take_along_axis(d, order, 1)
        ok = dd <= radius
        dist[s : s + block][ok] = dd[ok]
        ids[s : s + block][ok] = order[ok]
    return dist, ids


def greedy_cover(ids: np.ndarray, max_base_poses: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Recount every neighbourhood from scratch after each base pose.

    ``N(f)`` is ``{f}`` plus the valid ids of row ``f``; the next base pose is the uncovered
    frame whose neighbourhood holds the most uncovered frames (smallest id on ties); it
    covers its whole neighbourhood.
    """
    ids = np.asarray(ids)
    n = len(ids)
    hoods = [sorted({f} | {int(g) for g in ids[f] if g >= 0}) for f in range(n)]
    degree = np.array([len(h) for h in hoods], np.int64)
    covered = np.zeros(n, bool)
    cluster = np.full(n, -1, np.int64)
    bases: list[int] = []
    while not covered.all() and (max_base_poses <= 0 or len(bases) < max_base_poses):
        best, best_count = -1, -1
        for f in range(n):
            if covered[f]:
                continue
            c = sum(1 for g in hoods[f] if not covered[g])
            if c > best_count:
                best, best_count = f, c
        for g in hoods[best]:
            if not covered[g]:
                covered[g] = True
                cluster[g] = len(bases)
        bases.append(best)
    return np.array(bases, np.int64), cluster, degree


def clip_transitions(cluster: np.ndarray, offsets: np.ndarray) -> list[tuple[int, int, int, int]]:
    """``(clip position, frame, from, to)`` wherever the cluster changes inside a clip,
    skipping uncovered frames (-1)."""
    out = []
    for c in range(len(offsets) - 1):
        prev = -1
        for f in range(offsets[c], offsets[c + 1]):
            cur = int(cluster[f])
            if cur < 0:
                continue
            if prev >= 0 and cur != prev:
                out.append((c, int(f - offsets[c]), prev, cur))
            prev = cur
    return out
