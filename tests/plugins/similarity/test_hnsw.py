"""``indexes.hnsw`` (the ``ann`` extra): the Index contract, determinism, recall, the LNG through it."""

from __future__ import annotations

import numpy as np
import pytest

hnswlib = pytest.importorskip("hnswlib", reason="indexes.hnsw needs the 'ann' extra (pip install 'mocapflow[ann]')")

from mocapflow.framework.matching import SearchSpace  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra
from mocapflow.framework.testing import parametrize_with_checks  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra
from mocapflow.plugins.similarity.knn.hnsw import HNSWIndex  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra
from mocapflow.plugins.similarity.search.lng import lazy_neighborhood_graph  # noqa: E402 - after pytest.importorskip: skip cleanly without the optional extra


@parametrize_with_checks([HNSWIndex])
def test_conformance(component_class, check):
    check(component_class)


def smooth(n=3000, d=15, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0, 0.1, (n, d)), axis=0).astype(np.float32)


def brute(x, q, k):
    d = np.linalg.norm(q[:, None].astype(float) - x[None].astype(float), axis=2)
    order = np.argsort(d, axis=1, kind="stable")[:, :k]
    return np.take_along_axis(d, order, 1), order


def test_recall_padding_radius_and_determinism(tmp_path):
    x = smooth()
    q = x[::97] + np.float32(0.01)
    ix = HNSWIndex(ef=512).build(x)
    dist, ids = ix.query(q, 64)
    _, want = brute(x, q, 64)
    recall = np.mean([len(set(a) & set(b)) / 64 for a, b in zip(ids, want, strict=True)])
    assert recall >= 0.99
    assert np.all(np.diff(dist, axis=1) >= 0)
    np.testing.assert_allclose(dist, np.linalg.norm(q[:, None] - x[ids], axis=2), rtol=1e-4, atol=1e-5)
    # same seed, one build thread: the same graph, the same answers
    again = HNSWIndex(ef=512).build(x)
    np.testing.assert_array_equal(again.query(q, 64)[1], ids)
    ix.save(tmp_path)
    np.testing.assert_array_equal(HNSWIndex.load(tmp_path).query(q, 64)[1], ids)
    # fewer rows than k: padded; radius: only the near ones
    small = HNSWIndex().build(x[:5])
    d5, i5 = small.query(q[:2], 8)
    assert np.all(i5[:, 5:] == -1) and np.all(np.isinf(d5[:, 5:])) and np.all(i5[:, :5] >= 0)
    r = float(np.median(dist[:, 10]))
    dr, ir = ix.query(q, 64, radius=r)
    assert np.all(dr[ir >= 0] <= r) and np.all(ir[dr > r] == -1)


def test_lng_through_the_contract():
    rng = np.random.default_rng(1)
    x = smooth(2000, 3, seed=1)
    clip_id = np.repeat(np.arange(20), 100).astype(np.int32)
    frame = np.tile(np.arange(100), 20).astype(np.int32)
    space = SearchSpace(clip_id, frame, HNSWIndex().build(x), x)
    q = x[430:460] + rng.normal(0, 0.01, (30, 3)).astype(np.float32)
    res = lazy_neighborhood_graph(q, space, k=32, count=3)
    assert (res.start[0], res.end[0]) == (430, 460)
