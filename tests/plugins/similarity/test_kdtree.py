"""indexes.kdtree against the naive brute force (tests/naive/knn.py)."""

from __future__ import annotations

import numpy as np
import pytest
from naive.knn import knn

from mocapflow.framework.errors import ConfigError, DataError
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex, TreeSettings

METHODS = ["kdtree", "brute"]


def _clustered(rng, n, d):
    centres = rng.normal(size=(5, d)) * 5
    return (centres[rng.integers(0, 5, n)] + 0.05 * rng.normal(size=(n, d))).astype(np.float32)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("kind", ["random", "clustered"])
def test_knn_equals_brute_force(method, kind):
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2000, 7)).astype(np.float32) if kind == "random" else _clustered(rng, 2000, 7)
    q = np.concatenate([x[:20] + 0.01, rng.normal(size=(20, 7)).astype(np.float32)])
    ix = KDTreeIndex(method=method).build(x, tree=TreeSettings(leafsize=8))
    for k in (1, 16, 300):
        d, i = ix.query(q, k)
        d0, i0 = knn(x, q, k)
        assert d.dtype == np.float32 and i.dtype == np.int64 and d.shape == (len(q), k)
        np.testing.assert_array_equal(i, i0)
        np.testing.assert_allclose(d, d0, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("method", METHODS)
def test_ties_resolve_by_row_id(method):
    # integer grid with many duplicates: distances tie exactly
    rng = np.random.default_rng(1)
    x = rng.integers(0, 3, size=(500, 3)).astype(np.float32)
    ix = KDTreeIndex(method=method).build(x, tree=TreeSettings(leafsize=4))
    d, i = ix.query(x[:30], 40)
    d0, i0 = knn(x, x[:30], 40)
    np.testing.assert_array_equal(i, i0)
    np.testing.assert_array_equal(d, d0.astype(np.float32))


@pytest.mark.parametrize("method", METHODS)
def test_radius_caps_and_pads(method):
    rng = np.random.default_rng(2)
    x = rng.normal(size=(1500, 4)).astype(np.float32)
    ix = KDTreeIndex(method=method).build(x)
    d, i = ix.query(x[:25], 50, radius=0.4)
    d0, i0 = knn(x, x[:25], 50, radius=0.4)
    np.testing.assert_array_equal(i, i0)
    assert np.all((d <= 0.4) | (i == -1)) and np.all(np.isinf(d[i == -1]))
    assert (i == -1).any() and (i != -1).sum(1).min() >= 1


@pytest.mark.parametrize("method", METHODS)
def test_exclusion_of_own_clip_window(method):
    rng = np.random.default_rng(3)
    # smooth clips: the nearest neighbours of a frame are its own neighbouring frames
    t = np.arange(600)
    x = np.stack([np.sin(t / 20), np.cos(t / 13), np.sin(t / 7)], 1).astype(np.float32)
    groups = t // 200
    frames = t % 200
    ix = KDTreeIndex(method=method).build(x, groups=groups, frames=frames, tree=TreeSettings(leafsize=8))
    rows = rng.choice(600, 30, replace=False)
    d, i = ix.query_rows(rows, 10, exclude=5)
    d0, i0 = knn(
        x, x[rows], 10, groups=groups, frames=frames, query_groups=groups[rows], query_frames=frames[rows], exclude=5
    )
    np.testing.assert_array_equal(i, i0)
    same = groups[i] == groups[rows][:, None]
    assert not np.any(same & (np.abs(frames[i] - frames[rows][:, None]) <= 5))


def test_eps_approximate_bound():
    rng = np.random.default_rng(4)
    x = _clustered(rng, 3000, 6)
    q = rng.normal(size=(40, 6)).astype(np.float32)
    ix = KDTreeIndex(method="kdtree").build(x)
    d, _ = ix.query(q, 8, eps=0.5)
    d0, _ = knn(x, q, 8)
    assert np.all(d[:, -1] <= 1.5 * d0[:, -1] + 1e-6)


def test_save_load_does_not_rebuild(tmp_path, monkeypatch):
    rng = np.random.default_rng(5)
    x = rng.normal(size=(800, 5)).astype(np.float32)
    ix = KDTreeIndex(method="kdtree").build(x, groups=np.arange(800) // 100, frames=np.arange(800) % 100)
    ix.save(tmp_path / "ix")
    from mocapflow.plugins.similarity.knn import _tree_kernels

    monkeypatch.setattr(_tree_kernels, "build_tree", None)  # load must not call it
    back = KDTreeIndex.load(tmp_path / "ix")
    assert back.method_ == "kdtree" and back.data_.dtype == np.float32
    # memory-mapped, not read into memory: the features are views of the saved file
    assert isinstance(back.data_.base, np.memmap) and back.data_.flags.writeable
    for a, b in zip(
        ix.query_rows(np.arange(10), 7, exclude=2), back.query_rows(np.arange(10), 7, exclude=2), strict=True
    ):
        np.testing.assert_array_equal(a, b)


def test_float32_stored_once_and_auto_reports_method():
    rng = np.random.default_rng(6)
    x = rng.normal(size=(3000, 12)).astype(np.float32)
    ix = KDTreeIndex().build(x, tree=TreeSettings(min_probe_rows=1000, probe_queries=8, probe_k=(4, 64)))
    assert ix.data_.dtype == np.float32 and ix.data_.nbytes == x.nbytes
    assert ix.method_ in ("kdtree", "brute") and set(ix.probe_) == {f"tree_share@{k}" for k in (4, 64)}
    assert ix.brute_from_k_ in (None, 16)
    # the choice counts work, never times it: the same data gives the same choice and counts
    again = KDTreeIndex().build(x, tree=TreeSettings(min_probe_rows=1000, probe_queries=8, probe_k=(4, 64)))
    assert (again.method_, again.brute_from_k_, again.probe_) == (ix.method_, ix.brute_from_k_, ix.probe_)
    for k in (3, 100):
        np.testing.assert_array_equal(ix.query(x[:5], k)[1], knn(x, x[:5], k)[1])
    ix.method_, ix.brute_from_k_, ix.large_method_ = "kdtree", 16, "brute"  # switching by k keeps answers exact
    assert ix.method_for(3) == "kdtree" and ix.method_for(16) == "brute"
    np.testing.assert_array_equal(ix.query(x[:5], 20)[1], knn(x, x[:5], 20)[1])
    ix.method_, ix.large_method_ = "brute", "kdtree"
    assert ix.method_for(3) == "brute" and ix.method_for(16) == "kdtree"
    np.testing.assert_array_equal(ix.query(x[:5], 3)[1], knn(x, x[:5], 3)[1])


def test_batches_switch_to_brute_force_by_the_batched_cost_model():
    from mocapflow.plugins.similarity.knn import cost_model as kdtree

    rng = np.random.default_rng(7)
    x = rng.normal(size=(4000, 10)).astype(np.float32)
    ix = KDTreeIndex().build(x, tree=TreeSettings(min_probe_rows=1000, probe_queries=8, probe_k=(4, 64)))
    ix.method_, ix.brute_from_k_ = "kdtree", None
    # the switch follows the saved probe counts and d only (share x d against the constant)
    ix.probe_ = {"tree_share@4": 0.1, "tree_share@64": kdtree.BATCH_BRUTE_FROM_WORK / 10}
    assert ix.batch_brute_from_k() == 16  # between the probed k: their geometric mean
    ix.probe_ = {"tree_share@4": kdtree.BATCH_BRUTE_FROM_WORK / 10, "tree_share@64": 1.0}
    assert ix.batch_brute_from_k() == 4
    ix.probe_ = {"tree_share@4": 0.01, "tree_share@64": 0.05}
    assert ix.batch_brute_from_k() is None
    ix.probe_ = {"tree_share@4": 0.1, "tree_share@64": 1.0}
    m = kdtree.BATCH_QUERIES
    assert ix.method_for(3, m) == "kdtree" and ix.method_for(16, m) == "brute" and ix.method_for(16, m - 1) == "kdtree"
    # a batch answered by brute force equals the naive reference and the one-by-one tree answers
    q = x[rng.choice(len(x), m + 3, replace=False)] + 0.01
    d, i = ix.query(q, 20)
    np.testing.assert_array_equal(i, knn(x, q, 20)[1])
    for r in range(0, len(q), 9):
        np.testing.assert_array_equal(ix.query(q[r : r + 1], 20)[1][0], i[r])
    # an index that is not `auto` keeps its method
    fixed = KDTreeIndex(method="kdtree").build(x)
    fixed.probe_ = ix.probe_
    assert fixed.method_for(16, m) == "kdtree"


def test_awkward_inputs():
    one = KDTreeIndex().build(np.ones((1, 3), np.float32))
    d, i = one.query(np.zeros(3), 4)
    assert i.tolist() == [[0, -1, -1, -1]] and np.isinf(d[0, 1:]).all()
    same = KDTreeIndex().build(np.zeros((50, 2), np.float32), tree=TreeSettings(leafsize=2))  # constant features
    assert same.query(np.zeros(2), 5)[1].tolist() == [[0, 1, 2, 3, 4]]
    with pytest.raises(DataError):
        same.query(np.zeros(3), 1)
    with pytest.raises(DataError):
        KDTreeIndex().build(np.full((3, 2), np.nan, np.float32))
    with pytest.raises(ConfigError):
        same.query(np.zeros(2), 1, exclude=3)
    with pytest.raises(DataError):
        KDTreeIndex().query(np.zeros(2), 1)


def test_brute_force_massive_ties_fall_back_exactly():
    x = np.zeros((1500, 4), np.float32)
    x[::7] = 1.0
    ix = KDTreeIndex(method="brute").build(x)
    d, i = ix.query(np.zeros((2, 4), np.float32), 5)
    assert i.tolist() == [[1, 2, 3, 4, 5]] * 2 and not d.any()
    d, i = ix.query(np.ones((1, 4), np.float32), 3, radius=0.5)
    assert i.tolist() == [[0, 7, 14]]
    from mocapflow.plugins.similarity.knn._brute import brute_knn  # the blocked path overflows its buffers here

    z = np.zeros(2, np.int64)
    d2, i = brute_knn(
        np.zeros((2, 4), np.float32),
        x,
        ix.mean_,
        ix.sqnorms_,
        5,
        np.inf,
        ix.groups_,
        ix.frames_,
        z,
        z,
        -1,
        ids=ix.perm_,
        lean_max_rows=0,
    )
    assert i.tolist() == [[1, 2, 3, 4, 5]] * 2 and not d2.any()


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("case", ["plain", "radius", "exclude", "ties", "clip_end"])
def test_consecutive_queries_seeded_search_is_exact(case, workers):
    # the kd-tree seeds each query's bound from the previous query's neighbours and their
    # successor rows: smooth clips (the LNG's case), ties, radius, exclusion, the last rows
    rng = np.random.default_rng(7)
    t = np.arange(1200)
    x = np.stack([np.sin(t / 17), np.cos(t / 11), np.sin(t / 5 + 1)], 1) + 0.01 * rng.normal(size=(1200, 3))
    x = x.astype(np.float32)
    if case == "ties":
        x = np.round(x * 2).astype(np.float32)
    groups, frames = t // 300, t % 300
    rows = np.arange(1180, 1200) if case == "clip_end" else np.arange(400, 440)
    ix = KDTreeIndex(method="kdtree", workers=workers).build(
        x, groups=groups, frames=frames, tree=TreeSettings(leafsize=8)
    )
    kw = {"radius": 0.3} if case == "radius" else {}
    ref = {"radius": 0.3} if case == "radius" else {}
    if case == "exclude":
        d, i = ix.query_rows(rows, 25, exclude=4)
        ref = dict(groups=groups, frames=frames, query_groups=groups[rows], query_frames=frames[rows], exclude=4)
    else:
        d, i = ix.query(x[rows] + np.float32(0.003), 25, **kw)
    d0, i0 = knn(x, x[rows] + (0 if case == "exclude" else np.float32(0.003)), 25, **ref)
    np.testing.assert_array_equal(i, i0)
    np.testing.assert_allclose(d, d0, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("case", ["clustered", "ties", "radius", "exclude"])
def test_brute_single_query_lean_path_is_exact(case):
    # small databases take the lean brute path (GEMV, sampled k-th, exact re-rank)
    rng = np.random.default_rng(8)
    x = _clustered(rng, 3000, 9) if case != "ties" else rng.integers(0, 3, size=(3000, 4)).astype(np.float32)
    groups, frames = np.arange(3000) // 500, np.arange(3000) % 500
    ix = KDTreeIndex(method="brute").build(x, groups=groups, frames=frames)
    rows = rng.choice(3000, 12, replace=False)
    kw, ref = {}, {}
    if case == "radius":
        kw = ref = {"radius": 0.12}
    if case == "exclude":
        kw = dict(exclude=30, query_groups=groups[rows], query_frames=frames[rows])
        ref = dict(groups=groups, frames=frames, query_groups=groups[rows], query_frames=frames[rows], exclude=30)
    # k = 1 / 40 / 300: sampled threshold; 400 > n / 8: the full heap; ties overflow the buffer
    for k in (1, 40, 300, 400):
        d0, i0 = knn(x, x[rows], k, **ref)
        for per_call in (1, 3):  # one query per call: one compiled call; three: one GEMM per block
            for a in range(0, 12, per_call):
                sub = {key: (v[a : a + per_call] if key.startswith("query_") else v) for key, v in kw.items()}
                d, i = ix.query(x[rows[a : a + per_call]], k, **sub)
                np.testing.assert_array_equal(i, i0[a : a + per_call])
                np.testing.assert_allclose(d, d0[a : a + per_call], rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(ix.query(x[rows], k, **kw)[1], i0)  # the blocked path agrees


@pytest.mark.parametrize("case", ["clustered", "ties", "radius", "exclude"])
def test_blocked_brute_path_equals_naive(case):
    # databases over lean_max_rows take the blocked path: force it on a small one
    from mocapflow.plugins.similarity.knn._brute import brute_knn

    rng = np.random.default_rng(9)
    x = _clustered(rng, 2500, 6) if case != "ties" else rng.integers(0, 3, size=(2500, 3)).astype(np.float32)
    groups, frames = (np.arange(2500) // 400).astype(np.int32), (np.arange(2500) % 400).astype(np.int32)
    rows = rng.choice(2500, 20, replace=False)
    mean = x.mean(0, dtype=np.float64).astype(np.float32)
    sqn = np.einsum("ij,ij->i", x - mean, x - mean)
    r2 = 0.15**2 if case == "radius" else np.inf
    excl = 20 if case == "exclude" else -1
    d2, i = brute_knn(
        x[rows],
        x,
        mean,
        sqn,
        30,
        r2,
        groups,
        frames,
        groups[rows].astype(np.int64),
        frames[rows].astype(np.int64),
        excl,
        lean_max_rows=0,
        block_rows=700,
        block_queries=8,
    )
    ref = (
        dict(groups=groups, frames=frames, query_groups=groups[rows], query_frames=frames[rows], exclude=20)
        if case == "exclude"
        else ({"radius": 0.15} if case == "radius" else {})
    )
    d0, i0 = knn(x, x[rows], 30, **ref)
    np.testing.assert_array_equal(i, i0)
    np.testing.assert_allclose(np.sqrt(d2), d0, rtol=1e-6, atol=1e-6)


def test_kdtree_single_row_queries_take_the_lean_call_exactly():
    rng = np.random.default_rng(11)
    x = _clustered(rng, 1500, 5)
    ix = KDTreeIndex(method="kdtree").build(x, tree=TreeSettings(leafsize=8))
    q = (x[:12] + np.float32(0.002)).astype(np.float32)
    for k in (1, 16, 200):
        d0, i0 = knn(x, q, k)
        for r in range(len(q)):  # the first call builds the cached arguments, later ones use them
            d, i = ix.query(q[r : r + 1], k)
            np.testing.assert_array_equal(i[0], i0[r])
            np.testing.assert_allclose(d[0], d0[r], rtol=1e-6, atol=1e-6)
    assert ix._interactive(q[:1], 16, None, 0.0, None) is not None  # the lean call was taken
    assert ix._interactive(q[:1].astype(np.float64), 16, None, 0.0, None) is None


def test_tree_work_counts_the_buckets_within_the_kth_distance():
    # the auto cost model's counts against a plain reading of the tree: every leaf whose
    # points' box lies within the k-th neighbour distance, and every node visited on the way
    from mocapflow.plugins.similarity.knn import _knn_kernels as kern

    rng = np.random.default_rng(11)
    x = rng.normal(size=(2000, 5)).astype(np.float32)
    ix = KDTreeIndex(method="kdtree").build(x, tree=TreeSettings(leafsize=16))
    q = x[:7].astype(np.float64)
    d2 = knn(x, x[:7], 9)[0].astype(np.float64) ** 2
    _, _, start, end, left, right, _, _, blo, bhi = ix._tree_args()[0][:10]
    pts, nds = kern.tree_work(q, d2[:, -1] * (1 + 1e-9), start, end, left, right, blo, bhi, ix._max_depth())
    for r in range(len(q)):

        def gap(node, r=r):
            g = np.maximum(np.maximum(blo[node] - q[r], q[r] - bhi[node]), 0.0)
            return float((g.astype(np.float64) ** 2).sum())

        want_pts, want_nodes, todo = 0, 0, [0]
        while todo:
            node = todo.pop()
            want_nodes += 1
            if gap(node) > d2[r, -1] * (1 + 1e-9):
                continue
            if left[node] < 0:
                want_pts += end[node] - start[node]
            else:
                todo += [left[node], right[node]]
        assert (pts[r], nds[r]) == (want_pts, want_nodes)
        assert want_pts >= 9  # the k neighbours lie in buckets within reach
