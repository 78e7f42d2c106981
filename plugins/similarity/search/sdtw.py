"""Exact subsequence DTW (Müller 2007, §4): the reference the lazy neighborhood graph is
measured against, and a matcher in its own right.

Same local distance (Euclidean in the feature space of the database), same step pattern
and the same ranked, non-overlapping selection as :mod:`.lng`, so with every database
frame among the neighbours the two return identical matches. O(nm) time, O(n + m)
memory: the forward pass keeps one DP column; the warping path of each kept match is
recomputed on its own window only.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from mocapflow.framework import Matcher
from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import MatchParams, QueryMatches, SearchSpace, min_frames_of, select_matches

from .matcher_base import match_kw


def validate_query(query: np.ndarray, dim: int) -> np.ndarray:
    """``(m, dim)`` float32, finite, at least one frame."""
    q = np.ascontiguousarray(query, dtype=np.float32)
    if q.ndim != 2 or q.shape[0] < 1 or q.shape[1] != dim:
        raise DataError(f"query must be (n_frames >= 1, {dim}) feature vectors, got {q.shape}")
    if not np.isfinite(q).all():
        raise DataError("query features contain NaN or inf")
    return q


def sdtw_costs(query: np.ndarray, space: SearchSpace) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best path ending in every database row.

    Parameters
    ----------
    query : ndarray of shape (m, d)
    space : SearchSpace
        With ``features`` (n, d).

    Returns
    -------
    cost : ndarray of float64, shape (n,)
        Accumulated Euclidean distance of the best path ending in row ``j``.
    start : ndarray of int64, shape (n,)
        Its first row.
    length : ndarray of int64, shape (n,)
        Its number of cells.
    """
    import numba

    from ._dtw_kernels import sdtw_forward
    from .ranges import ranges_dp

    if space.features is None:
        raise DataError("subsequence DTW needs the database features (SearchSpace.features)")
    q = validate_query(query, space.features.shape[1])
    qt = np.ascontiguousarray(q.T)
    if numba.get_num_threads() > 1:  # the clips on numba's threads (same values; one thread: one pass)
        _, cost, start, length = ranges_dp(qt, space, np.array([[0, space.n_rows]], np.int64))
        return cost, start, length
    return sdtw_forward(qt, space.features, ~space.continues)


def subsequence_dtw(
    query: np.ndarray,
    space: SearchSpace,
    *,
    count: int = 10,
    max_cost: float | None = None,
    rank_by: str = "cost",
    min_span: float = 0.5,
) -> QueryMatches:
    """Ranked non-overlapping matches of ``query`` by exact subsequence DTW.

    Parameters
    ----------
    query : ndarray of shape (m, d)
        Query features, in the database's feature space.
    space : SearchSpace
        With ``features``.
    count, max_cost, rank_by, min_span
        See :func:`mocapflow.framework.matching.select_matches`.
    """
    from ._dtw_kernels import dtw_window_path

    cost, start, length = sdtw_costs(query, space)
    feats = space.features
    assert feats is not None  # sdtw_costs refused a space without them
    q = validate_query(query, feats.shape[1])
    ends = np.arange(len(cost), dtype=np.int64)
    keep = select_matches(
        ends,
        start,
        cost,
        length,
        count=count,
        max_cost=max_cost,
        rank_by=rank_by,
        min_frames=min_frames_of(min_span, len(q)),
        excluded=space.excluded,
    )
    paths = []
    for e in keep:
        s = int(start[e])
        path, _ = dtw_window_path(q, feats[s : e + 1])
        path[:, 1] += s
        paths.append(path)
    return QueryMatches(start[keep], ends[keep] + 1, cost[keep], length[keep].astype(np.int64), paths)


class SubsequenceDTW(Matcher):
    """Exact subsequence DTW of each query against every clip of the database.

    ``database`` is an index dataset (its features dataset is found through its
    provenance) or a features dataset; ``features`` overrides where the vectors come from.
    """

    name = "sdtw"
    needs_index: ClassVar[bool] = False
    needs_features: ClassVar[bool] = True

    Params = MatchParams
    params: MatchParams

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        return subsequence_dtw(query, space, **match_kw(self.params))
