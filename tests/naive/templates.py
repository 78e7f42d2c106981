"""Slow, obviously correct references for ``plugins/relational/_template_kernels.py`` and ``_hit_kernels.py``.

Full matrices straight from the recurrences (motion templates, Müller & Röder 2006).
"""

from __future__ import annotations

import numpy as np


def dtw_path(a, b):
    """Global DTW, local cost mean |a_i - b_j| over features; steps (1,0), (0,1), (1,1)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n, m = len(a), len(b)
    c = np.abs(a[:, None, :] - b[None, :, :]).mean(axis=2)
    acc = np.full((n + 1, m + 1), np.inf)
    acc[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            acc[i, j] = c[i - 1, j - 1] + min(acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1])
    # backtrack, preferring diagonal, then vertical, then horizontal
    i, j, path = n, m, [(n - 1, m - 1)]
    while (i, j) != (1, 1):
        options = [(acc[i - 1, j - 1], (i - 1, j - 1)), (acc[i - 1, j], (i - 1, j)), (acc[i, j - 1], (i, j - 1))]
        _, (i, j) = min(options, key=lambda o: o[0])
        path.append((i - 1, j - 1))
    return acc[n, m], np.array(path[::-1])


def local_cost(template, bits, weights=None):
    """c[k, j] = mean over the cared-for features of row k of |template - bit| (0 if none);
    with ``weights`` (K, 31) the weighted mean.

    ``template`` (K, 31) in {0, 0.5, 1}, 0.5 meaning don't care; ``bits`` (N, 31) 0/1.
    """
    t = np.asarray(template, float)
    care = t != 0.5
    w = np.ones(t.shape) if weights is None else np.asarray(weights, float)
    out = np.zeros((len(t), len(bits)))
    for k in range(len(t)):
        for j in range(len(bits)):
            total = sum(w[k, f] for f in range(t.shape[1]) if care[k, f])
            if total > 0:
                out[k, j] = (
                    sum(w[k, f] * abs(t[k, f] - float(bits[j][f])) for f in range(t.shape[1]) if care[k, f]) / total
                )
    return out


def subsequence_dtw(c, clip_of):
    """Subsequence DTW with steps (1,1) w1, (2,1) w2, (1,2) w1 on the local cost ``c (K, N)``.

    A virtual row -1 of zeros lets a path start at any column (template frame 0, or frame
    1 by a (2,1) step); paths stay inside one clip (``clip_of`` (N,)). Returns per column
    ``D[K-1, j] / K`` and the first column of the path.
    """
    K, N = c.shape
    D = np.full((K, N), np.inf)
    S = np.full((K, N), -1)
    for j in range(N):
        for k in range(K):
            if k == 0:  # a fresh start at template frame 0
                D[k, j], S[k, j] = c[k, j], j
                continue
            options = []  # in tie order: (1,1), (2,1), (1,2)
            for dk, dj, w in ((1, 1, 1.0), (2, 1, 2.0), (1, 2, 1.0)):
                pk, pj = k - dk, j - dj
                if pk == -1 and dj == 1:  # from the virtual zero row: start at template frame 1
                    options.append((w * c[k, j], j))
                elif pk >= 0 and pj >= 0 and clip_of[pj] == clip_of[j]:
                    options.append((D[pk, pj] + w * c[k, j], S[pk, pj]))
            if options:
                best = min(options, key=lambda o: o[0])  # min keeps the first of equals
                if np.isfinite(best[0]):
                    D[k, j], S[k, j] = best
    return D[K - 1] / K, S[K - 1]


def template_hits(cost, start, threshold, min_gap=0.5, ranges=None):
    """Local minima with cost <= threshold, cheapest first, greedy overlap suppression.

    With ``ranges`` ((R, 2) frame ranges) minima are taken inside each range, the frames
    beyond its ends counting as inf."""
    c = np.asarray(cost, float)
    ranges = [(0, len(c))] if ranges is None else [tuple(r) for r in ranges]
    cand = [
        j
        for lo, hi in ranges
        for j in range(lo, hi)
        if c[j] <= threshold and (j == lo or c[j - 1] >= c[j]) and (j + 1 == hi or c[j + 1] > c[j])
    ]
    cand.sort(key=lambda j: c[j])  # stable: equal costs keep frame order
    acc = []
    for j in cand:
        s, e = int(start[j]), j + 1
        if all(min(e, e2) - max(s, s2) <= min_gap * min(e - s, e2 - s2) for s2, e2, _ in acc):
            acc.append((s, e, c[j]))
    return (
        np.array([a[0] for a in acc], np.int64),
        np.array([a[1] for a in acc], np.int64),
        np.array([a[2] for a in acc], float),
    )
