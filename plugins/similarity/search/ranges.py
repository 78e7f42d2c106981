"""Subsequence-DTW columns over row ranges of a search space: the fine DP that the exact
(:mod:`.certified`), fast (:mod:`.fast`) and plain (:mod:`.sdtw`) searches share."""

from __future__ import annotations

from typing import cast

import numpy as np

from mocapflow.framework.matching import SearchSpace

#: cells (rows x query frames) from which :func:`ranges_dp` spreads ranges over numba's threads
_PARALLEL_CELLS = 4_000_000


def clip_starts(space: SearchSpace) -> np.ndarray:
    """bool (n,): row ``j`` starts a clip (``~space.continues``), computed once per space."""
    return cast("np.ndarray", space.memo(("similarity.clip_starts",), lambda: ~space.continues))


def merged_ranges(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Union of the row ranges ``[lo, hi)`` as sorted disjoint ranges, int64 (r, 2)."""
    if not len(lo):
        return np.zeros((0, 2), np.int64)
    o = np.argsort(lo, kind="stable")
    lo, hi = lo[o], np.maximum.accumulate(hi[o])
    new = np.r_[True, lo[1:] > hi[:-1]]
    first = np.flatnonzero(new)
    last = np.r_[first[1:] - 1, len(lo) - 1]
    return np.stack([lo[first], hi[last]], axis=1).astype(np.int64)


def run_starts(space: SearchSpace) -> np.ndarray:
    """int64 (r + 1,): first row of every run of consecutive rows (clip), then ``n``."""
    return cast(
        "np.ndarray",
        space.memo(
            ("similarity.run_starts",), lambda: np.r_[np.flatnonzero(~space.continues), space.n_rows].astype(np.int64)
        ),
    )


def ranges_dp(
    qt: np.ndarray, space: SearchSpace, ranges: np.ndarray, threads: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The fine DP over row ranges (:func:`._dtw_kernels.sdtw_ranges_compact`): ``rows, cost,
    start, length``. With several numba threads (``threads``, default: numba's) and at least
    ``_PARALLEL_CELLS`` cells, long ranges are cut at clip starts and groups of ranges of about
    equal rows run on the threads (:func:`._dtw_kernels.sdtw_ranges_parallel`): the same values."""
    import numba

    from ._dtw_kernels import sdtw_ranges_compact, sdtw_ranges_parallel

    feats = space.features
    if feats is None:
        from mocapflow.framework.errors import DataError

        raise DataError("the DP over row ranges needs the database features (SearchSpace.features)")
    t = numba.get_num_threads() if threads is None else int(threads)
    total = int((ranges[:, 1] - ranges[:, 0]).sum())
    if t <= 1 or total * qt.shape[1] < _PARALLEL_CELLS:
        return sdtw_ranges_compact(qt, feats, clip_starts(space), ranges)
    parts = 4 * t
    rs = run_starts(space)
    share = max(1, total // parts)
    long = (ranges[:, 1] - ranges[:, 0]) > share
    if long.any():  # a range longer than its share is cut at clip starts (each piece starts afresh there anyway)
        pieces = [ranges[~long]]
        for a, b in ranges[long].tolist():
            inside = rs[np.searchsorted(rs, a, "right") : np.searchsorted(rs, b, "left")]
            at = np.unique(np.searchsorted(inside, np.arange(a + share, b, share)))
            e = np.r_[a, inside[at[at < len(inside)]], b]
            pieces.append(np.stack([e[:-1], e[1:]], axis=1))
        ranges = np.concatenate(pieces)
        ranges = ranges[np.argsort(ranges[:, 0], kind="stable")]
    cum = np.cumsum(ranges[:, 1] - ranges[:, 0])
    bounds = np.searchsorted(cum, np.linspace(0, cum[-1], parts + 1)[1:-1], "right")
    groups = np.unique(np.r_[0, bounds, len(ranges)]).astype(np.int64)
    return sdtw_ranges_parallel(qt, feats, clip_starts(space), np.ascontiguousarray(ranges, np.int64), groups)
