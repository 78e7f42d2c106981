"""Naive reference of the voted seed windows (``plugins/similarity/_seed_votes.py``): plain loops."""
from __future__ import annotations

import numpy as np


def naive_voted_windows(frames, ids, dist, continues, m, n, slope, gap, top):
    """Clusters of neighbours agreeing on a start (same run, estimated starts chained within
    ``gap``), scored by the sum over seed frames of the nearest member's distance (else the
    frame's largest returned distance); the windows of the ``top`` best, merged, as [a, b) pairs."""
    run, r = [], -1
    for j in range(n):
        r += 0 if (j > 0 and continues[j]) else 1
        run.append(r)
    pts = []  # (run, estimated start, seed index, row, distance)
    for i in range(len(frames)):
        for h, d in zip(ids[i], dist[i]):
            if h >= 0:
                pts.append((run[h], int(h) - int(frames[i]), i, int(h), float(d)))
    if not pts:
        return []
    order = sorted(range(len(pts)), key=lambda p: (pts[p][0], pts[p][1], p))
    clusters, cur = [], [order[0]]
    for a, b in zip(order, order[1:]):
        if pts[b][0] == pts[a][0] and pts[b][1] - pts[a][1] <= gap:
            cur.append(b)
        else:
            clusters.append(cur)
            cur = [b]
    clusters.append(cur)
    far = [max([float(d) for h, d in zip(ids[i], dist[i]) if h >= 0], default=np.inf) for i in range(len(frames))]
    scores = []
    for c in clusters:
        s = 0.0
        for i in range(len(frames)):
            ds = [pts[p][4] for p in c if pts[p][2] == i]
            s += min(ds) if ds else far[i]
        scores.append(s)
    best = sorted(range(len(clusters)), key=lambda c: (scores[c], c))[:top]
    windows = []
    for c in best:
        for p in clusters[c]:
            f, h = int(frames[pts[p][2]]), pts[p][3]
            windows.append((max(h - int(slope * f) - 2, 0), min(h + int(slope * (m - 1 - f)) + 3, n)))
    windows.sort()
    out = []
    for a, b in windows:
        if out and a <= out[-1][1]:
            out[-1][1] = max(out[-1][1], b)
        else:
            out.append([a, b])
    return out
