"""Voted seed windows (plugins/similarity/_seed_votes.py): the naive reference, and sDTW's matches with them."""
from __future__ import annotations

import numpy as np
import pytest
from naive.dtw import continues_of
from naive.seeds import naive_voted_windows
from test_exact_search import same
from test_lng import BruteIndex
from test_sdtw import make_db

from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search import exact
from mocapflow.plugins.similarity._seed_votes import voted_windows
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw


@pytest.mark.parametrize("seed,top,gap", [(0, 1, 4), (1, 3, 2), (2, 50, 6), (3, 2, 0)])
def test_voted_windows_equal_naive(seed, top, gap):
    rng = np.random.default_rng(seed)
    lengths = [40, 1, 30, 12, 55]
    clip_id = np.concatenate([np.full(n, c) for c, n in enumerate(lengths)])
    frame = np.concatenate([np.arange(n) for n in lengths])
    cont = continues_of(clip_id, frame)
    n, m = len(clip_id), 17
    frames = np.array([0, 4, 8, 12, 16])
    ids = rng.integers(0, n, (5, 6))
    ids[1, 4:] = -1  # padding: fewer neighbours for one frame
    ids[3, :2] = ids[0, :2] + 12  # two frames agreeing on a start (rows 12 frames apart)
    dist = np.sort(rng.random((5, 6)), axis=1)
    if seed == 2:
        dist = np.round(dist * 4) / 4  # tied scores
    run_of = np.cumsum(~cont) - 1
    got = exact.merged_ranges(*voted_windows(frames, ids, dist, run_of, m, n, 2.0, gap, top))
    ref = naive_voted_windows(frames, ids, dist, cont, m, n, 2.0, gap, top)
    assert got.tolist() == ref
    assert len(got) >= 1


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("vote", [1, 3])
def test_certified_with_voted_seeds_equals_sdtw(seed, vote, monkeypatch):
    monkeypatch.setattr(exact, "SEED_VOTE", vote)
    clip_id, frame, x = make_db([60, 3, 90, 40, 70, 25], seed=seed)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    rng = np.random.default_rng(seed)
    s = int(rng.integers(0, 150))
    q = (x[s : s + 12] + rng.normal(0, 0.3, (12, 3))).astype(np.float32)
    for count, max_cost in ((1, None), (6, None), (9, 10.0)):
        st = exact.ExactStats()
        got = exact.certified_sdtw(q, space, count=count, max_cost=max_cost, levels=(8, 4), direct_cells=0, stats=st)
        same(got, subsequence_dtw(q, space, count=count, max_cost=max_cost))
        assert st.guess_columns > 0
