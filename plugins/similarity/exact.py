"""Certified-exact global matching: subsequence DTW's top matches, pruned by an admissible bound.

``certified_sdtw`` returns exactly what :func:`.sdtw.subsequence_dtw` returns (same matches,
costs, paths; any ``rank_by: cost`` setting) while running the DP only where a lower bound
cannot rule a path of cost <= ``tau`` out (proof: ``docs/global-matching.md``,
"Certified-exact mode"):

1. the gap-tolerant LNG (:mod:`.lng`) finds real alignments with their exact costs; the
   ``count``-th cost of its selection is the threshold ``tau`` (capped by ``max_cost``);
2. a coarse subsequence DTW over blocks of ``block`` consecutive rows, each cell costing
   the query frame's distance to the block's bounding box, bounds every fine path from
   below (forward + backward, :func:`._coarse_kernels.coarse_alive`); blocks where the
   bound exceeds ``tau`` at every query frame are skipped;
3. the fine DP (:func:`._coarse_kernels.sdtw_ranges`, the arithmetic of ``sdtw_forward``)
   runs over the remaining blocks; every end row whose best path costs <= ``tau`` gets
   exactly sDTW's cost, start and length;
4. the same greedy selection on those candidates yields ``count`` matches, which are then
   sDTW's; if it yields fewer, ``tau`` is doubled (three times at most), then set to
   ``max_cost`` (or unbounded: the whole DP, plain sDTW).

Measured and dropped: the bound suggested first (the sum of the remaining query frames'
1-NN distances, or per run of rows the k-th neighbour distance, with the first row's
surviving cells from a radius query): with k = 256 on 380,813 rows the k-th neighbour
distance is far below a match's cost per frame, and half the queries kept every row.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import QueryMatches, SearchSpace, min_frames_of, select_matches

from .matcher_base import block_boxes_of

#: box distances are shrunk by this relative margin: the fine DP's float32 distances may
#: round below the exact ones, and the bound must stay below them
_SHRINK = 1.0 - 1e-4
#: default of ``certified_sdtw(full_from=)``: share of alive rows from which a pass is the whole DP
FULL_FROM = 0.5


@dataclass
class ExactStats:
    """What one certified search did: ``tau`` used, fine DP columns computed (of ``n``), retries."""

    tau: float = np.inf
    columns: int = 0
    passes: int = 0
    retried: bool = False


def alive_ranges(alive: np.ndarray, bstart: np.ndarray) -> np.ndarray:
    """Row ranges ``[a, b)`` (int64 (r, 2)) covering the runs of consecutive alive blocks."""
    if not alive.any():
        return np.zeros((0, 2), np.int64)
    edge = np.diff(np.r_[0, alive.astype(np.int8), 0])
    first, stop = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
    return np.stack([bstart[first], bstart[stop]], axis=1).astype(np.int64)


def certified_sdtw(query: np.ndarray, space: SearchSpace, *, count: int = 10, max_cost: float | None = None,
                   rank_by: str = "cost", min_span: float = 0.5, k: int = 256, gaps: int = 32, block: int = 16,
                   graph=None, stats: ExactStats | None = None, full_from: float | None = None) -> QueryMatches:
    """Exactly :func:`.sdtw.subsequence_dtw`'s matches, by the pruned DP (see module doc).

    Parameters
    ----------
    query : ndarray of shape (m, d)
    space : SearchSpace
        With ``index`` and ``features``.
    count, max_cost, rank_by, min_span
        As :func:`mocapflow.framework.matching.select_matches`; ``rank_by="normalized"`` has no admissible
        cost bound here and runs the whole DP.
    k, gaps
        kNN sets and gap band of the LNG that supplies ``tau`` (:func:`.lng.build_graph`).
    block : int
        Rows per block of the coarse bound.
    graph : NeighborhoodGraph, optional
        The LNG of this query, when already built (any sets: it only supplies ``tau``).
    stats : ExactStats, optional
        Filled with what the search did.
    full_from : float, optional
        (Default :data:`FULL_FROM`.) When the alive rows of a pass reach this share of the database, that pass is the
        whole DP with no threshold (the last pass: a pruned pass, then retries, would cost
        more than sDTW itself). Speed only; the result is sDTW's either way.
    """
    from ._coarse_kernels import coarse_alive, sdtw_ranges
    from ._dtw_kernels import dtw_window_path
    from .lng import build_graph
    from .sdtw import validate_query

    if space.features is None or space.index is None:
        raise DataError("certified-exact search needs the database index and features (SearchSpace)")
    q = validate_query(query, space.features.shape[1])
    st = stats if stats is not None else ExactStats()
    full_from = FULL_FROM if full_from is None else float(full_from)
    ceiling = np.inf if (max_cost is None or rank_by != "cost") else float(max_cost)
    tau = np.inf
    if rank_by == "cost":
        if graph is None:
            graph = build_graph(q, space, k=min(k, space.n_rows), gaps=gaps)
        found = graph.matches(count=count, max_cost=max_cost, rank_by="cost", min_span=min_span)
        if len(found) == count:
            tau = float(found.cost[-1])
        elif len(found):  # a guess, verified below: too few matches under it doubles it
            tau = 2.0 * float(found.cost[-1])
    tau = min(tau, ceiling)
    qt = np.ascontiguousarray(q.T)
    clip_start = ~space.continues
    tries = 0
    while True:
        if np.isfinite(tau):
            bstart, lo, hi, link = block_boxes_of(space, block)
            ranges = alive_ranges(coarse_alive(qt, lo, hi, link, tau, _SHRINK), bstart)
            if (ranges[:, 1] - ranges[:, 0]).sum() >= full_from * space.n_rows:
                tau = ceiling
                ranges = np.array([[0, space.n_rows]], np.int64)
        else:
            ranges = np.array([[0, space.n_rows]], np.int64)
        cost, start, length = sdtw_ranges(qt, space.features, clip_start, ranges)
        st.tau, st.passes = tau, st.passes + 1
        st.columns += int((ranges[:, 1] - ranges[:, 0]).sum())
        ends = np.flatnonzero(cost <= tau).astype(np.int64)
        keep = select_matches(ends, start[ends], cost[ends], length[ends], count=count, max_cost=max_cost,
                              rank_by=rank_by, min_frames=min_frames_of(min_span, len(q)))
        if len(keep) == count or tau >= ceiling:
            break
        tries += 1
        tau, st.retried = (min(2.0 * tau, ceiling) if tries < 4 and tau > 0 else ceiling), True
    keep = ends[keep]
    paths = []
    for e in keep:
        s = int(start[e])
        path, _ = dtw_window_path(q, space.features[s : e + 1])
        path[:, 1] += s
        paths.append(path)
    return QueryMatches(start[keep], keep + 1, cost[keep], length[keep].astype(np.int64), paths)
