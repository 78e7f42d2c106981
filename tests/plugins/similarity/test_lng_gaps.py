"""Gap-tolerant lazy neighborhood graph: kernel against the definition, paths against Dijkstra."""

from __future__ import annotations

import numpy as np
import pytest
from naive.dtw import continues_of, naive_lng
from naive.gaps import naive_gap_neighbors, naive_gap_nodes
from test_lng import BruteIndex, space_of
from test_sdtw import make_db

from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search._gap_kernels import gap_layers
from mocapflow.plugins.similarity.search.graph import build_graph, neighbor_sets
from mocapflow.plugins.similarity.search.lng import lazy_neighborhood_graph
from mocapflow.plugins.similarity.search.sdtw import sdtw_costs


@pytest.mark.parametrize(
    "lengths,m,k,gaps,seed",
    [
        ([30, 1, 25, 9], 6, 3, 1, 0),
        ([40, 40], 10, 4, 3, 1),
        ([1, 1, 1, 1], 3, 2, 2, 2),
        ([60], 1, 5, 4, 3),
        ([20, 30, 15], 15, 6, 5, 4),
        ([2, 3, 2, 50], 12, 2, 20, 5),
    ],
)
def test_gap_layers_equal_definition(lengths, m, k, gaps, seed):
    space = space_of(lengths, seed=seed)
    rng = np.random.default_rng(seed)
    q = (space.features[rng.integers(0, space.n_rows, m)] + rng.normal(0, 0.3, (m, 3))).astype(np.float32)
    ids, dist, count = neighbor_sets(q, space.index, k, None)
    out_ids, out_dist, out_count, cells = gap_layers(q, ids, dist, count, space.features, space.continues, gaps)
    cont = continues_of(space.clip_id, space.frame)
    nn = [set(ids[i, : count[i]].tolist()) for i in range(m)]
    ref = naive_gap_nodes(nn, cont, gaps)
    for i in range(m):
        got = out_ids[i, : out_count[i]]
        assert np.all(np.diff(got) > 0)
        assert set(got.tolist()) == ref[i]
        assert np.all(out_ids[i, out_count[i] :] == -1)
        want = np.linalg.norm(q[i].astype(float) - space.features[got].astype(float), axis=1)
        np.testing.assert_allclose(out_dist[i, : out_count[i]], want, rtol=1e-5, atol=1e-6)
    assert cells == int(out_count.sum() - count.sum())


@pytest.mark.parametrize("seed,gaps", [(0, 1), (1, 2), (2, 4), (3, 8)])
def test_gap_graph_paths_equal_dijkstra(seed, gaps):
    space = space_of([35, 2, 50, 20], seed=seed)
    rng = np.random.default_rng(seed)
    q = (space.features[40:52] + rng.normal(0, 0.3, (12, 3))).astype(np.float32)
    g = build_graph(q, space, k=4, gaps=gaps)
    ids, _, count = neighbor_sets(q, space.index, 4, None)
    cont = continues_of(space.clip_id, space.frame)
    neighbors = naive_gap_neighbors(
        q, space.features, [set(ids[i, : count[i]].tolist()) for i in range(12)], cont, gaps
    )
    ref = naive_lng(neighbors, cont)
    last = 11
    reach = {int(h): c for h, c in zip(g.ids[last, : g.count[last]], g.cost[last], strict=False) if np.isfinite(c)}
    assert set(reach) == set(ref)
    for h, c in reach.items():
        assert c == pytest.approx(ref[h][0], rel=1e-5)
    # every gap-graph path is a real warping path: its cost is at least sDTW's at that end
    sd, _, _ = sdtw_costs(q, space)
    for h, c in reach.items():
        assert c >= sd[h] * (1 - 1e-5)


def test_gaps_find_what_the_paper_graph_cannot():
    # clip 1 repeats clip 0's motif with two frames moved far away: with k small, those query
    # frames' neighbours all lie in clip 0, so the paper's graph has no path through clip 1
    rng = np.random.default_rng(3)
    motif = np.cumsum(rng.normal(0, 1, (20, 3)), axis=0).astype(np.float32)
    other = motif + np.float32(0.05)
    other[9:11] += 30.0
    x = np.concatenate([motif, other])
    clip_id = np.r_[np.zeros(20), np.ones(20)].astype(np.int32)
    frame = np.r_[np.arange(20), np.arange(20)].astype(np.int32)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    both_paper = lazy_neighborhood_graph(motif, space, k=2, count=2, gaps=0, fill=False, min_span=0)
    both_gaps = lazy_neighborhood_graph(motif, space, k=2, count=2, gaps=2, fill=False, min_span=0)
    assert len(both_paper) == 1 and both_paper.start[0] == 0
    assert len(both_gaps) == 2 and set(clip_id[both_gaps.start]) == {0, 1}
    assert both_gaps.end[1] - both_gaps.start[1] == 20


def test_gaps_need_features():
    space = space_of([30], seed=1)
    bare = SearchSpace(space.clip_id, space.frame, space.index)
    with pytest.raises(DataError, match="features"):
        build_graph(space.features[:5], bare, k=3, gaps=2)


def test_fill_returns_count_when_graph_is_short():
    clip_id, frame, x = make_db([30, 30, 30], seed=8)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    q = x[5:15] + np.float32(3.0)
    short = lazy_neighborhood_graph(q, space, k=1, count=5, gaps=0, fill=False)
    filled = lazy_neighborhood_graph(q, space, k=1, count=5, gaps=0, fill=True)
    assert len(short) < 5 and len(filled) == 5
