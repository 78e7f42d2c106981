"""Numerical and logical similarity search (Krüger et al. 2010, §5.1; Kovar & Gleicher 2004).

A *numerical* search is one LNG search (:mod:`.lng`: the gap-tolerant graph, no fallback). A *logical* search iterates it:
the segments found in one round become the queries of the next ("use the set of found
similar motion segments as queries for new iterations"), so motions that are logically
similar but numerically far from the original query are reached through numerically
close intermediates. Every segment is reported once: a match overlapping a segment
already found (including the query's own segment when it comes from the database) is
dropped. The search stops after ``rounds`` rounds, when a round finds no new segment
(only matches within ``max_cost`` of their query count), or at ``max_matches`` segments.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from mocapflow.framework import Matcher
from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import IntervalSet, MatchParams, QueryMatches, SearchSpace

from .graph import GAPS, PROPAGATE
from .lng import MAX_K, lazy_neighborhood_graph
from .matcher_base import match_kw


@dataclass
class LogicalMatches(QueryMatches):
    """Matches of a logical search, in the order found.

    ``round`` is 1 for matches of the original query, r for matches of round-(r-1)
    segments; ``source`` is the position (in these arrays) of the segment that served as
    query, -1 for the original query.
    """

    round: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    source: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))

    def columns(self) -> dict[str, np.ndarray]:
        """``round`` and ``source_rank`` (rank of the match that served as query; 0: the
        original query)."""
        rank_of = np.r_[0, np.arange(1, len(self) + 1)].astype(np.int32)
        return {"round": np.asarray(self.round, np.int32), "source_rank": rank_of[np.asarray(self.source) + 1]}


def logical_search(
    query: np.ndarray,
    space: SearchSpace,
    *,
    rounds: int = 3,
    max_matches: int = 100,
    exclude: tuple[int, int] | None = None,
    k: int = 256,
    count: int = 10,
    max_cost: float | None = None,
    rank_by: str = "cost",
    min_span: float = 0.5,
    propagate: int = PROPAGATE,
    gaps: int = GAPS,
) -> LogicalMatches:
    """Iterated LNG search.

    Parameters
    ----------
    query : ndarray of shape (m, d)
    space : SearchSpace
        With ``index`` and ``features`` (found segments are re-used as queries).
    rounds : int
        Maximum number of search rounds (1: a plain numerical search).
    max_matches : int
        Stop once this many distinct segments were found.
    exclude : (int, int) or None
        Rows ``[start, end)`` not to report (the query's own segment in the database).
    k, count, max_cost, rank_by, min_span, propagate, gaps
        Per-query LNG parameters (:func:`.lng.lazy_neighborhood_graph`, no fallback); ``max_cost``
        also decides which matches count as found.
    """
    if space.features is None or space.index is None:
        raise DataError("logical search needs the database index and features (SearchSpace)")
    found = IntervalSet()
    if exclude is not None:
        found.add(exclude[0], exclude[1] - 1)
    rows: dict[str, list[Any]] = {
        "start": [],
        "end": [],
        "cost": [],
        "length": [],
        "paths": [],
        "round": [],
        "source": [],
    }
    frontier: list[tuple[np.ndarray, int]] = [(np.asarray(query, np.float32), -1)]
    for r in range(1, rounds + 1):
        new: list[tuple[np.ndarray, int]] = []
        for qx, src in frontier:
            res = lazy_neighborhood_graph(
                qx,
                space,
                k=k,
                count=count,
                max_cost=max_cost,
                rank_by=rank_by,
                min_span=min_span,
                propagate=propagate,
                gaps=gaps,
                fill=False,
            )
            for i in range(len(res)):
                s, e = int(res.start[i]), int(res.end[i])  # half-open
                if len(rows["start"]) >= max_matches or not found.add(s, e - 1):
                    continue
                pos = len(rows["start"])
                for key, val in (
                    ("start", s),
                    ("end", e),
                    ("cost", float(res.cost[i])),
                    ("length", int(res.length[i])),
                    ("paths", res.paths[i]),
                    ("round", r),
                    ("source", src),
                ):
                    rows[key].append(val)
                new.append((space.features[s:e], pos))
        if not new or len(rows["start"]) >= max_matches:
            break
        frontier = new
    return LogicalMatches(
        np.asarray(rows["start"], np.int64),
        np.asarray(rows["end"], np.int64),
        np.asarray(rows["cost"], np.float64),
        np.asarray(rows["length"], np.int64),
        rows["paths"],
        np.asarray(rows["round"], np.int32),
        np.asarray(rows["source"], np.int32),
    )


class LogicalSearch(Matcher):
    """Logical similarity search: LNG searches iterated on their own matches (§5.1).

    Output columns after the shared match columns: ``round`` and ``source_rank`` (rank of
    the match that served as query; 0 for the original query). ``cost`` and ``path``
    refer to the query that found the match. Needs the index and its features dataset.
    """

    name = "logical"
    needs_index: ClassVar[bool] = True
    needs_features: ClassVar[bool] = True

    class Params(MatchParams):
        k: int = Field(256, ge=1, le=MAX_K, description="maximum neighbours per query frame of each round's graph")
        rounds: int = Field(3, ge=1, description="maximum search rounds (1: numerical search only)")
        max_matches: int = Field(100, ge=1, description="stop once this many distinct segments were found")
        count: int = Field(10, ge=1, description="matches kept per query and round")
        max_cost: float | None = Field(
            None, ge=0, description="matches above this ranking cost are not found (stopping rule)"
        )
        rank_by: Literal["cost", "normalized"] = Field(
            "normalized",
            description=("rank by accumulated cost or by cost per path cell (comparable across query lengths)"),
        )

    params: Params

    def search(self, query: np.ndarray, space: SearchSpace, exclude: tuple[int, int] | None = None) -> LogicalMatches:
        p = self.params
        return logical_search(
            query,
            space,
            rounds=p.rounds,
            max_matches=p.max_matches,
            exclude=exclude,
            k=p.k,
            **match_kw(p),
        )

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        """The logical search of ``query``, never reporting the space's excluded rows (the
        query's own span, :attr:`~mocapflow.framework.SearchSpace.excluded`)."""
        ex = space.excluded
        return self.search(query, space, (ex[0], ex[1] + 1) if ex is not None else None)
