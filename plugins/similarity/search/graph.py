"""The lazy neighborhood graph of one query (Krüger et al. 2010, §4.1): neighbour sets of
the query frames (kNN, optionally propagated between searched frames), gap cells, and the
shortest-path search over the graph. :mod:`.lng` ranks its paths into matches; the
certified exact search (:mod:`.certified`) uses the graph's costs as a first threshold.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import QueryMatches, SearchSpace, min_frames_of, select_matches

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.matching import NeighbourIndex

#: neighbours per query frame of the default graph (the paper's k)
K = 256
#: gap band of the default graph, in query frames (measured: docs/global-matching.md)
GAPS = 32
#: the default graph searches the index on every this-many-th query frame
PROPAGATE = 2


def graph_options(paper: bool = False, k: int = K) -> dict[str, int]:
    """``k``, ``propagate`` and ``gaps`` of :func:`build_graph`: the gap-tolerant default
    graph, or the paper's (``paper``: neighbour cells only, every query frame searched)."""
    return {"k": int(k), "propagate": 0 if paper else PROPAGATE, "gaps": 0 if paper else GAPS}


@dataclass(frozen=True)
class NeighborhoodGraph:
    """The lazy neighborhood graph of one query after path search.

    Attributes
    ----------
    ids : ndarray of int64, shape (m, k)
        Neighbour rows of each query frame, ascending; ``-1`` past ``count[i]``.
    dist : ndarray of float32, shape (m, k)
        Their distances (the locally computed cells of the distance matrix).
    count : ndarray of int64, shape (m,)
    cost, start, pred, length : ndarray, shape (m, k)
        Shortest-path cost from the super-source, first row of that path, predecessor
        node (flat ``i*k + a``) and number of nodes on it.
    """

    ids: np.ndarray
    dist: np.ndarray
    count: np.ndarray
    cost: np.ndarray
    start: np.ndarray
    pred: np.ndarray
    length: np.ndarray
    gap_cells: int = 0

    @property
    def n_nodes(self) -> int:
        return int(self.count.sum())

    def matches(
        self,
        *,
        count: int = 10,
        max_cost: float | None = None,
        rank_by: str = "cost",
        min_span: float = 0.5,
        excluded: tuple[int, int] | None = None,
    ) -> QueryMatches:
        """Ranked non-overlapping matches ending in the last layer, none overlapping the
        ``excluded`` rows (see :func:`.select_matches`); ``end`` exclusive."""
        from ._lng_kernels import lng_backtrack

        last = self.ids.shape[0] - 1
        c = int(self.count[last])
        ends = self.ids[last, :c]
        keep = select_matches(
            ends,
            self.start[last, :c],
            self.cost[last, :c],
            self.length[last, :c],
            count=count,
            max_cost=max_cost,
            rank_by=rank_by,
            min_frames=min_frames_of(min_span, self.ids.shape[0]),
            excluded=excluded,
        )
        paths = [lng_backtrack(self.ids, self.pred, last, int(a)) for a in keep]
        return QueryMatches(
            self.start[last, keep],
            ends[keep] + 1,
            self.cost[last, keep],
            self.length[last, keep].astype(np.int64),
            paths,
        )


def neighbor_sets(
    query: np.ndarray,
    index: NeighbourIndex,
    k: int,
    radius: float | None,
    propagate: int = 0,
    space: SearchSpace | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``S(q_i)`` from the index, re-sorted by row id: ``(ids, dist, count)`` (see :class:`NeighborhoodGraph`).

    ``propagate = N > 0`` searches the index only for query frames ``0, N, 2N, ...`` and
    derives the other sets from the previous one (:func:`propagated_sets`; needs
    ``space`` with features).
    """
    if propagate > 0:
        return propagated_sets(query, index, k, radius, propagate, space)
    dist, ids = index.query(query, k, radius)
    dist = np.asarray(dist, np.float32)
    ids = np.asarray(ids, np.int64)
    if ids.shape != (query.shape[0], k) or dist.shape != ids.shape:
        raise DataError(f"index returned shapes {dist.shape}, {ids.shape}; expected ({query.shape[0]}, {k})")
    valid = ids >= 0
    big = np.iinfo(np.int64).max
    order = np.argsort(np.where(valid, ids, big), axis=1, kind="stable")
    ids = np.take_along_axis(ids, order, 1)
    dist = np.take_along_axis(dist, order, 1)
    valid = np.take_along_axis(valid, order, 1)
    count = valid.sum(axis=1).astype(np.int64)
    ids[~valid] = -1
    if np.any((np.diff(ids, axis=1) == 0) & valid[:, 1:]):
        raise DataError("index returned the same row twice for one query frame")
    return ids, dist, count


def propagated_sets(
    query: np.ndarray, index: NeighbourIndex, k: int, radius: float | None, every: int, space: SearchSpace | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Approximate neighbour sets by temporal propagation (our extension, not in the paper).

    Query frames ``0, every, 2 every, ...`` get the index's exact kNN; every
    other frame gets the ``k`` nearest (within ``radius``) of the rows a warping path can
    reach from the previous frame's set: ``h - 1 .. h + 2`` for each of its rows ``h``
    (:func:`._lng_kernels.propagate_layer`, distances exact). The graph then holds the
    neighbourhoods of the paths that start near ``q_1``, as a beam of width ``k`` would:
    the kNN sets themselves are no longer the true ones, but every path cost is exact, and
    an alignment is lost only when its rows drop out of the ``k`` best of the beam.
    ``benchmarks/search.py`` measures the fraction of sDTW's alignments kept.
    """
    from ._lng_kernels import propagate_sets

    if space is None or space.features is None:
        raise DataError("propagated kNN sets need the database features (SearchSpace.features)")
    m = query.shape[0]
    ids = np.full((m, k), -1, np.int64)
    dist = np.full((m, k), np.inf, np.float32)
    count = np.zeros(m, np.int64)
    r2 = np.inf if radius is None else float(radius) ** 2
    exact = np.arange(0, m, every)
    ids[exact], dist[exact], count[exact] = neighbor_sets(query[exact], index, k, radius)
    propagate_sets(
        np.ascontiguousarray(query, dtype=np.float32), ids, dist, count, every, space.features, space.continues, r2
    )
    return ids, dist, count


def build_graph(
    query: np.ndarray,
    space: SearchSpace,
    *,
    k: int = 256,
    radius: float | None = None,
    propagate: int = 0,
    gaps: int = 0,
    sets: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> NeighborhoodGraph:
    """kNN search, graph construction and path search for one query.

    Parameters
    ----------
    query : ndarray of shape (m, d)
        Query features in the index's feature space.
    space : SearchSpace
        With a built ``index`` over its rows.
    k : int
        Cap on the neighbours per query frame.
    radius : float or None
        Fixed search radius ``r`` (same units as the features); ``None``: plain kNN.
    propagate : int
        0: the index's kNN for every query frame (the paper). N > 0: only for every N-th
        frame, the sets in between propagated along the database (:func:`propagated_sets`).
    gaps : int
        0: nodes are the neighbour cells only (the paper). G > 0: also the cells within G
        query frames after or before a neighbour cell, at most two database frames per
        query frame, each cell's distance computed exactly (:mod:`._gap_kernels`; needs
        ``space.features``).
    sets : (ids, dist, count), optional
        The neighbour sets as :func:`neighbor_sets` returns them, when already searched.
    """
    from ._lng_kernels import lng_forward

    if space.index is None:
        raise DataError("the lazy neighborhood graph needs a built index (SearchSpace.index)")
    q = np.ascontiguousarray(query, dtype=np.float32)
    if q.ndim != 2 or q.shape[0] < 1 or not np.isfinite(q).all():
        raise DataError(f"query must be finite (n_frames >= 1, dim) feature vectors, got shape {q.shape}")
    ids, dist, count = sets if sets is not None else neighbor_sets(q, space.index, k, radius, propagate, space)
    if count.any() and ids.max() >= space.n_rows:
        raise DataError(f"index returned row {ids.max()} but the database has {space.n_rows} rows")
    gap_cells = 0
    if gaps > 0:
        from ._gap_kernels import gap_layers

        if space.features is None:
            raise DataError("gap cells need the database features (SearchSpace.features)")
        ids, dist, count, gap_cells = gap_layers(q, ids, dist, count, space.features, space.continues, int(gaps))
    cost, start, pred, length = lng_forward(ids, dist, count, space.continues)
    return NeighborhoodGraph(ids, dist, count, cost, start, pred, length, int(gap_cells))
