"""What the Krüger matchers (``lng``, ``sdtw``, ``logical``) share beyond the core contract.

The step itself (search space, queries, match table) is the core's default
:meth:`~mocapflow.framework.components.Matcher.run`; here are the parameters of the lazy
neighborhood graph (:class:`NeighborParams`), when its extensions need the database
features (:meth:`GlobalMatcher.uses_features`) and the block boxes of the certified-exact
search, computed once per search space (:func:`block_boxes_of`, :func:`block_subspaces_of`).
"""
from __future__ import annotations

import numpy as np
from pydantic import Field

from mocapflow.framework import Matcher
from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import MatchParams, SearchSpace


class NeighborParams(MatchParams):
    """:class:`~mocapflow.framework.matching.MatchParams` plus the kNN search of the lazy neighborhood graph."""

    k: int = Field(256, ge=1, description="maximum neighbours per query frame (paper: k)")
    radius: float | None = Field(None, gt=0, description="fixed kNN search radius r in feature units; null: unbounded")
    eps: float = Field(0.0, ge=0, description=(
        "approximate kNN: neighbours within (1+eps) of the true ones (paper: 0, 0.1, 0.5; needs an index with eps)"))
    propagate: int = Field(2, ge=0, description=(
        "approximate neighbour sets (our extension): search the index only on every N-th query frame and take the "
        "k nearest of the rows reachable from the previous frame's set in between; 0: every frame (the paper); "
        "default 2: half the kNN searches at the gap-tolerant graph's quality (docs/global-matching.md)"))
    gaps: int = Field(32, ge=0, le=1000, description=(
        "gap-tolerant graph (our extension): cells within this many query frames after or before a neighbour cell "
        "join the graph, their distance computed exactly; a path may cross up to 2*gaps query frames without a "
        "neighbour cell; 0: the paper's graph (neighbour cells only)"))
    exact: bool = Field(False, description=(
        "certified-exact: return exactly subsequence DTW's matches by a coarse-to-fine DP pruned with an "
        "admissible bound, no graph built (rank_by cost; other rankings run the whole DP)"))
    approx: float = Field(0.0, ge=0, description=(
        "exact true: bounded approximation of the certified search (our extension); a block of rows is pruned when "
        "(1 + approx) x its lower bound exceeds the threshold, so the count-th cost is at most (1 + approx) x subsequence "
        "DTW's and every match is a real alignment with its exact cost; 0 (default): exactly subsequence DTW "
        "(docs/global-matching.md, 'Bounded approximation')"))
    fill: bool = Field(True, description=(
        "exact false: when the graph holds fewer than count matches, return the certified-exact search's instead"))


class GlobalMatcher(Matcher):
    """A core :class:`~mocapflow.framework.Matcher` whose graph extensions (``propagate``,
    ``gaps``, ``exact``, ``fill``) read the database features: the default step loads them
    when any is on. Subclasses set ``needs_index``/``needs_features`` and implement ``match``."""

    def uses_features(self) -> bool:
        p = self.params
        return self.needs_features or any(getattr(p, a, 0) for a in ("propagate", "gaps", "exact", "fill"))


def block_boxes_of(space: SearchSpace, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Row blocks of at most ``size`` rows within runs and their feature boxes, cached on
    the space (:func:`._coarse_kernels.block_boxes`; needs ``features``)."""
    if space.features is None:
        raise DataError("block boxes need the database features (SearchSpace.features)")

    def compute():
        from ._coarse_kernels import block_boxes

        return block_boxes(space.features, space.continues, int(size))

    return space.memo(("similarity.block_boxes", int(size)), compute)


def block_subspaces_of(space: SearchSpace, size: int, p: int) -> tuple[np.ndarray, ...]:
    """The local subspace cells ``(cen, basis, alo, ahi, rad)`` of the blocks of
    :func:`block_boxes_of` ``(space, size)`` with a basis of ``p`` directions, cached on the
    space (:func:`._subspace_kernels.block_subspaces`)."""
    def compute():
        from ._subspace_kernels import block_subspaces

        return block_subspaces(space.features, block_boxes_of(space, size)[0], int(p))

    return space.memo(("similarity.block_subspaces", int(size), int(p)), compute)
