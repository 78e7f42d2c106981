"""Certified-exact global matching: subsequence DTW's top matches, pruned by an admissible bound.

``certified_sdtw`` returns exactly what :func:`.sdtw.subsequence_dtw` returns (same matches,
costs, paths; any ``rank_by: cost`` setting) while running the DP only where a lower bound
cannot rule a path of cost <= ``tau`` out (proof: ``docs/global-matching.md``,
"Certified-exact mode"):

1. a threshold ``tau`` from real alignments with their exact costs: a given graph's
   ``count``-th match, else the fine DP over windows around the index's nearest rows of
   :data:`SEED_FRAMES` query frames (:func:`_seed_tau`; searched with ``eps`` :data:`SEED_EPS`),
   else over the blocks of lowest coarse bound (:func:`_guess_tau`); capped by ``max_cost``.
   Any value is safe (step 4);
2. a coarse subsequence DTW over blocks of consecutive rows, each cell costing the query
   frame's distance to the block's bounding box, bounds every fine path from below
   (forward + backward, :func:`._coarse_kernels.coarse_bounds`), level by level
   (:data:`LEVELS`: blocks of 512, 64, 16, 4 rows), each level only over the runs of
   blocks still alive (bound <= ``tau``) at the level above; where the levels above pruned
   little (:data:`SUBSPACE_FROM` of a level's blocks in play), the 16- and 4-row levels use
   *local subspace cells* instead of boxes (:data:`SUBSPACE`: a block's centre, 3 principal
   directions, the box of its rows' coordinates and their residual radius,
   :func:`._coarse_kernels.subspace_bounds`), tighter and 1.2-1.5x dearer per cell;
3. the fine DP (:func:`._dtw_kernels.sdtw_ranges_compact`, the arithmetic of
   ``sdtw_forward``) runs over the rows still alive; every end row whose best path costs
   <= ``tau`` gets exactly sDTW's cost, start and length;
4. the same greedy selection on those candidates yields ``count`` matches, which are then
   sDTW's; if it yields fewer, ``tau`` is doubled (three times at most), then set to
   ``max_cost`` (or unbounded: the whole DP, plain sDTW). Below :data:`DIRECT_CELLS` DP
   cells, and once half the rows are alive (:data:`FULL_FROM`), the whole DP runs at once.

``approx > 0`` is the bounded approximation: a block is pruned when ``(1 + approx) * LB >
tau``; every match is still a real alignment with its exact cost, the ``count``-th cost is
at most ``(1 + approx)`` times sDTW's, and the result is sDTW's whenever sDTW's ``count``-th
cost is at most ``tau / (1 + approx)`` (``approx = inf``: the seed windows alone). Measured
(docs/global-matching.md): with the recall constraint (>= 0.95 of sDTW's top-10, chosen leave
one actor out: 0.15) it saves 0-30 % of the time, so the default stays exact.

Measured and dropped: the bound suggested first (the sum of the remaining query frames'
1-NN distances, or per run of rows the k-th neighbour distance, with the first row's
surviving cells from a radius query): with k = 256 on 380,813 rows the k-th neighbour
distance is far below a match's cost per frame, and half the queries kept every row.
Also dropped (2026-12-02): ``tau`` from the full gap-tolerant graph (its kNN search alone
cost more than this whole search), ``tau`` from the lowest-bound blocks alone (loose: the
whole DP in most queries at 1 M rows), boxes in PCA-rotated coordinates (no tighter).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import QueryMatches, SearchSpace, min_frames_of, select_matches

from .matcher_base import block_boxes_of, block_subspaces_of

#: box distances are shrunk by this relative margin: the fine DP's float32 distances may
#: round below the exact ones, and the bound must stay below them
_SHRINK = 1.0 - 1e-4
#: default of ``certified_sdtw(full_from=)``: share of alive rows from which a pass is the whole DP
FULL_FROM = 0.5
#: below this many DP cells (rows x query frames) the whole DP runs at once: the seeds, the
#: coarse levels and the selection's Python work cost a few milliseconds, which the whole DP
#: at 100-200 M cells/s beats (HDM05 cuts, 4,419 rows: 0.5x sDTW's speed with the levels)
DIRECT_CELLS = 2_000_000
#: query frames whose nearest neighbours seed the threshold's windows (:func:`_seed_tau`)
SEED_FRAMES = 5
#: neighbours per seed frame, times ``count``
SEED_K = 6
#: the seeds' neighbours are searched epsilon-approximately (when the index takes ``eps``): they
#: only supply ``tau``, which the pass verifies; the exact 60-NN search was a fifth of a query's
#: time at 1 M rows (measured, docs/global-matching.md "fourth round": 3-20 % faster at 1.0, the
#: same ``tau`` median and work; 2.0 loosened ``tau`` in some queries)
SEED_EPS = 1.0
#: database frames per query frame a seed window allows on either side of its neighbour
SEED_SLOPE = 2.0
#: with ``V > 0``, the seed DP runs first over the windows of the ``V * count`` best-voted
#: clusters of neighbours (:mod:`._seed_votes`), over all windows only if those hold fewer than
#: ``count`` matches; 0: all windows at once
SEED_VOTE = 0
#: default block sizes of ``certified_sdtw``, coarsest first (benchmarks/matching.py: best of
#: (128, 16), (256, 32, 8), (512, 64, 8), (512, 64, 16, 4), (1024, 128, 16, 4) at 380 k and 1 M rows)
LEVELS = (512, 64, 16, 4)
#: basis size of each level's local subspace cells (0: boxes), as :data:`LEVELS`
#: (docs/global-matching.md, "sixth round")
SUBSPACE = (0, 0, 3, 3)
#: a level with a basis uses its subspace cells when at least this share of its blocks is in
#: play (the levels above pruned little), boxes otherwise (docs/global-matching.md, "sixth round")
SUBSPACE_FROM = 0.3


@dataclass
class ExactStats:
    """What one certified search did: ``tau`` used, fine DP columns computed (of ``n``), retries."""

    tau: float = np.inf
    columns: int = 0
    passes: int = 0
    retried: bool = False
    coarse_blocks: int = 0
    guess_columns: int = 0
    level_blocks: list = field(default_factory=list)


def block_ranges(mask: np.ndarray) -> np.ndarray:
    """Index ranges ``[a, b)`` (int64 (r, 2)) of the runs of true entries of ``mask``."""
    if not mask.any():
        return np.zeros((0, 2), np.int64)
    edge = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.stack([np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)], axis=1).astype(np.int64)


def clip_starts(space: SearchSpace) -> np.ndarray:
    """bool (n,): row ``j`` starts a clip (``~space.continues``), computed once per space."""
    return space.memo(("similarity.clip_starts",), lambda: ~space.continues)


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


def _query_params(index) -> frozenset:
    """Keyword names of ``index.query`` (cached per index class)."""
    import inspect

    cls = type(index)
    if cls not in _QUERY_PARAMS:
        _QUERY_PARAMS[cls] = frozenset(inspect.signature(index.query).parameters)
    return _QUERY_PARAMS[cls]


_QUERY_PARAMS: dict = {}


def _seed_tau(q, qt, space, count, max_cost, rank_by, min_frames, st, n_frames=None,
              k_per=None) -> tuple[float, tuple]:
    """A threshold from real alignments around the nearest neighbours of a few query frames.

    :data:`SEED_FRAMES` query frames spread over the query (first and last included) get
    their ``SEED_K * count`` nearest rows from the index; a match through row ``h`` at query frame ``i`` lies
    within ``h - 2i .. h + 2(m - 1 - i)`` when it takes at most two database frames per
    query frame, so the fine DP runs over those windows (merged). Returns the
    ``count``-th cost of their selection, or inf when it holds fewer.
    """
    from ._dtw_kernels import sdtw_ranges_compact

    m, n = len(q), space.n_rows
    frames = np.unique(np.linspace(0, m - 1, n_frames or SEED_FRAMES).round().astype(np.int64))
    kk = min(n, (k_per or SEED_K) * count)
    qs = np.ascontiguousarray(q[frames])
    kw = {}
    params = _query_params(space.index)
    if "workers" in params:  # a few queries: waking threads costs more than it saves
        kw["workers"] = 1
    if "eps" in params and SEED_EPS > 0:  # any tau is safe: approximate neighbours only seed it
        kw["eps"] = SEED_EPS
    dist, ids = space.index.query(qs, kk, **kw)
    ids = np.asarray(ids, np.int64)
    if SEED_VOTE > 0:
        from ._seed_votes import voted_windows

        run_of = space.memo(("similarity.run_of",), lambda: np.cumsum(~space.continues) - 1)
        ranges = merged_ranges(*voted_windows(frames, ids, dist, run_of, m, n, SEED_SLOPE, max(4, m // 8),
                                                    SEED_VOTE * count))
        rows, cost, start, length = sdtw_ranges_compact(qt, space.features, clip_starts(space), ranges)
        st.guess_columns += len(rows)
        keep = select_matches(rows, start, cost, length, count=count, max_cost=max_cost, rank_by=rank_by,
                              min_frames=min_frames)
        if len(keep) == count:
            return float(cost[keep[-1]]), (rows, cost, start, length)
    fi = np.broadcast_to(frames[:, None], ids.shape)
    ok = ids >= 0
    h, fi = ids[ok], fi[ok]
    sl = SEED_SLOPE
    ranges = merged_ranges(np.maximum(h - (sl * fi).astype(np.int64) - 2, 0),
                           np.minimum(h + (sl * (m - 1 - fi)).astype(np.int64) + 3, n))
    rows, cost, start, length = sdtw_ranges_compact(qt, space.features, clip_starts(space), ranges)
    st.guess_columns += len(rows)
    keep = select_matches(rows, start, cost, length, count=count, max_cost=max_cost, rank_by=rank_by,
                          min_frames=min_frames)
    return (float(cost[keep[-1]]) if len(keep) == count else np.inf), (rows, cost, start, length)


def merged_candidates(a: tuple, b: tuple) -> tuple:
    """Candidates ``(rows, cost, start, length)`` of two fine DP passes, one per row: the lower
    cost (``a``'s on ties), rows ascending. Both are costs of real paths into their row."""
    rows, cost, start, length = (np.concatenate([u, v]) for u, v in zip(a, b))
    src = np.r_[np.zeros(len(a[0]), np.int8), np.ones(len(b[0]), np.int8)]
    o = np.lexsort((src, cost, rows))
    first = np.r_[True, rows[o][1:] != rows[o][:-1]]
    o = o[first]
    return rows[o], cost[o], start[o], length[o]


def _guess_tau(qt, space, lb, blocks, count, max_cost, rank_by, min_frames, st) -> float:
    """A threshold from real alignments: the fine DP over the blocks of lowest bound.

    The ``count`` blocks of lowest bound (with their linked neighbours, so that a match
    straddling a block edge is seen) get the fine DP; if its selection holds ``count``
    matches the last one's cost is returned, else four times more blocks are tried. Any
    value is safe (the caller verifies it); a low one prunes more.
    """
    from ._dtw_kernels import sdtw_ranges_compact

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
        rows, cost, start, length = sdtw_ranges_compact(qt, space.features, clip_starts(space), bstart[br])
        st.guess_columns += len(rows)
        keep = select_matches(rows, start, cost, length, count=count, max_cost=max_cost, rank_by=rank_by,
                              min_frames=min_frames)
        if len(keep) == count:
            return float(cost[keep[-1]])
        if take >= nb:
            return np.inf
        take *= 4


def _level_bounds(qt, space, level, branges, sub_from=np.inf) -> np.ndarray:
    """The coarse bound of the blocks of ``branges`` at one level (``block_boxes_of`` plus a basis size).

    Local subspace cells (:func:`._coarse_kernels.subspace_bounds`) when the level has a basis
    and at least ``sub_from`` of its blocks are in play, box cells otherwise.
    """
    from ._coarse_kernels import coarse_bounds, subspace_bounds

    bstart, lo, hi, link, size, p = level
    if p > 0 and int((branges[:, 1] - branges[:, 0]).sum()) >= sub_from * len(lo):
        return subspace_bounds(qt, *block_subspaces_of(space, size, p), link, branges, _SHRINK)
    return coarse_bounds(qt, lo, hi, link, branges, _SHRINK)


def certified_sdtw(query: np.ndarray, space: SearchSpace, *, count: int = 10, max_cost: float | None = None,
                   rank_by: str = "cost", min_span: float = 0.5, k: int = 256, gaps: int = 32, block: int = 16,
                   top: int | None = None, graph=None, stats: ExactStats | None = None,
                   full_from: float | None = None, seeds: bool = True,
                   levels: tuple[int, ...] | None = None, direct_cells: int | None = None,
                   approx: float = 0.0, seed_frames: int | None = None, seed_k: int | None = None,
                   subspace: tuple[int, ...] | None = None, subspace_from: float | None = None) -> QueryMatches:
    """Exactly :func:`.sdtw.subsequence_dtw`'s matches, by the pruned DP (see module doc).

    Parameters
    ----------
    query : ndarray of shape (m, d)
    space : SearchSpace
        With ``features`` (and ``index`` when ``graph`` is not given and ``top`` is 0).
    count, max_cost, rank_by, min_span
        As :func:`mocapflow.framework.matching.select_matches`; ``rank_by="normalized"`` has no admissible
        cost bound here and runs the whole DP.
    k, gaps
        kNN sets and gap band of the LNG that supplies ``tau`` when ``top`` is 0
        (:func:`.graph.build_graph`).
    block, top : int
        With ``top`` given: two levels, blocks of ``top`` rows (rounded up to a multiple of
        ``block``) then of ``block`` rows; ``top = 0``: one level of ``block`` rows with ``tau``
        from the LNG (the first certified mode). Default (``top`` None): :data:`LEVELS`.
    levels : tuple of int, optional
        Block sizes from coarsest to finest (each rounded up to a multiple of the next),
        overriding ``(top, block)``; e.g. ``(256, 32, 8)``. The lowest-bound blocks of the
        coarsest level supply ``tau`` when neither ``graph`` nor the seeds do
        (:func:`_guess_tau`).
    subspace : tuple of int, optional
        Basis size of each level's local subspace cells, 0 for boxes (default: :data:`SUBSPACE`
        with the default :data:`LEVELS`, boxes with any other hierarchy). Speed only.
    subspace_from : float, optional
        (Default :data:`SUBSPACE_FROM`.) A level with a basis uses subspace cells once this share
        of its blocks is still in play, box cells below it. Speed only.
    seeds : bool
        Take ``tau`` from the windows around the index's neighbours of a few query frames
        (:func:`_seed_tau`) before the lowest-bound blocks.
    graph : NeighborhoodGraph, optional
        The LNG of this query, when already built (any sets: it only supplies ``tau``).
    stats : ExactStats, optional
        Filled with what the search did.
    full_from : float, optional
        (Default :data:`FULL_FROM`.) When the alive rows of a pass reach this share of the database, that pass is the
        whole DP with no threshold (the last pass: a pruned pass, then retries, would cost
        more than sDTW itself). Speed only; the result is sDTW's either way.
    direct_cells : int, optional
        (Default :data:`DIRECT_CELLS`.) Up to this many DP cells (rows x query frames) the
        whole DP runs at once, with no threshold. Speed only.
    approx : float
        Bounded approximation (0: certified exact). A block is pruned when ``(1 + approx) *
        LB > tau``, so every path left out costs more than ``tau / (1 + approx)``; what a user
        can rely on (docs/global-matching.md, "Bounded approximation"): every match is a real
        alignment with its exact cost, the ``count``-th cost is at most ``(1 + approx)`` times
        sDTW's, and the result is sDTW's whenever sDTW's ``count``-th cost is at most
        ``tau / (1 + approx)``.
    seed_frames, seed_k : int, optional
        (Defaults :data:`SEED_FRAMES`, :data:`SEED_K`.) Query frames searched for the seeds, and
        neighbours per frame (times ``count``).
    """
    from ._coarse_kernels import alive_runs
    from ._dtw_kernels import dtw_window_path, sdtw_ranges_compact
    from .graph import build_graph
    from .sdtw import validate_query

    if not levels:
        levels = LEVELS if top is None else ((top, block) if top else (block,))
    sizes = [int(b) for b in levels]
    for a in range(len(sizes) - 2, -1, -1):  # each a multiple of the next: its blocks tile the coarser ones
        sizes[a] = -(-sizes[a] // sizes[a + 1]) * sizes[a + 1]
    top = sizes[0] if len(sizes) > 1 else 0
    if space.features is None or (space.index is None and graph is None and not top):
        raise DataError("certified-exact search needs the database features (and an index with one level)")
    q = validate_query(query, space.features.shape[1])
    st = stats if stats is not None else ExactStats()
    full_from = FULL_FROM if full_from is None else float(full_from)
    min_frames = min_frames_of(min_span, len(q))
    ceiling = np.inf if (max_cost is None or rank_by != "cost") else float(max_cost)
    qt = np.ascontiguousarray(q.T)
    n = space.n_rows
    scale = 1.0 + float(approx)  # alive when scale * LB <= tau
    if not scale >= 1.0:
        raise DataError(f"approx must be >= 0, got {approx}")
    direct = n * len(q) <= (DIRECT_CELLS if direct_cells is None else direct_cells)
    if subspace is None:
        subspace = SUBSPACE if len(sizes) == len(LEVELS) and sizes == list(LEVELS) else (0,) * len(sizes)
    if len(subspace) != len(sizes):
        raise DataError(f"subspace needs one basis size per level ({len(sizes)}), got {len(subspace)}")
    levels = [] if direct else [block_boxes_of(space, b) + (b, int(p)) for b, p in zip(sizes, subspace)]
    sub_from = SUBSPACE_FROM if subspace_from is None else float(subspace_from)
    lb_top = None
    tau = np.inf
    seeded = None  # the seed windows' candidates, whose selection gave tau: an approximate pass keeps them
    if rank_by == "cost" and not direct:
        if graph is None and not top:
            graph = build_graph(q, space, k=min(k, n), gaps=gaps)
        found = graph.matches(count=count, max_cost=max_cost, rank_by="cost", min_span=min_span) \
            if graph is not None else None
        if found is not None and len(found) == count:
            tau = float(found.cost[-1])
        elif top and space.index is not None and seeds:
            tau, seeded = _seed_tau(q, qt, space, count, max_cost, rank_by, min_frames, st, seed_frames,
                                     seed_k)
        if not np.isfinite(tau) and top:
            bs = levels[0]
            lb_top = _level_bounds(qt, space, bs, np.array([[0, len(bs[1])]], np.int64), sub_from)
            st.coarse_blocks += len(bs[1])
            tau = _guess_tau(qt, space, lb_top, bs, count, max_cost, rank_by, min_frames, st)
        if not np.isfinite(tau) and found is not None and len(found):  # a guess, verified below: too few matches under it doubles it
            tau = 2.0 * float(found.cost[-1])
    tau = min(tau, ceiling)
    tries = 0
    while True:
        ranges = np.array([[0, n]], np.int64)
        if np.isfinite(tau) and not direct and np.isinf(scale) and seeded is not None:
            ranges = np.zeros((0, 2), np.int64)  # approx inf: the seed windows alone (no bound computed)
        elif np.isfinite(tau) and not direct:
            br = None  # block ranges of the current level still in play (None: all)
            for li, level in enumerate(levels):
                bstart, lo = level[0], level[1]
                evaluated = np.array([[0, len(lo)]], np.int64) if br is None else br
                if br is None:
                    if li == 0 and lb_top is not None:
                        lb = lb_top
                    else:
                        lb = _level_bounds(qt, space, level, evaluated, sub_from)
                        st.coarse_blocks += len(lo)
                        if li == 0 and top:
                            lb_top = lb
                else:
                    lb = _level_bounds(qt, space, level, br, sub_from)
                    st.coarse_blocks += int((br[:, 1] - br[:, 0]).sum())
                    st.level_blocks.append(int((br[:, 1] - br[:, 0]).sum()))
                alive = alive_runs(lb, evaluated, scale, tau)
                ranges = bstart[alive]
                if li + 1 < len(levels):  # the next level's blocks tile these rows exactly
                    br = np.searchsorted(levels[li + 1][0], ranges)
            if (ranges[:, 1] - ranges[:, 0]).sum() >= full_from * n:
                tau = ceiling
                ranges = np.array([[0, n]], np.int64)
        rows, cost, start, length = sdtw_ranges_compact(qt, space.features, clip_starts(space), ranges)
        st.tau, st.passes = tau, st.passes + 1
        st.columns += len(rows)
        whole = len(ranges) == 1 and ranges[0, 0] == 0 and ranges[0, 1] == n
        if scale > 1.0 and seeded is not None and not whole:
            # the (1 + approx) pruning may rule out the very windows that gave tau: their candidates
            # (real paths, cost >= the true best into their row) join, so count matches <= tau remain
            rows, cost, start, length = merged_candidates((rows, cost, start, length), seeded)
        sel = np.flatnonzero(cost <= tau)
        keep = select_matches(rows[sel], start[sel], cost[sel], length[sel], count=count, max_cost=max_cost,
                              rank_by=rank_by, min_frames=min_frames)
        if len(keep) == count or tau >= ceiling:
            break
        tries += 1
        tau, st.retried = (min(2.0 * tau, ceiling) if tries < 4 and tau > 0 else ceiling), True
    keep = sel[keep]
    out_end = rows[keep]
    paths = []
    for e, s in zip(out_end.tolist(), start[keep].tolist()):
        path, _ = dtw_window_path(q, space.features[s : e + 1])
        path[:, 1] += s
        paths.append(path)
    return QueryMatches(start[keep], out_end + 1, cost[keep], length[keep].astype(np.int64), paths)
