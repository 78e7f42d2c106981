"""Certified-exact global matching (``matchers.search``): subsequence DTW's top matches, pruned by an admissible bound.

``certified_sdtw`` returns exactly what :func:`.sdtw.subsequence_dtw` returns while running
the DP only where a lower bound cannot rule out a path of cost <= ``tau`` (steps and proof:
docs/global-matching.md): ``tau`` from real alignments (:func:`_seed_tau`,
:func:`_guess_tau`); coarse bounds level by level over blocks of rows, boxes or subspace
cells (:mod:`._coarse_kernels`); the fine DP over the rows still alive
(:func:`._dtw_kernels.sdtw_ranges_compact`); the greedy selection, with ``tau`` doubled
(then unbounded) if it yields fewer than ``count``. :class:`CertifiedSettings` changes
speed only, never the result.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from mocapflow.framework import Matcher
from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import MatchParams, QueryMatches, SearchSpace, min_frames_of, select_matches

from .matcher_base import block_boxes_of, block_subspaces_of, match_kw
from .ranges import merged_ranges, ranges_dp

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework import StepContext

    from .graph import NeighborhoodGraph

#: box distances are shrunk by this relative margin: the fine DP's float32 distances may
#: round below the exact ones, and the bound must stay below them
_SHRINK = 1.0 - 1e-4
#: below this many DP cells a ranged DP stays on one thread (waking threads costs more)


@dataclass(frozen=True)
class CertifiedSettings:
    """How :func:`certified_sdtw` prunes (speed only: the result is sDTW's with any settings).

    The defaults are the measured best (docs/global-matching.md, "How the default was chosen").

    Attributes
    ----------
    levels : block sizes in rows, coarsest first (each rounded up to a multiple of the next)
    subspace : basis size of each level's local subspace cells, 0 for boxes; None: 3 at the
        16- and 4-row levels of the default ``levels``, boxes for any other hierarchy
    subspace_from : a level with a basis uses its subspace cells once this share of its blocks is in play
    seed_frames : query frames whose nearest rows seed ``tau`` (0: no seeds, lowest-bound blocks only)
    seed_k : neighbours per seed frame, times ``count``
    seed_eps : the seeds' neighbours are searched ``eps``-approximately where the index can
        (``"eps" in Index.query_options``): they only supply ``tau``, which the pass verifies
    seed_slope : database rows per query frame a seed window allows on either side of its neighbour
    full_from : share of alive rows from which a pass is the whole DP
    direct_cells : up to this many DP cells (rows x query frames) the whole DP runs at once
    """

    levels: tuple[int, ...] = (512, 64, 16, 4)
    subspace: tuple[int, ...] | None = None
    subspace_from: float = 0.3
    seed_frames: int = 5
    seed_k: int = 6
    seed_eps: float = 1.0
    seed_slope: float = 2.0
    full_from: float = 0.5
    direct_cells: int = 2_000_000

    def sizes(self) -> list[int]:
        """``levels``, each rounded up to a multiple of the next (its blocks tile the coarser ones)."""
        sizes = [int(b) for b in self.levels]
        for a in range(len(sizes) - 2, -1, -1):
            sizes[a] = -(-sizes[a] // sizes[a + 1]) * sizes[a + 1]
        return sizes

    def bases(self) -> tuple[int, ...]:
        if self.subspace is not None:
            if len(self.subspace) != len(self.levels):
                raise DataError(
                    f"subspace needs one basis size per level ({len(self.levels)}), got {len(self.subspace)}"
                )
            return tuple(int(p) for p in self.subspace)
        return (0, 0, 3, 3) if tuple(self.levels) == (512, 64, 16, 4) else (0,) * len(self.levels)


DEFAULT_SETTINGS = CertifiedSettings()


@dataclass
class ExactStats:
    """What one certified search did: ``tau`` used, fine DP columns computed (of ``n``), retries."""

    tau: float = np.inf
    columns: int = 0
    passes: int = 0
    retried: bool = False
    coarse_blocks: int = 0
    guess_columns: int = 0


def block_ranges(mask: np.ndarray) -> np.ndarray:
    """Index ranges ``[a, b)`` (int64 (r, 2)) of the runs of true entries of ``mask``."""
    if not mask.any():
        return np.zeros((0, 2), np.int64)
    edge = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.stack([np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)], axis=1).astype(np.int64)


def _seed_tau(
    q: np.ndarray,
    qt: np.ndarray,
    space: SearchSpace,
    count: int,
    max_cost: float | None,
    rank_by: str,
    min_frames: int,
    st: ExactStats,
    cfg: CertifiedSettings,
) -> float:
    """A threshold from real alignments around the nearest neighbours of a few query frames.

    ``cfg.seed_frames`` query frames spread over the query (first and last included) get
    their ``cfg.seed_k * count`` nearest rows from the index; a match through row ``h`` at
    query frame ``i`` lies within ``h - 2i .. h + 2(m - 1 - i)`` when it takes at most two
    database frames per query frame, so the fine DP runs over those windows (merged).
    Returns the ``count``-th cost of their selection, or inf when it holds fewer.
    """
    index = space.index
    assert index is not None  # the caller seeds only a space with an index
    m, n = len(q), space.n_rows
    frames = np.unique(np.linspace(0, m - 1, cfg.seed_frames).round().astype(np.int64))
    kk = min(n, cfg.seed_k * count)
    kw: dict[str, Any] = {}
    options: frozenset[str] = getattr(type(index), "query_options", frozenset())
    if "workers" in options:  # a few queries: waking threads costs more than it saves
        kw["workers"] = 1
    if "eps" in options and cfg.seed_eps > 0:  # any tau is safe: approximate neighbours only seed it
        kw["eps"] = cfg.seed_eps
    _, ids = index.query(np.ascontiguousarray(q[frames]), kk, **kw)
    ids = np.asarray(ids, np.int64)
    fi = np.broadcast_to(frames[:, None], ids.shape)
    ok = ids >= 0
    h, fi = ids[ok], fi[ok]
    sl = cfg.seed_slope
    ranges = merged_ranges(
        np.maximum(h - (sl * fi).astype(np.int64) - 2, 0), np.minimum(h + (sl * (m - 1 - fi)).astype(np.int64) + 3, n)
    )
    rows, cost, start, length = ranges_dp(qt, space, ranges)
    st.guess_columns += len(rows)
    keep = select_matches(
        rows,
        start,
        cost,
        length,
        count=count,
        max_cost=max_cost,
        rank_by=rank_by,
        min_frames=min_frames,
        excluded=space.excluded,
    )
    return float(cost[keep[-1]]) if len(keep) == count else np.inf


def _guess_tau(
    qt: np.ndarray,
    space: SearchSpace,
    lb: np.ndarray,
    blocks: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int],
    count: int,
    max_cost: float | None,
    rank_by: str,
    min_frames: int,
    st: ExactStats,
) -> float:
    """A threshold from real alignments: the fine DP over the blocks of lowest bound.

    The ``count`` blocks of lowest bound (with their linked neighbours, so that a match
    straddling a block edge is seen) get the fine DP; if its selection holds ``count``
    matches the last one's cost is returned, else four times more blocks are tried. Any
    value is safe (the caller verifies it); a low one prunes more.
    """
    bstart, _, _, link = blocks[:4]
    nb = len(lb)
    order = np.argsort(lb, kind="stable")
    take = count
    while True:
        sel = order[: min(take, nb)]
        sel = sel[np.isfinite(lb[sel])]
        mark = np.zeros(nb + 1, bool)
        mark[sel] = True
        mark[sel[link[sel]] - 1] = True  # the linked block before
        nxt = sel + 1
        nxt = nxt[nxt < nb]
        mark[nxt[link[nxt]]] = True  # the linked block after
        br = block_ranges(mark[:nb])
        rows, cost, start, length = ranges_dp(qt, space, bstart[br])
        st.guess_columns += len(rows)
        keep = select_matches(
            rows,
            start,
            cost,
            length,
            count=count,
            max_cost=max_cost,
            rank_by=rank_by,
            min_frames=min_frames,
            excluded=space.excluded,
        )
        if len(keep) == count:
            return float(cost[keep[-1]])
        if take >= nb:
            return np.inf
        take *= 4


def _level_bounds(
    qt: np.ndarray,
    space: SearchSpace,
    level: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int],
    branges: np.ndarray,
    sub_from: float = np.inf,
) -> np.ndarray:
    """The coarse bound of the blocks of ``branges`` at one level (``block_boxes_of`` plus a basis size).

    Local subspace cells (:func:`._coarse_kernels.subspace_bounds`) when the level has a basis
    and at least ``sub_from`` of its blocks are in play, box cells otherwise.
    """
    from ._coarse_kernels import coarse_bounds, subspace_bounds

    bstart, lo, hi, link, size, p = level
    if p > 0 and int((branges[:, 1] - branges[:, 0]).sum()) >= sub_from * len(lo):
        return subspace_bounds(qt, *block_subspaces_of(space, size, p), link, branges, _SHRINK)
    return coarse_bounds(qt, lo, hi, link, branges, _SHRINK)


def certified_sdtw(
    query: np.ndarray,
    space: SearchSpace,
    *,
    count: int = 10,
    max_cost: float | None = None,
    rank_by: str = "cost",
    min_span: float = 0.5,
    settings: CertifiedSettings = DEFAULT_SETTINGS,
    graph: NeighborhoodGraph | None = None,
    stats: ExactStats | None = None,
) -> QueryMatches:
    """Exactly :func:`.sdtw.subsequence_dtw`'s matches, by the pruned DP (see module doc).

    Parameters
    ----------
    query : ndarray of shape (m, d)
    space : SearchSpace
        With ``features`` (and an ``index`` for the seeds; without one ``tau`` comes from the
        lowest-bound blocks).
    count, max_cost, rank_by, min_span
        As :func:`mocapflow.framework.matching.select_matches`; ``rank_by="normalized"`` has no admissible
        cost bound here and runs the whole DP.
    settings : CertifiedSettings
        How it prunes (speed only).
    graph : NeighborhoodGraph, optional
        The lazy neighbourhood graph of this query, when already built: its ``count``-th match supplies ``tau``.
    stats : ExactStats, optional
        Filled with what the search did.
    """
    from ._coarse_kernels import alive_runs
    from ._dtw_kernels import dtw_window_path
    from .sdtw import validate_query

    cfg = settings
    if space.features is None:
        raise DataError("certified-exact search needs the database features")
    q = validate_query(query, space.features.shape[1])
    st = stats if stats is not None else ExactStats()
    min_frames = min_frames_of(min_span, len(q))
    ceiling = np.inf if (max_cost is None or rank_by != "cost") else float(max_cost)
    qt = np.ascontiguousarray(q.T)
    n = space.n_rows
    direct = n * len(q) <= cfg.direct_cells
    levels = (
        [] if direct else [block_boxes_of(space, b) + (b, p) for b, p in zip(cfg.sizes(), cfg.bases(), strict=True)]
    )
    lb_top = None
    tau = np.inf
    if rank_by == "cost" and not direct:
        found = (
            graph.matches(count=count, max_cost=max_cost, rank_by="cost", min_span=min_span, excluded=space.excluded)
            if graph is not None
            else None
        )
        if found is not None and len(found) == count:
            tau = float(found.cost[-1])
        elif space.index is not None and cfg.seed_frames > 0:
            tau = _seed_tau(q, qt, space, count, max_cost, rank_by, min_frames, st, cfg)
        if not np.isfinite(tau):
            bs = levels[0]
            lb_top = _level_bounds(qt, space, bs, np.array([[0, len(bs[1])]], np.int64), cfg.subspace_from)
            st.coarse_blocks += len(bs[1])
            tau = _guess_tau(qt, space, lb_top, bs, count, max_cost, rank_by, min_frames, st)
        if not np.isfinite(tau) and found is not None and len(found):  # a guess, verified below
            tau = 2.0 * float(found.cost[-1])
    tau = min(tau, ceiling)
    tries = 0
    while True:
        ranges = np.array([[0, n]], np.int64)
        if np.isfinite(tau) and not direct:
            ranges, lb_top = _alive_ranges(qt, space, levels, lb_top, tau, cfg, st, alive_runs)
            if (ranges[:, 1] - ranges[:, 0]).sum() >= cfg.full_from * n:
                tau = ceiling
                ranges = np.array([[0, n]], np.int64)
        rows, cost, start, length = ranges_dp(qt, space, ranges)
        st.tau, st.passes = tau, st.passes + 1
        st.columns += len(rows)
        sel = np.flatnonzero(cost <= tau)
        keep = select_matches(
            rows[sel],
            start[sel],
            cost[sel],
            length[sel],
            count=count,
            max_cost=max_cost,
            rank_by=rank_by,
            min_frames=min_frames,
            excluded=space.excluded,
        )
        if len(keep) == count or tau >= ceiling:
            break
        tries += 1
        tau, st.retried = (min(2.0 * tau, ceiling) if tries < 4 and tau > 0 else ceiling), True
    keep = sel[keep]
    out_end = rows[keep]
    paths = []
    for e, s in zip(out_end.tolist(), start[keep].tolist(), strict=True):
        path, _ = dtw_window_path(q, space.features[s : e + 1])
        path[:, 1] += s
        paths.append(path)
    return QueryMatches(start[keep], out_end + 1, cost[keep], length[keep].astype(np.int64), paths)


def _alive_ranges(
    qt: np.ndarray,
    space: SearchSpace,
    levels: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]],
    lb_top: np.ndarray | None,
    tau: float,
    cfg: CertifiedSettings,
    st: ExactStats,
    alive_runs: Callable[..., np.ndarray],
) -> tuple[np.ndarray, np.ndarray | None]:
    """Row ranges ``[a, b)`` still alive at ``tau`` after every level, and the first level's
    bound over all its blocks (``lb_top``, reused when given: a retry needs it again)."""
    br = None  # block ranges of the current level still in play (None: all)
    for li, level in enumerate(levels):
        bstart, lo = level[0], level[1]
        evaluated = np.array([[0, len(lo)]], np.int64) if br is None else br
        if br is None and li == 0 and lb_top is not None:
            lb = lb_top
        else:
            lb = _level_bounds(qt, space, level, evaluated, cfg.subspace_from)
            st.coarse_blocks += int((evaluated[:, 1] - evaluated[:, 0]).sum())
            if li == 0:
                lb_top = lb
        ranges = bstart[alive_runs(lb, evaluated, 1.0, tau)]
        if li + 1 < len(levels):  # the next level's blocks tile these rows exactly
            br = np.searchsorted(levels[li + 1][0], ranges)
    return ranges, lb_top


class CertifiedSearch(Matcher):
    """The default global search: exactly subsequence DTW's matches by the certified pruned DP.

    ``database`` is an index dataset (``indexes.*``: its nearest rows seed the threshold); query
    motions are turned into features by the database's feature set.
    """

    name = "search"
    needs_index: ClassVar[bool] = True
    needs_features: ClassVar[bool] = True

    class Params(MatchParams):
        mode: Literal["exact", "fast"] = Field(
            "exact",
            description=(
                "exact: subsequence DTW's matches (certified pruning); fast: filter-and-refine, the exact DP only "
                "where the index's neighbours vote (measured recall: docs/global-matching.md)"
            ),
        )
        plots: int = Field(
            0,
            ge=0,
            description=(
                "write a Fig. 3-style PNG (plots/q<query>_m<rank>.png: the query's kNN cells with the warping path) "
                "for this many top matches of each of the first 16 queries"
            ),
        )

    params: Params

    settings: ClassVar[CertifiedSettings] = DEFAULT_SETTINGS

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        if self.params.mode == "fast":
            from .fast import fast_sdtw

            return fast_sdtw(query, space, **match_kw(self.params), exact_search=certified_sdtw)
        return certified_sdtw(query, space, **match_kw(self.params), settings=self.settings)

    def after_match(
        self, query_id: int, query: Any, matches: QueryMatches, space: SearchSpace, ctx: StepContext
    ) -> None:
        from .plots import plot_matches

        plot_matches(self.params.plots, query_id, query, matches, space, ctx)
