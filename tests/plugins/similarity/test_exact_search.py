"""Certified-exact search (``matchers.search``): identical to subsequence DTW (synthetic and real data), pruning checked."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from naive.coarse import naive_boxes, naive_coarse_bounds, naive_sdtw_ranges
from naive.dtw import continues_of, naive_blocks, naive_through_cell
from test_lng import BruteIndex
from test_sdtw import make_db

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search._coarse_kernels import block_boxes, coarse_bounds
from mocapflow.plugins.similarity.search._dtw_kernels import sdtw_forward, sdtw_ranges_compact
from mocapflow.plugins.similarity.search.certified import CertifiedSettings, ExactStats, certified_sdtw
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"


def pruned(**kw) -> CertifiedSettings:
    """Settings that run the pruned search even on a tiny database (``direct_cells`` 0)."""
    return CertifiedSettings(direct_cells=0, **kw)


def same(a, b):
    np.testing.assert_array_equal(a.start, b.start)
    np.testing.assert_array_equal(a.end, b.end)
    np.testing.assert_array_equal(a.cost, b.cost)
    np.testing.assert_array_equal(a.length, b.length)
    for p, r in zip(a.paths, b.paths, strict=True):
        np.testing.assert_array_equal(p, r)


def tie_db(lengths, seed):
    """One-dimensional small integers: many equal-cost paths, every distance and sum exact in float32 and float64."""
    clip_id = np.concatenate([np.full(n, c) for c, n in enumerate(lengths)]).astype(np.int32)
    frame = np.concatenate([np.arange(n) for n in lengths]).astype(np.int32)
    return clip_id, frame, np.random.default_rng(seed).integers(0, 3, (len(clip_id), 1)).astype(np.float32)


def query_of(x, m, seed, ties=False):
    rng = np.random.default_rng(seed)
    if ties:
        return rng.integers(0, 3, (m, 1)).astype(np.float32)
    return (x[rng.integers(0, len(x), m)] + rng.normal(0, 0.2, (m, x.shape[1]))).astype(np.float32)


# random walks; a 1-row clip (single-row blocks); blocks of 1 row; queries longer than blocks and clips; ties
BOUND_CASES = [
    (0, [40, 1, 30, 12], 6, 4, False),
    (1, [80], 10, 16, False),
    (2, [5, 5, 5, 60], 3, 7, False),
    (3, [50, 50], 1, 3, False),
    (4, [7, 1, 1, 20], 12, 1, False),
    (5, [30, 2, 25], 9, 5, True),
    (6, [60], 4, 60, True),
    (7, [45, 30], 150, 8, False),
]  # long query: float32 chains' margin


@pytest.mark.parametrize("seed,lengths,m,size,ties", BOUND_CASES)
def test_block_boxes_equal_naive(seed, lengths, m, size, ties):
    clip_id, frame, x = (tie_db if ties else make_db)(lengths, seed=seed)
    cont = continues_of(clip_id, frame)
    bstart, lo, hi, link = block_boxes(x, cont, size)
    block, nlo, nhi, nlink = naive_boxes(x, cont, size)
    np.testing.assert_array_equal(np.searchsorted(bstart, np.arange(len(x)), side="right") - 1, block)
    np.testing.assert_array_equal(lo, nlo)
    np.testing.assert_array_equal(hi, nhi)
    np.testing.assert_array_equal(link, nlink)


@pytest.mark.parametrize("seed,lengths,m,size,ties", BOUND_CASES)
def test_coarse_bounds_equal_naive_and_are_admissible(seed, lengths, m, size, ties):
    clip_id, frame, x = (tie_db if ties else make_db)(lengths, seed=seed)
    q = query_of(x, m, seed, ties)
    qt = np.ascontiguousarray(q.T)
    cont = continues_of(clip_id, frame)
    bstart, lo, hi, link = block_boxes(x, cont, size)
    block = naive_blocks(cont, size)
    nb = len(lo)
    shrink = 1.0 - 1e-4
    lb = coarse_bounds(qt, lo, hi, link, np.array([[0, nb]], np.int64), shrink)
    naive = naive_coarse_bounds(q, x, cont, size, shrink=shrink)
    rtol = 1e-5 + 4 * m * 2.0**-24  # the kernel's float32 margin (coarse_bounds docstring)
    np.testing.assert_allclose(lb, naive, rtol=rtol, atol=1e-6)
    assert np.all(lb <= naive * (1 + 1e-9) + 1e-12)  # the margin is taken below, never above
    # a lower bound of the best path through every row of the block
    through = naive_through_cell(q, x, cont).min(axis=0)
    assert np.all(lb[block] <= through * (1 + 1e-9))
    for tau in (float(np.quantile(through, 0.2)), float(np.quantile(through, 0.7)), float(through.min()) * 1.001):
        # restricted to the alive runs (started afresh), the bound still keeps every row of a path <= tau
        alive = lb <= tau
        assert np.all(alive[block[through <= tau]])
        edge = np.diff(np.r_[0, alive.astype(np.int8), 0])
        br = np.stack([np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)], axis=1).astype(np.int64)
        sub = coarse_bounds(qt, lo, hi, link, br, shrink)
        np.testing.assert_allclose(sub, naive_coarse_bounds(q, x, cont, size, br, shrink), rtol=rtol, atol=1e-6)
        assert np.all(sub[block[through <= tau]] <= tau) and np.all(np.isinf(sub[~alive]))


def check_ranges_against_naive(q, x, cont, ranges, exact_costs):
    rows, cost, start, length = sdtw_ranges_compact(np.ascontiguousarray(q.T), x, ~cont, ranges)
    nrows, ncost, nstart, nlength = naive_sdtw_ranges(q, x, cont, ranges)
    np.testing.assert_array_equal(rows, nrows)
    if exact_costs:
        np.testing.assert_array_equal(cost, ncost)
    else:
        np.testing.assert_allclose(cost, ncost, rtol=1e-6)
    np.testing.assert_array_equal(start, nstart)
    np.testing.assert_array_equal(length, nlength)


# random walks; ties; 1-row ranges and clips; queries longer than every range
RANGE_CASES = [
    (0, [40, 1, 30, 12], 6, False),
    (1, [80], 10, False),
    (3, [50, 50], 1, False),
    (4, [40, 1, 30, 12], 7, True),
    (5, [3, 90], 25, True),
    (6, [20, 20, 20], 30, False),
]


@pytest.mark.parametrize("seed,lengths,m,ties", RANGE_CASES)
def test_sdtw_ranges_compact_equals_naive(seed, lengths, m, ties):
    clip_id, frame, x = (tie_db if ties else make_db)(lengths, seed=seed)
    q = query_of(x, m, seed, ties)
    cont = continues_of(clip_id, frame)
    n = len(x)
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.choice(np.arange(1, n - 1), 6, replace=False))
    for ranges in (
        [[0, 7], [9, 30], [31, n]],
        [[0, n]],
        [[0, 1], [1, 2], [5, 6], [n - 1, n]],
        [[cuts[0], cuts[1]], [cuts[2], cuts[3]], [cuts[4], cuts[5] + 1]],
    ):
        check_ranges_against_naive(q, x, cont, np.array(ranges, np.int64), exact_costs=ties)


@pytest.mark.skipif(not (DATA / "hdm05" / "amc").is_dir(), reason="needs the development corpus ../shared/data (HDM05)")
def test_coarse_kernels_equal_naive_on_hdm05():
    from mocapflow.framework import MotionDatabase
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    files = sorted((DATA / "hdm05" / "amc").glob("*/*.amc"))[:2]
    db = MotionDatabase([resample(read_amc(f), 30.0) for f in files])
    x = EndEffectorFeatures(joints=5).transform(db)
    clip_id, frame = db.frame_ids
    assert db.n_clips == 2  # so one clip boundary
    cont = continues_of(clip_id, frame)
    n = len(x)
    q = x[n // 2 : n // 2 + 24] + np.float32(0.05)
    check_ranges_against_naive(q, x, cont, np.array([[0, n // 3], [n // 3 + 10, n]], np.int64), exact_costs=False)
    bstart, lo, hi, link = block_boxes(x, cont, 16)
    lb = coarse_bounds(np.ascontiguousarray(q.T), lo, hi, link, np.array([[0, len(lo)]], np.int64), 1.0 - 1e-4)
    np.testing.assert_allclose(lb, naive_coarse_bounds(q, x, cont, 16, shrink=1.0 - 1e-4), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("levels,seed_frames", [((512, 64, 16, 4), 5), ((8, 4), 5), ((12, 5, 2), 0), ((6,), 5)])
def test_certified_levels_equal_sdtw(seed, levels, seed_frames):
    # any block hierarchy, tau from the seeds or from the lowest-bound blocks: sDTW's matches
    clip_id, frame, x = make_db([60, 3, 90, 40, 70, 25], seed=seed)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    rng = np.random.default_rng(seed)
    s = int(rng.integers(0, 150))
    q = (x[s : s + 12] + rng.normal(0, 0.3, (12, 3))).astype(np.float32)
    for count, max_cost in ((1, None), (6, None), (9, 10.0)):
        got = certified_sdtw(
            q, space, count=count, max_cost=max_cost, settings=pruned(levels=levels, seed_frames=seed_frames)
        )
        same(got, subsequence_dtw(q, space, count=count, max_cost=max_cost))
    # no index: the lowest-bound blocks supply tau
    bare = SearchSpace(clip_id, frame, None, x)
    same(certified_sdtw(q, bare, count=5, settings=pruned(levels=(8, 4))), subsequence_dtw(q, space, count=5))
    st = ExactStats()  # a small search runs the whole DP at once
    same(certified_sdtw(q, space, count=5, stats=st), subsequence_dtw(q, space, count=5))
    assert st.columns == len(x) and st.passes == 1 and st.coarse_blocks == 0


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize(
    "levels,subspace,sub_from",
    [
        ((512, 64, 16, 4), None, 0.0),
        ((16, 4), (3, 2), 0.0),
        ((8, 4, 2), (1, 3, 3), 0.0),
        ((512, 64, 16, 4), (0, 0, 3, 3), 2.0),
    ],
)
def test_certified_with_subspace_cells_equals_sdtw(seed, levels, subspace, sub_from):
    # subspace cells at every level that has a basis (sub_from 0), or never (2): sDTW's matches
    clip_id, frame, x = make_db([60, 3, 90, 40, 70, 25], dim=6, seed=seed)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    rng = np.random.default_rng(seed)
    for m in (5, 14):
        s = int(rng.integers(0, 200))
        q = (x[s : s + m] + rng.normal(0, 0.3, (m, 6))).astype(np.float32)
        for count in (1, 7):
            cfg = pruned(levels=levels, subspace=subspace, subspace_from=sub_from)
            got = certified_sdtw(q, space, count=count, settings=cfg)
            same(got, subsequence_dtw(q, space, count=count))


def test_certified_subspace_needs_one_basis_size_per_level():
    clip_id, frame, x = make_db([60, 40], seed=0)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    with pytest.raises(DataError, match="one basis size per level"):
        certified_sdtw(x[:5], space, settings=pruned(levels=(16, 4), subspace=(3,)))


@pytest.mark.parametrize("seed,lengths,m", [(0, [40, 1, 30, 12], 6), (1, [80], 10), (3, [50, 50], 1)])
def test_sdtw_ranges_compact_equals_forward(seed, lengths, m):
    # both kernels run sdtw_column: over one whole range, sdtw_forward's values bit for bit
    clip_id, frame, x = make_db(lengths, seed=seed)
    q = query_of(x, m, seed)
    cont = continues_of(clip_id, frame)
    qt = np.ascontiguousarray(q.T)
    full = sdtw_forward(qt, x, ~cont)
    rows, *got = sdtw_ranges_compact(qt, x, ~cont, np.array([[0, len(x)]], np.int64))
    np.testing.assert_array_equal(rows, np.arange(len(x)))
    for a, b in zip(got, full, strict=True):
        np.testing.assert_array_equal(a, b)
    # a range starting at a clip start equals the full pass inside it
    a0 = int(np.flatnonzero(~cont)[-1])
    rows, *part = sdtw_ranges_compact(qt, x, ~cont, np.array([[a0, len(x)]], np.int64))
    for a, b in zip(part, full, strict=True):
        np.testing.assert_array_equal(a, b[a0:])


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("count,min_span,max_cost", [(1, 0.0, None), (5, 0.5, None), (8, 0.5, 12.0), (20, 1.0, None)])
def test_certified_equals_sdtw_synthetic(seed, count, min_span, max_cost):
    clip_id, frame, x = make_db([60, 3, 90, 40, 70], seed=seed)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    rng = np.random.default_rng(seed)
    s = int(rng.integers(0, 150))
    q = (x[s : s + 15] + rng.normal(0, 0.3, (15, 3))).astype(np.float32)
    st = ExactStats()
    got = certified_sdtw(
        q, space, count=count, min_span=min_span, max_cost=max_cost, stats=st, settings=pruned(levels=(20, 5))
    )
    same(got, subsequence_dtw(q, space, count=count, min_span=min_span, max_cost=max_cost))


def test_certified_prunes_columns():
    # 120 clips, each a noisy copy of a piece of one smooth signal: like a mocap corpus, a
    # query has a few close matches and many far clips, which the bound rules out
    rng = np.random.default_rng(4)
    base = np.cumsum(rng.normal(0, 0.3, (3000, 3)), axis=0)
    starts = rng.integers(0, 3000 - 40, 120)
    x = np.concatenate([base[s : s + 40] + rng.normal(0, 0.05, (40, 3)) for s in starts]).astype(np.float32)
    clip_id = np.repeat(np.arange(120), 40).astype(np.int32)
    frame = np.tile(np.arange(40), 120).astype(np.int32)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    q = (base[starts[7] + 5 : starts[7] + 25] + rng.normal(0, 0.05, (20, 3))).astype(np.float32)
    st = ExactStats()
    same(certified_sdtw(q, space, count=3, stats=st, settings=pruned()), subsequence_dtw(q, space, count=3))
    assert np.isfinite(st.tau) and st.columns < len(x) // 4 and not st.retried


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("full_from", [0.0, 0.3, 1.0, 2.0])
def test_whole_dp_once_alive_rows_pass_full_from(seed, full_from):
    # full_from only decides when the pruned DP gives way to the whole one: same matches
    clip_id, frame, x = make_db([60, 3, 90, 40, 70], seed=seed)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    rng = np.random.default_rng(seed)
    s = int(rng.integers(0, 150))
    q = (x[s : s + 15] + rng.normal(0, 0.3, (15, 3))).astype(np.float32)
    for count, max_cost in ((5, None), (8, 12.0)):
        st = ExactStats()
        got = certified_sdtw(
            q, space, count=count, max_cost=max_cost, stats=st, settings=pruned(levels=(20, 5), full_from=full_from)
        )
        same(got, subsequence_dtw(q, space, count=count, max_cost=max_cost))
        if full_from == 0.0:  # the first pass is the whole DP, and the last
            assert st.passes == 1 and st.columns == len(x)


def test_normalized_ranking_falls_back_to_the_whole_dp():
    clip_id, frame, x = make_db([50, 50], seed=6)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    q = x[10:20] * 1.1
    st = ExactStats()
    same(
        certified_sdtw(q, space, count=4, rank_by="normalized", stats=st),
        subsequence_dtw(q, space, count=4, rank_by="normalized"),
    )
    assert st.columns == len(x)


@pytest.mark.skipif(not (DATA / "hdm05" / "amc").is_dir(), reason="needs the development corpus ../shared/data (HDM05)")
def test_certified_equals_sdtw_on_hdm05():
    from mocapflow.framework import MotionDatabase
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    files = sorted((DATA / "hdm05" / "amc").glob("*/*.amc"))
    db = MotionDatabase([resample(read_amc(f), 30.0) for f in files])
    x = EndEffectorFeatures(joints=5).transform(db)
    clip_id, frame = db.frame_ids
    rng = np.random.default_rng(0)
    queries = []
    for c in rng.choice(db.n_clips, 6, replace=False):  # one actor's clips hidden: other performers only
        actor = Path(str(db.motions[c].metadata.get("path"))).parent.name
        keep = np.array([Path(str(m.metadata.get("path"))).parent.name != actor for m in db.motions])[clip_id]
        a, b = db.offsets[c], db.offsets[c + 1]
        lo = int(rng.integers(a, max(a + 1, b - 30)))
        queries.append((x[lo : min(b, lo + 30)], keep))
    for q, keep in queries:
        space = SearchSpace(clip_id[keep], frame[keep], KDTreeIndex(method="kdtree").build(x[keep]), x[keep])
        for count in (1, 10):
            same(certified_sdtw(q, space, count=count, settings=pruned()), subsequence_dtw(q, space, count=count))


def test_matcher_is_exactly_sdtw_on_a_pruned_search():
    # what matchers.search promises: subsequence DTW's matches, here on a database large enough
    # (> direct_cells) that the pruned coarse-to-fine search runs
    from mocapflow.plugins.similarity.search.certified import DEFAULT_SETTINGS, CertifiedSearch

    matcher = CertifiedSearch()
    p = matcher.params
    clip_id, frame, x = make_db([500] * 90, seed=5)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    q = (x[1000:1050] + np.random.default_rng(5).normal(0, 0.2, (50, 3))).astype(np.float32)
    assert len(x) * len(q) > DEFAULT_SETTINGS.direct_cells
    st = ExactStats()
    ref = subsequence_dtw(q, space, count=p.count, min_span=p.min_span)
    same(certified_sdtw(q, space, count=p.count, min_span=p.min_span, stats=st), ref)
    same(matcher.match(q, space), ref)
    assert st.coarse_blocks > 0 and st.columns < len(x)


def test_lng_alias_warns_and_equals_search():
    # one release: matchers.lng without exact: false is matchers.search, with a DeprecationWarning
    from mocapflow.plugins.similarity.search.certified import CertifiedSearch
    from mocapflow.plugins.similarity.search.lng import LazyNeighborhoodGraph

    clip_id, frame, x = make_db([500] * 20, seed=3)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    q = (x[700:740] + np.random.default_rng(3).normal(0, 0.2, (40, 3))).astype(np.float32)
    for params in ({}, {"exact": True}):
        with pytest.warns(DeprecationWarning, match="name matchers.search"):
            alias = LazyNeighborhoodGraph(params)
        same(alias.match(q, space), CertifiedSearch().match(q, space))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        LazyNeighborhoodGraph(exact=False)  # the graph: no warning


@pytest.mark.parametrize("seed_eps", [0.0, 1.0, 4.0])
def test_certified_with_approximate_seeds_equals_sdtw(seed_eps):
    # the seeds' neighbours may be approximate (seed_eps, kd-tree eps): they only supply tau
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    clip_id, frame, x = make_db([60, 3, 90, 40, 70, 25, 120, 80], seed=5)
    space = SearchSpace(clip_id, frame, KDTreeIndex(method="kdtree").build(x), x)
    rng = np.random.default_rng(5)
    for s in rng.integers(0, 400, 4):
        q = (x[s : s + 14] + rng.normal(0, 0.3, (14, 3))).astype(np.float32)
        for count in (1, 6):
            same(
                certified_sdtw(q, space, count=count, settings=pruned(seed_eps=seed_eps)),
                subsequence_dtw(q, space, count=count),
            )


@pytest.mark.parametrize("seed", range(6))
def test_alive_runs_equals_block_ranges(seed):
    # the scan over the evaluated ranges only == the runs block by block (and block_ranges), adjacent ranges merged
    from naive.coarse import naive_alive_runs

    from mocapflow.plugins.similarity.search._coarse_kernels import alive_runs
    from mocapflow.plugins.similarity.search.certified import block_ranges

    rng = np.random.default_rng(seed)
    nb = int(rng.integers(1, 80))
    cuts = np.unique(np.r_[0, np.sort(rng.integers(0, nb + 1, 8)), nb])
    pairs = np.stack([cuts[:-1], cuts[1:]], axis=1)
    br = pairs[rng.random(len(pairs)) < 0.7].astype(np.int64)  # some ranges adjacent, some apart
    lb = np.full(nb, np.inf)
    for a, b in br:
        lb[a:b] = rng.choice([0.5, 1.0, 2.0, 3.0, np.inf], b - a)
    for scale, tau in ((1.0, 1.0), (1.0, 2.5), (1.5, 2.0), (1.0, 0.1), (2.0, 1e9)):
        got = alive_runs(lb, br.reshape(-1, 2), scale, tau)
        np.testing.assert_array_equal(got, naive_alive_runs(lb, scale, tau))
        np.testing.assert_array_equal(got, block_ranges(lb * scale <= tau))
