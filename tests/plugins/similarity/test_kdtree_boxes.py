"""Bounding-box pruning of indexes.kdtree: the boxes, their lower bound, and exactness."""

from __future__ import annotations

import numpy as np
import pytest
from naive.knn import knn

from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex, TreeSettings


def _data(kind, rng):
    if kind == "random":
        return rng.normal(size=(1500, 6)).astype(np.float32)
    if kind == "clustered":
        centres = rng.normal(size=(4, 6)) * 5
        return (centres[rng.integers(0, 4, 1500)] + 0.03 * rng.normal(size=(1500, 6))).astype(np.float32)
    if kind == "ties":  # integer grid: many duplicate rows and exactly tied distances
        return rng.integers(0, 3, size=(1500, 4)).astype(np.float32)
    if kind == "one_row":
        return rng.normal(size=(1, 5)).astype(np.float32)
    if kind == "constant":
        return np.full((300, 5), 0.25, np.float32)
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["random", "clustered", "ties", "one_row", "constant"])
@pytest.mark.parametrize("leafsize", [1, 4, 16])
def test_node_boxes_are_the_tight_boxes_of_the_node_points(kind, leafsize):
    ix = KDTreeIndex(method="kdtree").build(_data(kind, np.random.default_rng(0)), tree=TreeSettings(leafsize=leafsize))
    lo, hi = ix._node_boxes()
    assert lo.shape == hi.shape == (len(ix.start_), ix.data_.shape[1]) and lo.dtype == np.float32
    for node in range(len(ix.start_)):
        pts = ix.data_[ix.start_[node] : ix.end_[node]]
        np.testing.assert_array_equal(lo[node], pts.min(0))
        np.testing.assert_array_equal(hi[node], pts.max(0))


@pytest.mark.parametrize("kind", ["random", "ties"])
def test_box_distance_never_exceeds_a_point_distance(kind):
    # the pruning rule: for every query and node, the box distance is <= the float64 distance
    # (summed as the search sums it) of each point in the node, ties included
    from mocapflow.plugins.similarity.knn._knn_kernels import _box_dist

    rng = np.random.default_rng(1)
    ix = KDTreeIndex(method="kdtree").build(_data(kind, rng)[:300], tree=TreeSettings(leafsize=4))
    lo, hi = ix._node_boxes()
    x = ix.data_.astype(np.float64)
    for q in np.concatenate([ix.data_[:5], ix.data_[:5] + np.float32(0.5)]).astype(np.float64):
        d2 = np.zeros(len(x))
        for j in range(x.shape[1]):
            d2 += (x[:, j] - q[j]) ** 2
        for node in range(len(ix.start_)):
            b = _box_dist(q, lo, hi, node, x.shape[1])
            assert b <= d2[ix.start_[node] : ix.end_[node]].min()


@pytest.mark.parametrize("kind", ["random", "clustered", "ties", "one_row", "constant"])
@pytest.mark.parametrize("leafsize", [1, 4, 16])
def test_box_pruned_search_equals_brute_force(kind, leafsize):
    rng = np.random.default_rng(2)
    x = _data(kind, rng)
    ix = KDTreeIndex(method="kdtree").build(x, tree=TreeSettings(leafsize=leafsize))
    # consecutive rows (seeded bounds), shifted copies (no exact hit) and far-away queries
    q = np.concatenate([x[:15], x[:15] + np.float32(0.01), rng.normal(size=(5, x.shape[1])).astype(np.float32) * 4])
    for k in (1, 7, 64):
        for radius in (None, 0.8):
            d, i = ix.query(q, k, radius)
            d0, i0 = knn(x, q, k, radius=radius)
            np.testing.assert_array_equal(i, i0)
            np.testing.assert_allclose(d, d0, rtol=1e-6, atol=1e-6)
            d1, i1 = ix.query(q[3], k, radius)  # one query: unseeded path
            np.testing.assert_array_equal(i1, i0[3:4])


@pytest.mark.parametrize("kind", ["random", "ties"])
def test_box_pruned_search_with_exclusion(kind):
    rng = np.random.default_rng(3)
    x = _data(kind, rng)
    n = len(x)
    groups, frames = np.arange(n) // 250, np.arange(n) % 250
    ix = KDTreeIndex(method="kdtree").build(x, groups=groups, frames=frames, tree=TreeSettings(leafsize=4))
    rows = np.arange(240, 270)  # crosses a clip boundary
    d, i = ix.query_rows(rows, 20, exclude=3)
    d0, i0 = knn(
        x, x[rows], 20, groups=groups, frames=frames, query_groups=groups[rows], query_frames=frames[rows], exclude=3
    )
    np.testing.assert_array_equal(i, i0)


def test_boxes_rebuilt_after_load_of_a_saved_index(tmp_path):
    # boxes are derived, not saved: an index saved without them loads and answers the same
    rng = np.random.default_rng(4)
    x = _data("clustered", rng)
    ix = KDTreeIndex(method="kdtree").build(x, tree=TreeSettings(leafsize=8))
    ix.save(tmp_path / "ix")
    assert not any("box" in p.name for p in (tmp_path / "ix").iterdir())
    back = KDTreeIndex.load(tmp_path / "ix")
    q = x[100:130] + np.float32(0.02)
    for a, b in zip(ix.query(q, 33), back.query(q, 33), strict=True):
        np.testing.assert_array_equal(a, b)
    for lo_a, lo_b in zip(ix._node_boxes(), back._node_boxes(), strict=True):
        np.testing.assert_array_equal(lo_a, lo_b)
