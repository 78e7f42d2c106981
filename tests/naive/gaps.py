"""Naive reference of the gap-tolerant lazy neighborhood graph (``plugins/similarity/_gap_kernels.py``).

The node set spelled out from its definition: row ``h`` is a node of layer ``i`` when it is
a neighbour of query frame ``i`` (depth 0), or when a node ``(i-1, g)`` of forward depth
``< gaps`` has ``h - g`` in ``{0, 1, 2}`` with ``g .. h`` consecutive frames of one clip
(forward depth one more), or when a node ``(i+1, g)`` of backward depth ``< gaps`` has
``g - h`` in ``{0, 1, 2}`` likewise (backward depth one more).
"""

from __future__ import annotations

import numpy as np


def linked(continues, a, b) -> bool:
    """Rows ``a <= b`` are consecutive frames of one clip."""
    return all(continues[r] for r in range(a + 1, b + 1))


def naive_gap_nodes(neighbors: list[set], continues, gaps: int) -> list[set]:
    """Rows of every layer of the gap-tolerant graph (``neighbors[i]``: neighbour rows of frame ``i``)."""
    m, n = len(neighbors), len(continues)

    def band(order, sign):
        depth = [dict() for _ in range(m)]
        prev = None
        for i in order:
            d = {h: 0 for h in neighbors[i]}
            if prev is not None:
                for g, dg in depth[prev].items():
                    if dg >= gaps:
                        continue
                    for s in range(3):
                        h = g + sign * s
                        if 0 <= h < n and linked(continues, min(g, h), max(g, h)):
                            d[h] = min(d.get(h, gaps + 1), dg + 1)
            depth[i] = d
            prev = i
        return depth

    fwd = band(range(m), 1)
    bwd = band(range(m - 1, -1, -1), -1)
    return [set(fwd[i]) | set(bwd[i]) for i in range(m)]


def naive_gap_neighbors(q, x, nn_rows: list[set], continues, gaps: int) -> list[dict]:
    """``{row: exact distance}`` per layer, for :func:`naive.dtw.naive_lng`."""
    layers = naive_gap_nodes(nn_rows, continues, gaps)
    q, x = np.asarray(q, np.float64), np.asarray(x, np.float64)
    return [{h: float(np.linalg.norm(q[i] - x[h])) for h in sorted(rows)} for i, rows in enumerate(layers)]
