"""The block boxes and local subspace cells of the certified search, computed once per search
space (:func:`block_boxes_of`, :func:`block_subspaces_of`). The matchers' step itself (search
space, queries, match table) is the core's default
:meth:`~mocapflow.framework.components.Matcher.run`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import SearchSpace

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.matching import MatchParams


def match_kw(p: MatchParams) -> dict[str, Any]:
    """The shared :class:`MatchParams` as keywords of the matching functions."""
    return {"count": p.count, "max_cost": p.max_cost, "rank_by": p.rank_by, "min_span": p.min_span}


def block_boxes_of(space: SearchSpace, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Row blocks of at most ``size`` rows within runs and their feature boxes, cached on
    the space (:func:`._coarse_kernels.block_boxes`; needs ``features``)."""
    feats = space.features
    if feats is None:
        raise DataError("block boxes need the database features (SearchSpace.features)")

    def compute() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        from ._coarse_kernels import block_boxes

        return block_boxes(feats, space.continues, int(size))

    return cast(
        "tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]",
        space.memo(("similarity.block_boxes", int(size)), compute),
    )


def block_subspaces_of(
    space: SearchSpace, size: int, p: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The local subspace cells ``(cen, basis, alo, ahi, rad)`` of the blocks of
    :func:`block_boxes_of` ``(space, size)`` with a basis of ``p`` directions, cached on the
    space (:func:`._subspace_kernels.block_subspaces`)."""

    boxes = block_boxes_of(space, size)  # refuses a space without features

    def compute() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        from ._subspace_kernels import block_subspaces

        assert space.features is not None
        return block_subspaces(space.features, boxes[0], int(p))

    return cast(
        "tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]",
        space.memo(("similarity.block_subspaces", int(size), int(p)), compute),
    )
