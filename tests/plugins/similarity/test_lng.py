"""Lazy neighborhood graph: kernel against the explicit graph, and against subsequence DTW."""

from __future__ import annotations

import numpy as np
import pytest
from naive.dtw import continues_of, naive_lng
from test_sdtw import make_db

from mocapflow.framework import Index
from mocapflow.framework.errors import DataError
from mocapflow.framework.matching import SearchSpace
from mocapflow.plugins.similarity.search.graph import build_graph
from mocapflow.plugins.similarity.search.lng import lazy_neighborhood_graph
from mocapflow.plugins.similarity.search.sdtw import subsequence_dtw


class BruteIndex(Index):
    """Exact fixed-radius kNN by brute force (the Index contract, for tests)."""

    name = "brute_test"

    def build(self, features):
        self.x_ = np.asarray(features, np.float64)
        return self

    def query(self, x, k, radius=None):
        d = np.linalg.norm(np.asarray(x, np.float64)[:, None, :] - self.x_[None], axis=2)
        order = np.argsort(d, axis=1, kind="stable")[:, :k]
        dist = np.take_along_axis(d, order, 1)
        ids = order.astype(np.int64)
        if radius is not None:
            ids[dist > radius] = -1
            dist[dist > radius] = np.inf
        pad = k - dist.shape[1]
        if pad > 0:
            dist = np.pad(dist, ((0, 0), (0, pad)), constant_values=np.inf)
            ids = np.pad(ids, ((0, 0), (0, pad)), constant_values=-1)
        return dist.astype(np.float32), ids


def space_of(lengths, seed=0, dim=3):
    clip_id, frame, x = make_db(lengths, dim=dim, seed=seed)
    return SearchSpace(clip_id, frame, BruteIndex().build(x), x)


@pytest.mark.parametrize(
    "lengths,m,k,radius,seed",
    [
        ([30, 1, 25, 9], 6, 8, None, 0),
        ([40, 40], 10, 12, 1.5, 1),
        ([1, 1, 1, 1], 3, 4, None, 2),
        ([60], 1, 5, None, 3),
        ([20, 30, 15], 15, 30, 2.0, 4),
    ],
)
def test_kernel_matches_explicit_graph(lengths, m, k, radius, seed):
    space = space_of(lengths, seed=seed)
    rng = np.random.default_rng(seed)
    s = int(rng.integers(0, max(1, space.n_rows - m)))
    q = space.features[s : s + m] + rng.normal(scale=0.2, size=(min(m, space.n_rows - s), 3)).astype(np.float32)
    g = build_graph(q, space, k=k, radius=radius)
    neighbors = [
        {int(h): float(d) for h, d in zip(g.ids[i, : g.count[i]], g.dist[i, : g.count[i]], strict=True)}
        for i in range(len(q))
    ]
    ref = naive_lng(neighbors, continues_of(space.clip_id, space.frame))
    last = len(q) - 1
    reach = {
        int(h): (c, st)
        for h, c, st in zip(g.ids[last, : g.count[last]], g.cost[last], g.start[last], strict=False)
        if np.isfinite(c)
    }
    assert set(reach) == set(ref)
    for h, (c, _) in reach.items():
        assert c == pytest.approx(ref[h][0], rel=1e-9)
    res = g.matches(count=50, min_span=0)
    for e, st, path in zip(res.end, res.start, res.paths, strict=True):
        rc, rs, rpath = ref[int(e) - 1]  # end is exclusive
        assert st == rs
        np.testing.assert_array_equal(path, rpath)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equals_subsequence_dtw_with_all_neighbours(seed):
    space = space_of([35, 2, 50, 20], seed=seed)
    q = space.features[40:52] * 1.05
    lng = lazy_neighborhood_graph(q, space, k=space.n_rows, count=6)
    ref = subsequence_dtw(q, space, count=6)
    np.testing.assert_allclose(lng.cost, ref.cost, rtol=1e-5)
    np.testing.assert_array_equal(lng.start, ref.start)
    np.testing.assert_array_equal(lng.end, ref.end)
    for a, b in zip(lng.paths, ref.paths, strict=True):
        np.testing.assert_array_equal(a, b)


def test_no_edge_across_clip_boundary():
    # two clips that continue each other perfectly: a path would love to cross
    x = np.linspace(0, 1, 40)[:, None].repeat(2, 1).astype(np.float32)
    clip_id = np.r_[np.zeros(20), np.ones(20)].astype(np.int32)
    frame = np.r_[np.arange(20), np.arange(20)].astype(np.int32)
    space = SearchSpace(clip_id, frame, BruteIndex().build(x), x)
    res = lazy_neighborhood_graph(x[15:25], space, k=40, count=3)
    for path in res.paths:
        assert len(set(clip_id[path[:, 1]])) == 1
    assert res.cost[0] > 0  # the perfect crossing alignment is forbidden


def test_radius_limits_neighbours_and_matches():
    space = space_of([50], seed=9)
    q = space.features[10:20]
    g = build_graph(q, space, k=50, radius=0.5)
    valid = g.ids >= 0
    assert np.all(g.dist[valid] <= 0.5) and np.all(g.count <= 50)
    far = build_graph(q + 100, space, k=50, radius=0.5)
    assert far.n_nodes == 0 and len(far.matches()) == 0


def test_index_contract_violations():
    space = space_of([10])

    class Dup(BruteIndex):
        def query(self, x, k, radius=None):
            d, i = super().query(x, k, radius)
            i[:, 1] = i[:, 0]
            return d, i

    bad = SearchSpace(space.clip_id, space.frame, Dup().build(space.features))
    with pytest.raises(DataError):
        build_graph(space.features[:3], bad, k=4)
    with pytest.raises(DataError):
        build_graph(space.features[:3], SearchSpace(space.clip_id, space.frame), k=4)


@pytest.mark.parametrize(
    "seed,k,radius,ties", [(0, 5, None, False), (1, 12, 1.2, False), (2, 3, None, True), (3, 40, None, False)]
)
def test_propagate_layer_equals_naive(seed, k, radius, ties):
    from naive.dtw import naive_propagate

    from mocapflow.plugins.similarity.search._lng_kernels import propagate_layer

    rng = np.random.default_rng(seed)
    lengths = [1, 7, 2, 30, 3]
    clip_id, frame, x = make_db(lengths, dim=3, seed=seed)
    if ties:  # integer features: many equal distances, resolved by row
        x = rng.integers(0, 2, size=x.shape).astype(np.float32)
    cont = continues_of(clip_id, frame)
    n = len(x)
    r2 = np.inf if radius is None else radius**2
    for _ in range(10):
        prev = np.sort(rng.choice(n, size=min(k, n), replace=False)).astype(np.int64)
        prev = np.concatenate([prev, [-1, -1]])  # padding past the count is ignored
        q = (x[rng.integers(n)] + rng.normal(0, 0.3, 3)).astype(np.float32)
        ids, dist = np.zeros(k, np.int64), np.zeros(k, np.float32)
        cnt = propagate_layer(q, prev, len(prev) - 2, x, cont, k, r2, ids, dist)
        ref_ids, ref_d = naive_propagate(q, prev[:-2], x, cont, k, r2)
        assert cnt == len(ref_ids)
        np.testing.assert_array_equal(ids[:cnt], ref_ids)
        np.testing.assert_allclose(dist[:cnt], ref_d, rtol=1e-6)
        assert np.all(ids[cnt:] == -1) and np.all(np.isinf(dist[cnt:]))


@pytest.mark.parametrize("seed", range(3))
def test_propagated_sets_with_every_row_equal_subsequence_dtw(seed):
    # k >= n: the first layer holds every row, so every later candidate set does too
    space = space_of([25, 1, 18, 6], seed=seed)
    q = np.random.default_rng(seed).normal(size=(9, 3)).astype(np.float32)
    exact = lazy_neighborhood_graph(q, space, k=space.n_rows, count=5)
    for every in (1, 4, 100):
        prop = lazy_neighborhood_graph(q, space, k=space.n_rows, count=5, propagate=every)
        np.testing.assert_array_equal(prop.start, exact.start)
        np.testing.assert_array_equal(prop.end, exact.end)
        np.testing.assert_allclose(prop.cost, exact.cost, rtol=1e-6)
    ref = subsequence_dtw(q, space, count=5)
    np.testing.assert_allclose(exact.cost, ref.cost, rtol=1e-5)


def test_propagated_sets_keep_exact_layers_and_need_features():
    space = space_of([40, 40], seed=5)
    q = space.features[10:22] + np.float32(0.01)
    g_exact = build_graph(q, space, k=6)
    g_prop = build_graph(q, space, k=6, propagate=4)
    for i in (0, 4, 8):  # searched layers are the index's own
        np.testing.assert_array_equal(g_prop.ids[i], g_exact.ids[i])
    assert g_prop.count.min() >= 1
    # the query is a database segment: its own rows stay in the beam, so its match is found
    best = lazy_neighborhood_graph(q, space, k=6, count=1, propagate=4)
    assert (best.start[0], best.end[0]) == (10, 22)
    bare = SearchSpace(space.clip_id, space.frame, space.index)
    with pytest.raises(DataError, match="features"):
        build_graph(q, bare, k=6, propagate=4)
