"""Global motion matching with the lazy neighborhood graph (Krüger et al. 2010, §4.1): ``matchers.lng``.

For a query ``Q = [q_1 .. q_m]``: a kNN search capped at ``k`` gives the neighbour set
``S(q_i)`` of every query frame; every reported neighbour is a node; the diagonal, vertical
and horizontal DTW steps between nodes are the edges (never across a clip boundary), each
costing the distance of the node it points at; a super-source points at all of ``S(q_1)``.
Shortest paths in this DAG, relaxed once in topological order (:mod:`._lng_kernels`), end in
the nodes of ``S(q_m)``; the ranked, non-overlapping best of them are the matches. With all
frames reachable through the neighbour sets the result equals subsequence DTW exactly.

By default the graph is gap-tolerant (:data:`GAPS` query frames of *gap cells* around the
neighbour cells, their cost computed exactly, :mod:`._gap_kernels`), searches the index on
every :data:`PROPAGATE`-th query frame only (the sets between propagated along the database),
and falls back to the certified search (:mod:`.certified`) when it holds fewer than ``count``
matches; ``paper: true`` is the paper's graph (neighbour cells only, every frame searched,
no fallback). For one more release ``matchers.lng`` without ``exact: false`` runs the
certified search (``matchers.search``) and warns.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework import Matcher, Removed
from mocapflow.framework.matching import MatchParams, QueryMatches, SearchSpace

from .graph import GAPS, PROPAGATE, K, build_graph
from .matcher_base import match_kw

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    from mocapflow.framework import StepContext

#: The most neighbours per query frame a graph may ask the index for: k x the query's frames
#: neighbour ids are held at once (4096 x a 1000-frame query: 33 MB).
MAX_K = 4096

DEPRECATED = (
    "matchers.lng runs the certified search for one more release; name matchers.search (same results) "
    "or set exact: false for the lazy neighbourhood graph"
)


def lazy_neighborhood_graph(
    query: np.ndarray,
    space: SearchSpace,
    *,
    k: int = 256,
    radius: float | None = None,
    count: int = 10,
    max_cost: float | None = None,
    rank_by: str = "cost",
    min_span: float = 0.5,
    propagate: int = PROPAGATE,
    gaps: int = GAPS,
    fill: bool = True,
) -> QueryMatches:
    """Ranked non-overlapping matches of ``query`` in its graph (:func:`.graph.build_graph`).

    ``fill``: when the graph holds fewer than ``count`` matches, return the certified search's
    instead (the graph's matches supply its threshold). The paper's LNG is ``gaps=0,
    propagate=0, fill=False, min_span=0``.
    """
    graph = build_graph(query, space, k=k, radius=radius, propagate=propagate, gaps=gaps)
    res = graph.matches(count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span, excluded=space.excluded)
    if fill and len(res) < count and space.features is not None:
        from .certified import certified_sdtw

        return certified_sdtw(
            query, space, count=count, max_cost=max_cost, rank_by=rank_by, min_span=min_span, graph=graph
        )
    return res


class LazyNeighborhoodGraph(Matcher):
    """Global motion matching by shortest paths in the lazy neighborhood graph.

    ``database`` is an index dataset (``indexes.*``); query motions are turned into
    features by the database's feature set, query features are used as they are.
    """

    name = "lng"
    needs_index: ClassVar[bool] = True
    needs_features: ClassVar[bool] = True

    class Params(MatchParams):
        k: int = Field(K, ge=1, le=MAX_K, description="maximum neighbours per query frame (paper: k)")
        paper: bool = Field(
            False,
            description=(
                "the paper's graph: neighbour cells only, the index searched for every query frame, no fallback; "
                f"false: gap-tolerant ({GAPS} query frames), propagated sets (every {PROPAGATE}nd frame searched), "
                "the certified search when the graph holds fewer than count matches"
            ),
        )
        exact: bool | None = Field(
            None,
            description=(
                "deprecated, one release: unset or true runs matchers.search (the certified search) with a warning; "
                "false: the lazy neighbourhood graph"
            ),
        )
        removed: ClassVar = {
            "plots": Removed(
                "the Fig. 3 pictures are matchers.search's `plots` parameter (same PNGs, plots/q<query>_m<rank>.png); "
                "matchers.lng still draws them for this release"
            )
        }

    params: Params

    def __init__(self, params: Any = None, **kw: Any) -> None:
        super().__init__(params, **kw)
        if self.params.exact is not False:
            warnings.warn(DEPRECATED, DeprecationWarning, stacklevel=2)

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        p = self.params
        if p.exact is not False:
            from .certified import certified_sdtw

            return certified_sdtw(query, space, **match_kw(p))
        if p.paper:  # the paper's graph: neighbour cells only, every query frame searched, no fallback
            return lazy_neighborhood_graph(query, space, k=p.k, **match_kw(p), propagate=0, gaps=0, fill=False)
        return lazy_neighborhood_graph(query, space, k=p.k, **match_kw(p))

    def after_match(
        self, query_id: int, query: Any, matches: QueryMatches, space: SearchSpace, ctx: StepContext
    ) -> None:
        """The deprecated ``plots`` (:attr:`Params.removed`): its pictures, of this matcher's graph."""
        n = int(self.params.removed_values().get("plots") or 0)
        if n:
            from .plots import plot_matches

            paper = {"propagate": 0, "gaps": 0} if self.params.paper else {}
            plot_matches(n, query_id, query, matches, space, ctx, k=self.params.k, **paper)

    def check_plan(self, base_dir: Path) -> list[str]:
        """The alias's warning at the step's line of the plan (and in the run log)."""
        return [DEPRECATED] if self.params.exact is not False else []
