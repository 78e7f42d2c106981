"""Filter-and-refine global search (``matchers.search`` ``mode: fast``): sDTW's matches where
the index's neighbours point, exact DP on those regions only.

1. **Filter.** ``frames`` query frames spread over the query each get their ``k`` nearest
   database rows from the search space's index. A neighbour ``h`` of query frame ``i`` votes
   for the *diagonal* ``a = h - i`` (the row where query frame 0 would sit on a slope-1 path):
   diagonals are binned per clip in bins of ``w = max(4, m // 4)`` rows, a vote counts for
   its bin and the two beside it (time scaling bends the diagonal), and each bin scores the
   number of distinct query frames voting for it.
2. **Refine.** The ``candidates * count`` best bins (most votes, then lowest summed distance)
   become row windows ``[a0 - 2w, a0 + 3w + 1.25 m)`` inside their clip (merged), and the fine
   DP (:func:`._dtw_kernels.sdtw_ranges_compact`, sDTW's own column) runs on them.
3. The greedy selection of those end rows gives the matches: every cost is an exact sDTW cost
   of a path inside its window, so a returned match is never better than sDTW's at its rows;
   a match of sDTW's whose region gets no votes is missed (measured recall:
   docs/global-matching.md).

Queries without an index, ``rank_by: normalized`` or with fewer than ``count`` matches in the
windows fall back to the exact search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapflow.framework.matching import QueryMatches, SearchSpace, min_frames_of, select_matches


@dataclass(frozen=True)
class FastSettings:
    """How :func:`fast_sdtw` filters (measured choice: docs/global-matching.md).

    Attributes
    ----------
    frames : query frames whose neighbours vote (at most the query's length)
    k : neighbours per voting frame
    candidates : windows refined, times ``count``
    eps : the neighbours are ``eps``-approximate where the index can
    """

    frames: int = 12
    k: int = 64
    candidates: int = 3
    eps: float = 0.0
    design: str = "gain"


DEFAULT_FAST = FastSettings()


def candidate_windows(space: SearchSpace, m: int, frames: np.ndarray, dist, ids, score: str = "gain") -> np.ndarray:
    """Row windows (int64 (b, 2), best first, unmerged) of every diagonal bin a neighbour votes for (module doc)."""
    from .certified import run_starts

    ok = ids >= 0
    h = ids[ok].astype(np.int64)
    fpos = np.broadcast_to(np.arange(len(frames))[:, None], ids.shape)[ok]
    fi = frames[fpos].astype(np.int64)
    dd = np.asarray(dist, np.float64)[ok]
    if not len(h):
        return np.zeros((0, 2), np.int64)
    radius = np.where(ids >= 0, dist, -np.inf).max(axis=1).astype(np.float64)  # each frame's k-th distance
    rs = run_starts(space)
    run = np.searchsorted(rs, h, side="right") - 1
    lo, hi = rs[run], rs[run + 1]
    w = max(4, m // 4)
    span = (hi - lo) // w
    bb = np.clip((h - fi - lo) // w, 0, span) + 1  # the diagonal's bin within its run, 1 .. span + 1
    off = np.r_[0, np.cumsum((rs[1:] - rs[:-1]) // w + 3)]  # bins 0 .. span + 2 of each run
    own_key = off[run] + bb
    key = np.concatenate([own_key - 1, own_key, own_key + 1])  # a vote counts for its bin and both beside it
    pair = key * (len(frames) + 1) + np.tile(fpos, 3)
    o = np.lexsort((np.tile(dd, 3), pair))  # by (bin, frame), nearest first
    first = np.r_[True, pair[o][1:] != pair[o][:-1]]
    pair, gain = pair[o][first], (radius[np.tile(fpos, 3)] - np.tile(dd, 3))[o][first]
    bins, at, votes = np.unique(pair // (len(frames) + 1), return_index=True, return_counts=True)
    # sum over frames of (k-th distance - nearest hit): the estimated saving on the diagonal's cost
    val = np.add.reduceat(gain, at) if score == "gain" else votes.astype(np.float64)
    peak = np.ones(len(bins), bool)  # a local maximum over the bins +-2 (earlier bin wins ties): one per region
    for dk in (-2, -1, 1, 2):
        j = np.searchsorted(bins, bins + dk)
        jj = np.minimum(j, len(bins) - 1)
        there = (j < len(bins)) & (bins[jj] == bins + dk)
        peak &= ~there | (val > val[jj]) | ((val == val[jj]) & (dk > 0))
    top = bins[peak][np.argsort(-val[peak], kind="stable")]
    r = np.searchsorted(off, top, side="right") - 1
    a0 = rs[r] + (top - off[r] - 1) * w  # first diagonal row of the bin
    wlo = np.maximum(a0 - 2 * w, rs[r])
    whi = np.minimum(a0 + 3 * w + (5 * m) // 4 + 1, rs[r + 1])
    return np.stack([wlo, whi], axis=1)[whi > wlo]


def seed_windows(space, m, frames, ids):
    from .certified import merged_ranges, run_starts

    ok = ids >= 0
    h = ids[ok].astype(np.int64)
    fi = np.broadcast_to(frames[:, None], ids.shape)[ok].astype(np.int64)
    rs = run_starts(space)
    run = np.searchsorted(rs, h, side="right") - 1
    lo = np.maximum(h - (1.3 * fi).astype(np.int64) - 2, rs[run])
    hi = np.minimum(h + (1.3 * (m - 1 - fi)).astype(np.int64) + 3, rs[run + 1])
    return merged_ranges(lo, hi)


def fast_sdtw(
    query: np.ndarray,
    space: SearchSpace,
    *,
    count: int = 10,
    max_cost: float | None = None,
    rank_by: str = "cost",
    min_span: float = 0.5,
    settings: FastSettings = DEFAULT_FAST,
    stats=None,
) -> QueryMatches:
    """sDTW's matches within the windows the index's neighbours vote for (module doc)."""
    import numba

    from ._dtw_kernels import dtw_window_path
    from .certified import certified_sdtw, ranges_dp
    from .sdtw import validate_query

    if space.index is None or rank_by != "cost" or space.features is None:
        return certified_sdtw(query, space, count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span)
    q = validate_query(query, space.features.shape[1])
    cfg = settings
    m = len(q)
    frames = np.unique(np.linspace(0, m - 1, min(cfg.frames, m)).round().astype(np.int64))
    kw = {}
    options = getattr(type(space.index), "query_options", frozenset())
    if "workers" in options:  # a dozen query frames: the index's threads only at scale
        kw["workers"] = 1 if space.n_rows < 1_000_000 else max(1, numba.get_num_threads())
    if "eps" in options and cfg.eps > 0:
        kw["eps"] = cfg.eps
    dist, ids = space.index.query(np.ascontiguousarray(q[frames]), min(cfg.k, space.n_rows), **kw)
    qt = np.ascontiguousarray(q.T)
    min_frames = min_frames_of(min_span, m)
    if cfg.design == "seed":
        windows = seed_windows(space, m, frames, np.asarray(ids))
    else:
        windows = candidate_windows(space, m, frames, np.asarray(dist), np.asarray(ids), cfg.design)
    take = cfg.candidates * count
    while True:  # the best windows; four times more while they hold fewer than count matches
        from .certified import merged_ranges

        ranges = windows if cfg.design == "seed" else merged_ranges(windows[:take, 0], windows[:take, 1])
        rows, cost, start, length = ranges_dp(qt, space, ranges)
        if stats is not None:
            stats.columns += len(rows)
        keep = select_matches(
            rows, start, cost, length, count=count, max_cost=max_cost, rank_by=rank_by, min_frames=min_frames
        )
        if len(keep) == count or take >= len(windows) or cfg.design == "seed":
            break
        take *= 4
    if len(keep) < count and len(rows) < space.n_rows:
        if stats is not None:
            stats.retried = True
        return certified_sdtw(query, space, count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span)
    paths = []
    for e, s in zip(rows[keep].tolist(), start[keep].tolist(), strict=True):
        path, _ = dtw_window_path(q, space.features[s : e + 1])
        path[:, 1] += s
        paths.append(path)
    return QueryMatches(start[keep], rows[keep] + 1, cost[keep], length[keep].astype(np.int64), paths)
