"""Subsequence DTW kernels and matcher against the naive full-matrix reference."""

from __future__ import annotations

import numpy as np
import pytest
from naive.dtw import continues_of, naive_path, naive_subsequence_dtw

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import SearchSpace, select_matches
from mocapflow.plugins.similarity.search.sdtw import sdtw_costs, subsequence_dtw


def make_db(lengths, dim=3, seed=0, walk=True):
    rng = np.random.default_rng(seed)
    clip_id = np.concatenate([np.full(n, c) for c, n in enumerate(lengths)]).astype(np.int32)
    frame = np.concatenate([np.arange(n) for n in lengths]).astype(np.int32)
    x = rng.normal(size=(len(clip_id), dim))
    if walk:  # smooth signals, like motion features
        x = np.cumsum(x * 0.3, axis=0)
    return clip_id, frame, x.astype(np.float32)


@pytest.mark.parametrize("lengths,m,seed", [([20, 1, 15, 7], 5, 0), ([1, 1, 1], 3, 1), ([30], 1, 2), ([12, 9], 12, 3)])
def test_forward_matches_naive(lengths, m, seed):
    clip_id, frame, x = make_db(lengths, seed=seed)
    q = (
        x[2 : 2 + m] + np.random.default_rng(seed).normal(scale=0.1, size=(m, x.shape[1])).astype(np.float32)
        if len(x) >= m + 2
        else x[:m] * 0.5
    )
    space = SearchSpace(clip_id, frame, features=x)
    cost, start, length = sdtw_costs(q, space)
    D, S, P = naive_subsequence_dtw(q, x, continues_of(clip_id, frame))
    np.testing.assert_allclose(cost, D[-1], rtol=1e-6)
    finite = np.isfinite(D[-1])
    np.testing.assert_array_equal(start[finite], S[-1][finite])
    for j in np.flatnonzero(finite):
        assert length[j] == len(naive_path(P, len(q) - 1, j))


def test_paths_match_naive_and_stay_in_clips():
    clip_id, frame, x = make_db([25, 3, 40, 18], seed=5)
    q = x[30:42].copy()
    space = SearchSpace(clip_id, frame, features=x)
    res = subsequence_dtw(q, space, count=5, min_span=0)
    D, S, P = naive_subsequence_dtw(q, x, continues_of(clip_id, frame))
    assert len(res) >= 2
    assert res.cost[0] == pytest.approx(D[-1].min(), rel=1e-9)
    for s, e, c, path in zip(res.start, res.end, res.cost, res.paths, strict=True):
        ref = naive_path(P, len(q) - 1, e - 1)  # end is exclusive
        np.testing.assert_array_equal(path, ref)
        assert path[0, 1] == s and path[-1, 1] == e - 1 and path[0, 0] == 0 and path[-1, 0] == len(q) - 1
        assert len(set(clip_id[path[:, 1]])) == 1
        dq, dx = np.diff(path, axis=0).T
        assert set(zip(dq, dx, strict=True)) <= {(1, 1), (0, 1), (1, 0)}
        local = np.linalg.norm(q[path[:, 0]].astype(float) - x[path[:, 1]], axis=1).sum()
        assert c == pytest.approx(local, rel=1e-6)
    # ranked and non-overlapping
    assert np.all(np.diff(res.cost) >= 0)
    iv = sorted(zip(res.start, res.end, strict=True))
    assert all(a[1] <= b[0] for a, b in zip(iv, iv[1:], strict=False))


def test_exact_copy_is_found_at_zero_cost():
    clip_id, frame, x = make_db([50, 60], seed=7)
    q = x[70:85]
    res = subsequence_dtw(q, SearchSpace(clip_id, frame, features=x), count=1)
    assert res.cost[0] == pytest.approx(0.0, abs=1e-9)
    assert (res.start[0], res.end[0]) == (70, 85)


def test_constant_signals():
    x = np.zeros((10, 2), np.float32)
    clip_id, frame = np.zeros(10, np.int32), np.arange(10, dtype=np.int32)
    res = subsequence_dtw(np.ones((4, 2), np.float32), SearchSpace(clip_id, frame, features=x), count=3)
    assert len(res) == 3 and np.allclose(res.cost, 4 * np.sqrt(2))


def test_max_cost_and_rank_by():
    clip_id, frame, x = make_db([40, 40], seed=3)
    space = SearchSpace(clip_id, frame, features=x)
    q = x[5:15]
    everything = subsequence_dtw(q, space, count=20)
    capped = subsequence_dtw(q, space, count=20, max_cost=float(everything.cost[2]))
    assert len(capped) == 3
    norm = subsequence_dtw(q, space, count=5, rank_by="normalized")
    key = norm.cost / norm.length
    assert np.all(np.diff(key) >= 0)


def test_select_matches_greedy():
    end = np.array([10, 11, 30, 12, 50])
    start = np.array([5, 6, 25, 11, 49])
    cost = np.array([1.0, 0.5, 2.0, 0.7, np.inf])
    keep = select_matches(end, start, cost, np.ones(5), count=10, max_cost=None, rank_by="cost")
    assert list(keep) == [1, 2]


def test_bad_query():
    clip_id, frame, x = make_db([10])
    space = SearchSpace(clip_id, frame, features=x)
    with pytest.raises(DataError):
        sdtw_costs(np.zeros((3, 5), np.float32), space)
    with pytest.raises(DataError):
        sdtw_costs(np.full((3, 3), np.nan, np.float32), space)


def test_min_span_drops_squashed_alignments():
    clip_id, frame, x = make_db([60, 60], seed=11)
    space = SearchSpace(clip_id, frame, features=x)
    q = x[10:30] + 0.5
    loose = subsequence_dtw(q, space, count=30, min_span=0)
    tight = subsequence_dtw(q, space, count=30)  # min_span 0.5 by default
    assert np.any(loose.end - loose.start < 10)  # unconstrained DTW squashes some
    assert np.all(tight.end - tight.start >= 10)
    assert len(tight) > 0 and tight.cost[0] >= loose.cost[0]
