"""Global motion matching with the lazy neighborhood graph (Krüger et al. 2010, §4.1).

Default (``exact: true``): exactly subsequence DTW's matches by a certified, pruned
coarse-to-fine DP (:mod:`.exact`), measured faster than both sDTW and the graph
(docs/global-matching.md). ``exact: false`` searches the graph: with ``gaps: 32`` (our
extension) it also holds *gap cells*, rows within ``gaps`` query frames of a neighbour
cell, their cost computed exactly on demand (:mod:`._gap_kernels`), so another performer's
movement is found even where a few of its frames are not among the ``k`` nearest;
``gaps: 0`` is the paper's graph; ``fill: true`` falls back to the certified search when
the graph holds fewer than ``count`` matches.

For a query ``Q = [q_1 .. q_m]``: a fixed-radius kNN search capped at ``k`` gives the
neighbour set ``S(q_i)`` of every query frame; every reported neighbour is a node; the
diagonal, vertical and horizontal DTW steps between nodes are the edges (never across a
clip boundary), each costing the distance of the node it points at; a super-source
points at all of ``S(q_1)``. Shortest paths in this DAG, relaxed once in topological order
(:mod:`._lng_kernels`), end in the nodes of ``S(q_m)``; the ranked, non-overlapping
best of them are the matches. Time and memory O(km) after the kNN search; no dense
matrix anywhere. With all frames reachable through the neighbour sets the result equals
subsequence DTW (:mod:`.sdtw`) exactly.
"""
from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework.matching import QueryMatches, SearchSpace

from .graph import build_graph
from .matcher_base import GlobalMatcher, NeighborParams


def lazy_neighborhood_graph(query: np.ndarray, space: SearchSpace, *, k: int = 256, radius: float | None = None,
                            eps: float = 0.0, count: int = 10, max_cost: float | None = None,
                            rank_by: str = "cost", min_span: float = 0.5, propagate: int = 2,
                            gaps: int = 32, exact: bool = True, fill: bool = True, approx: float = 0.0,
                            direct_cells: int | None = None, seed_frames: int | None = None,
                            seed_k: int | None = None) -> QueryMatches:
    """Ranked non-overlapping matches of ``query`` (see :func:`build_graph`, :func:`.select_matches`).

    Defaults are the matcher's: ``exact`` (below), ``min_span`` 0.5. With ``exact=False``
    the graph itself answers (gap-tolerant, index searched on every second query frame
    with propagated sets between, ``fill``); the paper's LNG is ``exact=False, gaps=0,
    propagate=0, fill=False, min_span=0``.

    ``exact``: subsequence DTW's matches, certified (:func:`.exact.certified_sdtw`: a
    coarse-to-fine DP pruned by an admissible bound, its threshold from the index's
    neighbours of a few query frames; no graph is built, it would cost more than it
    saves). ``fill`` (``exact=False``): when the graph holds fewer than ``count`` matches,
    return the certified-exact search's instead (the graph's matches supply its threshold
    when there are ``count`` of them; it is verified either way). ``approx`` (``exact``
    only): the bounded approximation of :func:`.exact.certified_sdtw` (0: certified exact);
    ``direct_cells``, ``seed_frames``, ``seed_k``: as there (benchmarks force the pruned
    search on small databases, or vary the seeds).
    """
    from .exact import certified_sdtw

    if exact:
        return certified_sdtw(query, space, count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span,
                              approx=approx, direct_cells=direct_cells, seed_frames=seed_frames, seed_k=seed_k)
    graph = build_graph(query, space, k=k, radius=radius, eps=eps, propagate=propagate, gaps=gaps)
    res = graph.matches(count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span)
    if fill and len(res) < count and space.features is not None:
        return certified_sdtw(query, space, count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span,
                              graph=graph)
    return res


class LazyNeighborhoodGraph(GlobalMatcher):
    """Fast global motion matching by shortest paths in the lazy neighborhood graph.

    ``database`` is an index dataset (``indexes.*``); query motions are turned into
    features by the database's feature set, query features are used as they are.
    """

    name = "lng"
    needs_index: ClassVar[bool] = True
    needs_features: ClassVar[bool] = False

    class Params(NeighborParams):
        exact: bool = Field(True, description=(
            "certified-exact (default): exactly subsequence DTW's matches by a coarse-to-fine DP pruned with an "
            "admissible bound, no graph built (measured faster than the graph: docs/global-matching.md); false: the "
            "lazy neighborhood graph answers (k, gaps, propagate, fill; the paper's LNG: exact false, gaps 0, "
            "propagate 0, fill false)"))
        plots: int = Field(0, ge=0, description=(
            "write a Fig. 3-style PNG (plots/q<query>_m<rank>.png) for this many top matches per query"))
        plot_queries: int = Field(16, ge=0, description="plot only the first this many queries")

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        p = self.params
        return lazy_neighborhood_graph(query, space, k=p.k, radius=p.radius, eps=p.eps, count=p.count,
                                       max_cost=p.max_cost, rank_by=p.rank_by, min_span=p.min_span,
                                       propagate=p.propagate, gaps=p.gaps, exact=p.exact, fill=p.fill,
                                       approx=p.approx)

    def after_match(self, query_id, query, matches, space, ctx) -> None:
        p = self.params
        if not p.plots or query_id >= p.plot_queries or not len(matches):
            return
        from .plots import plot_neighborhood

        graph = build_graph(query.features, space, k=p.k, radius=p.radius, eps=p.eps, propagate=p.propagate,
                            gaps=p.gaps)  # cheap next to I/O; keeps match() lean
        for r in range(min(p.plots, len(matches))):
            plot_neighborhood(graph, matches, space, ctx.out_dir / "plots" / f"q{query_id}_m{r + 1}.png",
                              match=r, title=f"{query.name} - match {r + 1}, cost {matches.cost[r]:.3g}")
