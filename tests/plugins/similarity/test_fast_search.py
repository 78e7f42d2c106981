"""``matchers.search`` ``mode: fast`` (filter-and-refine) and the all-core ranged DP: checked against
subsequence DTW and the one-thread kernels."""

from __future__ import annotations

import numpy as np
import pytest
from naive.dtw import continues_of, naive_subsequence_dtw
from test_lng import BruteIndex
from test_sdtw import make_db

from mocapflow.framework.errors import ConfigError
from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search import ranges
from mocapflow.plugins.similarity.search._dtw_kernels import sdtw_forward, sdtw_ranges_compact, sdtw_ranges_parallel
from mocapflow.plugins.similarity.search.certified import CertifiedSearch, certified_sdtw
from mocapflow.plugins.similarity.search.fast import FastSettings, fast_sdtw, seed_windows
from mocapflow.plugins.similarity.search.ranges import ranges_dp
from mocapflow.plugins.similarity.search.sdtw import sdtw_costs, subsequence_dtw


def planted(lengths=(300, 5, 420, 260, 1, 380), m=24, seed=0):
    """Random-walk clips with four noisy, time-stretched copies of one segment planted in them."""
    clip_id, frame, x = make_db(list(lengths), dim=4, seed=seed)
    rng = np.random.default_rng(seed)
    q = x[40 : 40 + m].copy()
    for at, stretch in ((320, 1.0), (600, 1.2), (750, 0.85), (1100, 1.1)):
        t = np.linspace(0, m - 1, int(round(m * stretch)))
        copy = np.stack([np.interp(t, np.arange(m), q[:, k]) for k in range(q.shape[1])], 1)
        x[at : at + len(copy)] = copy + rng.normal(0, 0.02, copy.shape)
    q = (q + rng.normal(0, 0.05, q.shape)).astype(np.float32)
    return SearchSpace(clip_id, frame, BruteIndex().build(x), x.astype(np.float32)), q


@pytest.mark.parametrize("groups", [[0, 1, 2, 3], [0, 3], [0, 2, 3]])
def test_parallel_ranged_dp_is_the_one_thread_kernel(groups):
    clip_id, frame, x = make_db([40, 1, 30, 12, 55], seed=3)
    q = (x[5:14] + 0.1).astype(np.float32)
    qt = np.ascontiguousarray(q.T)
    starts = ~continues_of(clip_id, frame)
    ranges = np.array([[0, 35], [41, 80], [90, 138]], np.int64)
    want = sdtw_ranges_compact(qt, x, starts, ranges)
    got = sdtw_ranges_parallel(qt, x, starts, ranges, np.array(groups, np.int64))
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


def test_ranges_dp_cut_at_clip_starts_equals_whole_dp(monkeypatch):
    """Whole-database ranges cut into pieces at clip starts on 2 threads: sDTW's arrays bit for bit."""
    monkeypatch.setattr(ranges, "_PARALLEL_CELLS", 0)
    clip_id, frame, x = make_db([40, 1, 30, 12, 55, 7, 90], seed=4)
    space = SearchSpace(clip_id, frame, features=x)
    q = (x[50:61] - 0.05).astype(np.float32)
    qt = np.ascontiguousarray(q.T)
    cost, start, length = sdtw_forward(qt, x, ~space.continues)
    rows, c, s, ln = ranges_dp(qt, space, np.array([[0, len(x)]], np.int64), threads=2)
    np.testing.assert_array_equal(rows, np.arange(len(x)))
    np.testing.assert_array_equal(c, cost)
    np.testing.assert_array_equal(s, start)
    np.testing.assert_array_equal(ln, length)
    sub = np.array([[3, 39], [41, 100], [120, 200]], np.int64)
    for a, b in zip(
        ranges_dp(qt, space, sub, threads=2), sdtw_ranges_compact(qt, x, ~space.continues, sub), strict=True
    ):
        np.testing.assert_array_equal(a, b)


def test_sdtw_costs_on_threads_match_naive(monkeypatch):
    import numba

    monkeypatch.setattr(ranges, "_PARALLEL_CELLS", 0)
    monkeypatch.setattr(numba, "get_num_threads", lambda: 2)
    clip_id, frame, x = make_db([20, 1, 15, 7, 33], seed=5)
    q = (x[2:8] + 0.1).astype(np.float32)
    space = SearchSpace(clip_id, frame, features=x)
    cost, start, _ = sdtw_costs(q, space)
    d, s, _ = naive_subsequence_dtw(q, x, continues_of(clip_id, frame))
    np.testing.assert_allclose(cost, d[-1], rtol=1e-6)
    fin = np.isfinite(d[-1])
    np.testing.assert_array_equal(start[fin], s[-1][fin])


def test_fast_finds_the_planted_copies_with_sdtw_costs():
    space, q = planted()
    ref = subsequence_dtw(q, space, count=5)
    got = fast_sdtw(q, space, exact_search=certified_sdtw, count=5, settings=FastSettings(frames=12, k=16))
    # the four planted copies and the source are sDTW's top-5; the filter finds all of them
    assert len(got) == 5
    for s, e in zip(ref.start.tolist(), ref.end.tolist(), strict=True):
        assert np.any((got.start < e) & (got.end > s))
    # every returned cost is the exact cost of a path in the database, never below sDTW's at that end row
    cost, _, _ = sdtw_costs(q, space)
    assert np.all(got.cost >= cost[got.end - 1] - 1e-9)
    np.testing.assert_array_equal(got.cost[:4], ref.cost[:4])


def test_seed_windows_stay_in_their_clip_and_hold_every_neighbour():
    space, q = planted()
    m = len(q)
    frames = np.arange(0, m, 3)
    _, ids = space.index.query(q[frames], 6)
    r = seed_windows(space, m, frames, ids, 1.3)
    assert np.all(r[:, 1] > r[:, 0]) and np.all(r[1:, 0] > r[:-1, 1])
    for a, b in r.tolist():  # inside one clip
        assert space.clip_id[a] == space.clip_id[b - 1]
    inside = np.zeros(space.n_rows, bool)
    for a, b in r.tolist():
        inside[a:b] = True
    assert inside[ids[ids >= 0]].all()
    # a neighbour of the first query frame opens rows h - 2 .. h + 1.3 (m - 1) + 2 of its clip
    h = int(ids[0, 0])
    run_end = np.flatnonzero(space.clip_id == space.clip_id[h])[-1] + 1
    assert inside[max(h - 2, 0) : min(h + int(1.3 * (m - 1)) + 3, run_end)].all()


def test_fast_falls_back_to_exact_when_windows_hold_too_few():
    space, q = planted()
    ref = subsequence_dtw(q, space, count=40, min_span=0.0)
    got = fast_sdtw(q, space, exact_search=certified_sdtw, count=40, min_span=0.0, settings=FastSettings(frames=2, k=1))
    np.testing.assert_array_equal(got.end, ref.end)
    np.testing.assert_array_equal(got.cost, ref.cost)


def test_matcher_mode_switch():
    space, q = planted()
    exact = CertifiedSearch({"count": 5}).match(q, space)
    fast = CertifiedSearch({"count": 5, "mode": "fast"}).match(q, space)
    ref = subsequence_dtw(q, space, count=5)
    np.testing.assert_array_equal(exact.end, ref.end)
    assert len(fast) == 5
    with pytest.raises(ConfigError, match="mode"):
        CertifiedSearch({"mode": "approximate"})
