"""Naive references of the global matchers (``plugins/matchers``): full matrices, explicit graphs.

Both follow Krüger 2010 §4.1 literally. Database rows ``j-1 -> j`` are linked only when
``continues[j]`` (same clip, consecutive frames).
"""

from __future__ import annotations

import heapq

import numpy as np


def continues_of(clip_id, frame) -> np.ndarray:
    clip_id, frame = np.asarray(clip_id), np.asarray(frame)
    c = np.zeros(len(clip_id), bool)
    for j in range(1, len(clip_id)):
        c[j] = clip_id[j] == clip_id[j - 1] and frame[j] == frame[j - 1] + 1
    return c


def naive_subsequence_dtw(q, x, continues):
    """Full (m, n) matrices of subsequence DTW.

    Returns ``(D, start, steps)``: accumulated cost, first row of the best path into each
    cell, and per cell the predecessor cell (or None for a fresh start in row 0).
    """
    q = np.asarray(q, np.float64)
    x = np.asarray(x, np.float64)
    m, n = len(q), len(x)
    D = np.full((m, n), np.inf)
    S = np.full((m, n), -1)
    P = [[None] * n for _ in range(m)]
    for j in range(n):
        for i in range(m):
            c = float(np.sqrt(np.sum((q[i] - x[j]) ** 2)))
            if i == 0:
                D[i, j], S[i, j] = c, j
                continue
            options = []  # in tie order: diagonal, vertical, horizontal
            if j > 0 and continues[j]:
                options.append((D[i - 1, j - 1], (i - 1, j - 1)))
                options.append((D[i, j - 1], (i, j - 1)))
            options.append((D[i - 1, j], (i - 1, j)))
            best, cell = min(options, key=lambda o: o[0])  # min keeps the first of equals
            if np.isfinite(best):
                D[i, j] = best + c
                S[i, j] = S[cell]
                P[i][j] = cell
    return D, S, P


def naive_path(P, i, j):
    path = [(i, j)]
    while P[i][j] is not None:
        i, j = P[i][j]
        path.append((i, j))
    return np.array(path[::-1])


def naive_lng(neighbors, continues):
    """Lazy neighborhood graph built edge by edge and solved with Dijkstra.

    Parameters
    ----------
    neighbors : list of dict
        ``neighbors[i][row] = distance`` for every reported neighbour of query frame ``i``.
    continues : bool array

    Returns
    -------
    dict ``row -> (cost, start_row, path)`` for every reachable node of the last layer.
    """
    m = len(neighbors)
    edges: dict = {}
    source = ("source",)
    edges[source] = [((0, h), d) for h, d in neighbors[0].items()]
    for i in range(m):
        for h in neighbors[i]:
            out = []
            nxt = h + 1
            if i + 1 < m and nxt < len(continues) and continues[nxt] and nxt in neighbors[i + 1]:
                out.append(((i + 1, nxt), neighbors[i + 1][nxt]))  # diagonal
            if nxt < len(continues) and continues[nxt] and nxt in neighbors[i]:
                out.append(((i, nxt), neighbors[i][nxt]))  # vertical
            if i + 1 < m and h in neighbors[i + 1]:
                out.append(((i + 1, h), neighbors[i + 1][h]))  # horizontal
            edges[(i, h)] = out
    dist = {source: 0.0}
    prev = {}
    heap = [(0.0, 0, source)]
    tick = 1
    done = set()
    while heap:
        d, _, u = heapq.heappop(heap)
        if u in done:
            continue
        done.add(u)
        for v, w in edges.get(u, []):
            if d + w < dist.get(v, np.inf):
                dist[v] = d + w
                prev[v] = u
                heapq.heappush(heap, (d + w, tick, v))
                tick += 1
    out = {}
    for h in neighbors[m - 1]:
        node = (m - 1, h)
        if node not in dist:
            continue
        path = [node]
        while prev[path[-1]] != source:
            path.append(prev[path[-1]])
        path = np.array(path[::-1])
        out[h] = (dist[node], int(path[0][1]), path)
    return out


def naive_propagate(q, prev_ids, x, continues, k, r2):
    """Propagated neighbour set of one query frame, spelled out (see ``_lng_kernels.propagate_layer``).

    Candidates: ``h - 1`` (if ``h`` continues it), ``h``, ``h + 1`` (if it continues ``h``),
    ``h + 2`` (if it continues ``h + 1`` which continues ``h``); the ``k`` nearest by
    (squared distance, row) within ``r2``; returned ascending by row with distances.
    """
    n = len(x)
    cand = set()
    for h in prev_ids:
        h = int(h)
        cand.add(h)
        if h > 0 and continues[h]:
            cand.add(h - 1)
        if h + 1 < n and continues[h + 1]:
            cand.add(h + 1)
            if h + 2 < n and continues[h + 2]:
                cand.add(h + 2)
    scored = []
    for c in sorted(cand):
        d2 = sum((float(x[c][j]) - float(q[j])) ** 2 for j in range(len(q)))
        if d2 <= r2:
            scored.append((d2, c))
    scored.sort()
    best = sorted(scored[:k], key=lambda t: t[1])
    return [c for _, c in best], [float(np.sqrt(d2)) for d2, _ in best]


def naive_through_cell(q, x, continues):
    """Cost of the best subsequence-DTW path through every cell, ``(m, n)``: forward + backward - cell."""
    q = np.asarray(q, np.float64)
    x = np.asarray(x, np.float64)
    m, n = len(q), len(x)
    c = np.sqrt(((q[:, None, :] - x[None, :, :]) ** 2).sum(axis=2))
    F = np.full((m, n), np.inf)
    G = np.full((m, n), np.inf)
    for j in range(n):
        for i in range(m):
            opts = [0.0] if i == 0 else [F[i - 1, j]]
            if j > 0 and continues[j] and i > 0:
                opts += [F[i - 1, j - 1], F[i, j - 1]]
            F[i, j] = min(opts) + c[i, j]
    for j in range(n - 1, -1, -1):
        for i in range(m - 1, -1, -1):
            opts = [0.0] if i == m - 1 else [G[i + 1, j]]
            if j + 1 < n and continues[j + 1] and i < m - 1:
                opts += [G[i + 1, j + 1], G[i, j + 1]]
            G[i, j] = min(opts) + c[i, j]
    return F + G - c


def naive_blocks(continues, size):
    """Block of every row: at most ``size`` consecutive rows within one run."""
    block, b, run = [], -1, 0
    for j in range(len(continues)):
        if j == 0 or not continues[j] or run == size:
            b, run = b + 1, 0
        block.append(b)
        run += 1
    return np.array(block)


def naive_window_cost(q, w):
    """DTW cost of the best warping path from row 0 to the last row of ``w`` (both ends pinned),
    same steps as subsequence DTW; the bounded approximation's matches are checked against it."""
    q = np.asarray(q, np.float64)
    w = np.asarray(w, np.float64)
    D = np.full((len(q), len(w)), np.inf)
    for j in range(len(w)):
        for i in range(len(q)):
            c = float(np.sqrt(np.sum((q[i] - w[j]) ** 2)))
            if i == 0:
                D[i, j] = c if j == 0 else D[i, j - 1] + c
                continue
            best = D[i - 1, j]
            if j > 0:
                best = min(best, D[i - 1, j - 1], D[i, j - 1])
            D[i, j] = best + c
    return D[-1, -1]
