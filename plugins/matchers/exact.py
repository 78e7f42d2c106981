"""Certified-exact global matching: subsequence DTW's top matches, pruned by an admissible bound.

``certified_sdtw`` returns exactly what :func:`.sdtw.subsequence_dtw` returns (same matches,
costs, paths; ``rank_by: cost``) while computing only the DP columns a lower bound cannot
rule out (proof: ``docs/global-matching.md``, "Certified-exact mode"):

1. the exact kNN sets bound every cell: in a run ``s`` of consecutive rows (a path never
   leaves its run) frame ``i``'s cell costs at least ``b_s(i)``, the smaller of the k-th
   neighbour distance and the nearest neighbour in ``s``; every frame is on the path at
   least once, so it spends at least ``rest_s[i] = sum(b_s[i:])`` on frames ``i ..``
   (:func:`run_bounds`);
2. the gap-tolerant LNG on the same sets finds real alignments; the ``count``-th cost of
   its selection is the threshold ``tau`` (capped by ``max_cost``);
3. the DP (:func:`._dtw_kernels.sdtw_pruned`) drops every cell with ``D(i, j) + rest_s[i+1]
   > tau``; its first row survives only where ``d(q_0, x_j) <= tau - rest_s[1]``, a radius
   query on the index, so runs of columns start only there;
4. the same greedy selection on the surviving candidates (all of cost <= ``tau``, exact)
   yields ``count`` matches, which are then sDTW's; if it yields fewer, the search is
   repeated with ``tau`` doubled (three times at most), then with ``tau = max_cost`` (or
   unbounded, which is plain sDTW). Without ``count`` LNG matches the first ``tau`` is a
   guess (twice the LNG's last cost, or twice the bound), verified the same way.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.framework.errors import DataError

from .matches import QueryMatches, SearchSpace, min_frames_of, select_matches

#: rest bounds are shrunk by this relative margin: the index's float32 distances and the
#: DP's may differ in the last bits, and the bound must stay below the DP's cells
_MARGIN = 1e-5


@dataclass
class ExactStats:
    """What one certified search did: ``tau`` used, columns computed (of ``n``), retries."""

    tau: float = np.inf
    columns: int = 0
    seeds: int = 0
    retried: bool = False


def rest_bounds(nn1: np.ndarray) -> np.ndarray:
    """``rest[i]`` = lower bound of any path's cost on query frames ``i ..`` (``rest[m] = 0``), shape (m+1,)."""
    nn1 = np.asarray(nn1, np.float64)
    rest = np.zeros(len(nn1) + 1)
    rest[:-1] = np.cumsum(nn1[::-1])[::-1]
    return rest * (1.0 - _MARGIN)


def run_bounds(ids: np.ndarray, dist: np.ndarray, count: np.ndarray, k: int, runs: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Per run of consecutive rows, a lower bound of the cost of query frames ``i ..``.

    A path stays in one run. In run ``s`` query frame ``i``'s cell costs at least
    ``b_s(i) = min(d_k(i), min of d(i, h) over the neighbours h in s)``: a row outside the
    exact kNN set is no nearer than the k-th neighbour (``d_k = inf`` when the set holds
    every row). Runs without a neighbour of any frame share slot 0 (``b = d_k``).

    Parameters
    ----------
    ids, dist, count : the exact kNN sets (:func:`.lng.neighbor_sets`), shape (m, k)
    k : int, the cap asked of the index
    runs : int64 (n,), run ordinal per row (:attr:`.SearchSpace.runs`)

    Returns
    -------
    rest : float64 (slots, m+1), rest[:, m] = 0
    seg_slot : int32 (n_runs,), the slot of every run
    """
    m = ids.shape[0]
    valid = ids >= 0
    dk = np.where(count >= k, np.where(valid, dist, -np.inf).max(axis=1), np.inf).astype(np.float64)
    frame_i = np.broadcast_to(np.arange(m)[:, None], ids.shape)[valid]
    seg = runs[ids[valid]]
    touched, inv = np.unique(seg, return_inverse=True)
    b = np.tile(dk, (len(touched) + 1, 1))
    np.minimum.at(b, (inv + 1, frame_i), dist[valid].astype(np.float64))
    rest = np.zeros((len(b), m + 1))
    rest[:, :-1] = np.cumsum(b[:, ::-1], axis=1)[:, ::-1]
    seg_slot = np.zeros(int(runs[-1]) + 1 if len(runs) else 0, np.int32)
    seg_slot[touched] = np.arange(1, len(touched) + 1, dtype=np.int32)
    return rest * (1.0 - _MARGIN), seg_slot


def radius_rows(space: SearchSpace, q0: np.ndarray, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """Ascending rows ``j`` with ``d(q0, x_j) <= rho`` (slightly inflated; a superset is safe), and their distances.

    A fixed-radius query on the index, its cap raised until the result is not full; past
    an eighth of the database a linear scan of the features is cheaper.
    """
    n = space.n_rows
    rho = float(rho) * (1.0 + 1e-4) + 1e-6
    cap = 1024
    while space.index is not None and cap < n // 8:
        dist, ids = space.index.query(q0[None].astype(np.float32), cap, rho)
        ids, dist = np.asarray(ids[0], np.int64), np.asarray(dist[0], np.float64)
        ok = ids >= 0
        if ok.sum() < cap:
            order = np.argsort(ids[ok])
            return ids[ok][order], dist[ok][order]
        cap *= 8
    diff = space.features - q0
    d = np.sqrt(np.einsum("ij,ij->i", diff, diff, dtype=np.float64))
    rows = np.flatnonzero(d <= rho).astype(np.int64)
    return rows, d[rows]


def certified_sdtw(query: np.ndarray, space: SearchSpace, *, count: int = 10, max_cost: float | None = None,
                   rank_by: str = "cost", min_span: float = 0.5, k: int = 256, gaps: int = 8,
                   graph=None, sets=None, stats: ExactStats | None = None) -> QueryMatches:
    """Exactly :func:`.sdtw.subsequence_dtw`'s matches, by the pruned DP (see module doc).

    Parameters
    ----------
    query : ndarray of shape (m, d)
    space : SearchSpace
        With ``index`` (exact kNN over all its rows) and ``features``.
    count, max_cost, rank_by, min_span
        As :func:`.matches.select_matches`; ``rank_by="normalized"`` has no admissible
        cost bound here and runs the unpruned DP.
    k, gaps
        kNN sets and gap band of the LNG that supplies ``tau`` (:func:`.lng.build_graph`).
    graph : NeighborhoodGraph, optional
        The LNG of this query on ``sets``, when already built.
    sets : (ids, dist, count), optional
        The query's exact kNN sets (:func:`.lng.neighbor_sets`), when already searched.
    stats : ExactStats, optional
        Filled with what the search did.
    """
    from ._dtw_kernels import dtw_window_path, sdtw_pruned
    from .lng import build_graph, neighbor_sets
    from .sdtw import validate_query

    if space.features is None or space.index is None:
        raise DataError("certified-exact search needs the database index and features (SearchSpace)")
    q = validate_query(query, space.features.shape[1])
    st = stats if stats is not None else ExactStats()
    min_frames = min_frames_of(min_span, len(q))
    kk = min(k, space.n_rows)
    if sets is None:
        sets = neighbor_sets(q, space.index, kk, None)
    if graph is None:
        graph = build_graph(q, space, k=kk, gaps=gaps, sets=sets)
    if rank_by == "cost":
        ids, dist, cnt = sets
        if (cnt < 1).any():  # exact k-NN is never empty
            raise DataError("certified-exact search needs exact kNN sets with at least one neighbour per frame")
        rest, seg_slot = run_bounds(ids, dist, cnt, kk, space.runs)
        found = graph.matches(count=count, max_cost=max_cost, rank_by="cost", min_span=min_span)
        if len(found) == count:
            tau = float(found.cost[-1])
        else:  # a guess, verified below: too few matches under it doubles it
            tau = 2.0 * (float(found.cost[-1]) if len(found) else float(rest[0, 0]))
    else:
        rest, seg_slot, tau = np.zeros((1, len(q) + 1)), np.zeros(int(space.runs[-1]) + 1, np.int32), np.inf
    ceiling = np.inf if (max_cost is None or rank_by != "cost") else float(max_cost)
    tau = min(tau, ceiling)
    qt = np.ascontiguousarray(q.T)
    clip_start = ~space.continues
    tries = 0
    while True:
        if np.isfinite(tau):
            low = float(rest[:, 1].min())
            seeds, d0 = radius_rows(space, q[0], tau - low) if tau >= low else (np.zeros(0, np.int64), np.zeros(0))
            # the first cell survives only under its own run's bound (re-tested in the kernel)
            seeds = seeds[d0 <= (tau - rest[seg_slot[space.runs[seeds]], 1]) * (1 + 1e-4) + 1e-6]
        else:
            seeds = np.arange(space.n_rows, dtype=np.int64)
        cost, start, length, cols = sdtw_pruned(qt, space.features, clip_start, seeds, rest, space.runs, seg_slot, tau)
        st.tau, st.columns, st.seeds = tau, st.columns + int(cols), len(seeds)
        ends = np.flatnonzero(np.isfinite(cost)).astype(np.int64)
        keep = select_matches(ends, start[ends], cost[ends], length[ends], count=count, max_cost=max_cost,
                              rank_by=rank_by, min_frames=min_frames)
        if len(keep) == count or tau >= ceiling:
            break
        # too few under tau: widen (doubling a few times, then to all that may count)
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
