"""Filter-and-refine global search (``matchers.search`` ``mode: fast``): the exact DP only on
the database regions the index's neighbours of a few query frames point at.

1. **Filter.** ``frames`` query frames spread over the query (first and last included) each
   get their ``k`` nearest database rows from the search space's index (``eps``-approximate:
   they only choose where the exact DP runs).
2. **Refine.** Around a neighbour ``h`` of query frame ``i`` a match that takes between
   ``1 / slope`` and ``slope`` database rows per query frame lies within rows
   ``h - slope i .. h + slope (m - 1 - i)`` of its clip; these windows, merged, get the fine
   DP (:func:`.certified.ranges_dp`: sDTW's own column, on numba's threads at scale).
3. **Select.** The greedy selection of those end rows gives the matches. Every cost is the
   exact cost of a path inside its window, never below sDTW's at the same end row; a match of
   sDTW's whose rows hold none of the neighbours is missed (measured recall:
   docs/global-matching.md). Fewer than ``count`` matches in the windows, no index, or
   ``rank_by: normalized``: the exact search answers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from mocapflow.framework.matching import QueryMatches, SearchSpace, min_frames_of, select_matches


@dataclass(frozen=True)
class FastSettings:
    """How :func:`fast_sdtw` filters (the measured choice: docs/global-matching.md).

    Attributes
    ----------
    frames : query frames whose neighbours open windows (at most the query's length)
    k : neighbours per such frame
    slope : most database rows per query frame (and fewest, as its inverse) a window allows
    eps : the neighbours are ``eps``-approximate where the index can (``"eps" in query_options``)
    """

    frames: int = 24
    k: int = 128
    slope: float = 1.3
    eps: float = 1.0


DEFAULT_FAST = FastSettings()


def seed_windows(space: SearchSpace, m: int, frames: np.ndarray, ids: np.ndarray, slope: float) -> np.ndarray:
    """Merged row ranges (int64 (r, 2)) around the neighbours ``ids`` (len(frames), k) of query frames ``frames``."""
    from .ranges import merged_ranges, run_starts

    ok = ids >= 0
    h = ids[ok].astype(np.int64)
    fi = np.broadcast_to(frames[:, None], ids.shape)[ok].astype(np.int64)
    rs = run_starts(space)
    run = np.searchsorted(rs, h, side="right") - 1
    lo = np.maximum(h - (slope * fi).astype(np.int64) - 2, rs[run])
    hi = np.minimum(h + (slope * (m - 1 - fi)).astype(np.int64) + 3, rs[run + 1])
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
    exact_search: Callable[..., QueryMatches],
    stats: Any = None,
) -> QueryMatches:
    """sDTW's matches within the windows around the index's neighbours (module doc).

    Parameters as :func:`.certified.certified_sdtw`; ``stats`` (an ``ExactStats``) gets the DP
    rows computed and ``retried`` when the exact search answered; ``exact_search`` (the
    certified search, given by its matcher) answers when the windows cannot.
    """
    from ._dtw_kernels import dtw_window_path
    from .ranges import ranges_dp
    from .sdtw import validate_query

    exact = {"count": count, "max_cost": max_cost, "rank_by": rank_by, "min_span": min_span}
    if space.index is None or rank_by != "cost" or space.features is None:
        return exact_search(query, space, **exact)
    q = validate_query(query, space.features.shape[1])
    cfg = settings
    m = len(q)
    frames = np.unique(np.linspace(0, m - 1, min(cfg.frames, m)).round().astype(np.int64))
    kw: dict[str, Any] = {}
    options: frozenset[str] = getattr(type(space.index), "query_options", frozenset())
    if "workers" in options:  # a few dozen query frames: waking threads costs more than it saves
        kw["workers"] = 1
    if "eps" in options and cfg.eps > 0:
        kw["eps"] = cfg.eps
    _, ids = space.index.query(np.ascontiguousarray(q[frames]), min(cfg.k, space.n_rows), **kw)
    ranges = seed_windows(space, m, frames, np.asarray(ids), cfg.slope)
    rows, cost, start, length = ranges_dp(np.ascontiguousarray(q.T), space, ranges)
    if stats is not None:
        stats.columns += len(rows)
    keep = select_matches(
        rows,
        start,
        cost,
        length,
        count=count,
        max_cost=max_cost,
        rank_by=rank_by,
        min_frames=min_frames_of(min_span, m),
        excluded=space.excluded,
    )
    if len(keep) < count and len(rows) < space.n_rows:
        if stats is not None:
            stats.retried = True
        return exact_search(query, space, **exact)
    paths = []
    for e, s in zip(rows[keep].tolist(), start[keep].tolist(), strict=True):
        path, _ = dtw_window_path(q, space.features[s : e + 1])
        path[:, 1] += s
        paths.append(path)
    return QueryMatches(start[keep], rows[keep] + 1, cost[keep], length[keep].astype(np.int64), paths)
