"""``indexes.sharded``: identical answers to one unsharded kd-tree, in pipelines too."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from mocapflow.framework import get_plugin_manager
from mocapflow.framework.executors import LocalExecutor
from mocapflow.framework.runner import run_pipeline
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex
from mocapflow.plugins.similarity.knn.sharded import ShardedIndex, _ShardQuery, shard_bounds

REPO = Path(__file__).resolve().parents[3]
CMU = REPO / "examples" / "data" / "cmu"


def clips_data(n_clips: int = 23, seed: int = 0, dim: int = 4):
    """Features of clips of random lengths, quantised so that many distances tie, with
    duplicated rows across clips."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(1, 60, n_clips)
    groups = np.repeat(np.arange(n_clips, dtype=np.int32) * 3 + 5, lengths)
    frames = np.concatenate([np.arange(n, dtype=np.int32) for n in lengths])
    x = np.round(rng.normal(size=(len(groups), dim)) * 2).astype(np.float32) / 2
    x[rng.choice(len(x), len(x) // 5)] = x[rng.choice(len(x), len(x) // 5)]
    return x, groups, frames


def test_shard_bounds_cut_only_between_clips():
    groups = np.repeat([0, 1, 2, 3, 4], [10, 1, 30, 2, 7])
    for n in (1, 2, 3, 4, 9):
        b = shard_bounds(groups, n)
        assert b[0] == 0 and b[-1] == len(groups) and np.all(np.diff(b) > 0)
        assert all(c == 0 or groups[c] != groups[c - 1] for c in b[:-1])
    assert len(shard_bounds(groups, 1, max_rows=15)) - 1 >= 3  # a 30-frame clip stays whole
    assert shard_bounds(np.zeros(0, np.int32), 3).tolist() == [0]


@pytest.mark.parametrize("shards", [1, 2, 3, 7])
def test_sharded_equals_one_kdtree_with_ties_radius_and_exclusion(shards):
    x, g, f = clips_data()
    one = KDTreeIndex(method="kdtree").build(x, groups=g, frames=f)
    sh = ShardedIndex(shards=shards, index_params={"method": "kdtree"}).build(x, groups=g, frames=f)
    assert len(sh.shards_) == min(shards, len(np.unique(g)))
    rng = np.random.default_rng(1)
    q = np.concatenate(
        [x[rng.choice(len(x), 30)], np.round(rng.normal(size=(20, x.shape[1])) * 2).astype(np.float32) / 2]
    )
    for k in (1, 5, 40, len(x) + 3):
        for radius in (None, 0.0, 1.0, 2.5):
            a, b = one.query(q, k, radius), sh.query(q, k, radius)
            np.testing.assert_array_equal(a[1], b[1])
            np.testing.assert_array_equal(a[0], b[0])
    rows = rng.choice(len(x), 25)
    for exclude in (0, 3, 20):
        a, b = one.query_rows(rows, 9, exclude=exclude), sh.query_rows(rows, 9, exclude=exclude)
        np.testing.assert_array_equal(a[1], b[1])
        np.testing.assert_array_equal(a[0], b[0])
        a = one.query(q, 9, 2.0, exclude=exclude, query_groups=g[:50], query_frames=f[:50])
        b = sh.query(q, 9, 2.0, exclude=exclude, query_groups=g[:50], query_frames=f[:50])
        np.testing.assert_array_equal(a[1], b[1])


def test_sharded_brute_force_shards_and_eps_zero_match_too():
    x, g, f = clips_data(seed=3, dim=12)
    one = KDTreeIndex(method="brute").build(x, groups=g, frames=f)
    sh = ShardedIndex(shards=4, index_params={"method": "brute"}).build(x, groups=g, frames=f)
    q = x[::7]
    for k in (3, 64):
        a, b = one.query(q, k), sh.query(q, k)
        np.testing.assert_array_equal(a[1], b[1])
        np.testing.assert_array_equal(a[0], b[0])


def _shard_identity(task: _ShardQuery):
    from mocapflow.framework.clip_refs import cached

    task(np.zeros((1, 4), np.float32))
    obj = cached(("index-shard", task.directory, task.stamp), lambda: None)
    return os.getpid(), task.directory, id(obj)


def test_saved_shards_answer_on_workers_loaded_once_per_process(tmp_path):
    x, g, f = clips_data(seed=5)
    sh = ShardedIndex(shards=3).build(x, groups=g, frames=f)
    sh.save(tmp_path / "index")
    loaded = ShardedIndex.load(tmp_path / "index")
    q = x[::5]
    ref = sh.query(q, 7, 2.0)
    ex = LocalExecutor(2, min_items_for_pool=1)
    try:
        for _ in range(2):
            got = loaded.query(q, 7, 2.0, executor=ex)
            np.testing.assert_array_equal(got[1], ref[1])
            np.testing.assert_array_equal(got[0], ref[0])
        tasks = [
            _ShardQuery(str(loaded.directory_ / f"shard-{s:03d}"), loaded.shard_cls_, loaded._stamp, 3, None, {})
            for s in range(3)
        ] * 6
        seen: dict[tuple[int, str], set[int]] = {}
        for pid, d, obj in ex.map(_shard_identity, tasks):
            seen.setdefault((pid, d), set()).add(obj)
        assert all(len(v) == 1 for v in seen.values())  # one loaded shard per process, reused by every task
    finally:
        ex.close()


@pytest.mark.parametrize("fan_out", ["queries", "shards"])
def test_both_fan_outs_on_workers_equal_one_kdtree(tmp_path, fan_out):
    """Query blocks (each worker asks every shard and merges) and shard tasks (each worker
    one shard, merged by the caller) give the unsharded answers, exclusion and radius too."""
    x, g, f = clips_data(seed=7)
    one = KDTreeIndex(method="kdtree").build(x, groups=g, frames=f)
    ShardedIndex(shards=3, fan_out=fan_out).build(x, groups=g, frames=f).save(tmp_path / "i")
    loaded = ShardedIndex.load(tmp_path / "i")
    assert loaded.params.fan_out == fan_out
    rows = np.arange(0, len(x), 3)
    ex = LocalExecutor(2, min_items_for_pool=1)
    try:
        for radius in (None, 1.5):
            a, b = one.query(x[rows], 6, radius), loaded.query(x[rows], 6, radius, executor=ex)
            np.testing.assert_array_equal(a[1], b[1])
            np.testing.assert_array_equal(a[0], b[0])
            a = one.query(x[rows], 6, radius, exclude=4, query_groups=g[rows], query_frames=f[rows])
            b = loaded.query(x[rows], 6, radius, exclude=4, query_groups=g[rows], query_frames=f[rows], executor=ex)
            np.testing.assert_array_equal(a[1], b[1])
            np.testing.assert_array_equal(a[0], b[0])
        a, b = one.query(x[:1], 6), loaded.query(x[:1], 6, executor=ex)  # a single query stays in-process
        np.testing.assert_array_equal(a[1], b[1])
    finally:
        ex.close()


def test_sharded_index_in_pipelines_gives_the_same_searches(tmp_path):
    (tmp_path / "p.yaml").write_text(f"""
name: sharded
workspace: ws
steps:
  motions: {{uses: formats.load, with: {{paths: ["{CMU}/**/*.amc"], fps: 30}}}}
  fe15: {{uses: features.end_effectors, input: motions}}
  tree: {{uses: indexes.kdtree, input: fe15}}
  shards: {{uses: indexes.sharded, input: fe15, with: {{shards: 3}}}}
  search_tree: {{uses: matchers.search, inputs: {{database: tree, query: motions}}, with: {{queries: ["16_15.amc:1s-2s", "02_01:10-50", "02_02:0-30", "35_01:5-40"], count: 5}}}}
  search_shards: {{uses: matchers.search, inputs: {{database: shards, query: motions}}, with: {{queries: ["16_15.amc:1s-2s", "02_01:10-50", "02_02:0-30", "35_01:5-40"], count: 5}}}}
  near_tree: {{uses: analyses.nearest_poses, inputs: {{index: tree, motions: motions}}, with: {{queries: ["02_01:30", "16_15:60"], k: 16, exclude_frames: 15}}}}
  near_shards: {{uses: analyses.nearest_poses, inputs: {{index: shards, motions: motions}}, with: {{queries: ["02_01:30", "16_15:60"], k: 16, exclude_frames: 15}}}}
""")
    from test_executors import table_bytes

    run_pipeline(tmp_path / "p.yaml", jobs=2, pm=get_plugin_manager(entry_points=False))
    ws = tmp_path / "ws"
    assert len(list((ws / "shards" / "index").glob("shard-*"))) == 3
    for a, b in (("search_tree", "search_shards"), ("near_tree", "near_shards")):
        assert table_bytes(ws / a / "data.parquet") == table_bytes(ws / b / "data.parquet"), a
    assert table_bytes(ws / "tree" / "data.parquet") == table_bytes(ws / "shards" / "data.parquet")
