"""analyses.fat_graph: greedy base poses against the quadratic reference, tables, plot."""

from __future__ import annotations

import numpy as np
import pytest
from naive.fat_graph import all_pairs_neighbours
from naive.fat_graph import clip_transitions as naive_transitions
from naive.fat_graph import greedy_cover as naive_greedy
from naive.knn import ckdtree_index_class

from mocapflow.plugins.similarity.applications._fat_graph_kernels import greedy_cover
from mocapflow.plugins.similarity.applications.fat_graph import (
    BasePoses,
    FatGraph,
    clip_transitions,
    cluster_runs,
    select_base_poses,
)

CKDTreeIndex = ckdtree_index_class()


def test_index_adapter_matches_all_pairs():
    x = np.random.default_rng(0).normal(size=(300, 4)).astype(np.float32)
    idx = CKDTreeIndex().build(x)
    _, ids = idx.query(x, 8, radius=1.2)
    _, ref = all_pairs_neighbours(x, 1.2, 8)
    assert np.array_equal(ids, ref)


@pytest.mark.parametrize("seed,n,k,radius", [(0, 200, 8, 0.8), (1, 157, 16, 1.5), (2, 50, 3, 0.5), (3, 120, 30, 5.0)])
def test_greedy_matches_naive(seed, n, k, radius):
    x = np.random.default_rng(seed).normal(size=(n, 3))
    _, ids = all_pairs_neighbours(x, radius, k)
    b, c, d = greedy_cover(ids, 0)
    rb, rc, rd = naive_greedy(ids)
    assert np.array_equal(b, rb) and np.array_equal(c, rc) and np.array_equal(d, rd)
    assert (c >= 0).all()
    # every frame lies in the neighbourhood of its base pose
    hood = {(int(f), int(g)) for f in range(n) for g in ids[f] if g >= 0}
    assert all(f == b[c[f]] or (int(b[c[f]]), f) in hood for f in range(n))


def test_greedy_count_limit_and_awkward_inputs():
    x = np.random.default_rng(4).normal(size=(90, 2))
    _, ids = all_pairs_neighbours(x, 0.7, 6)
    b, c, _ = greedy_cover(ids, 5)
    rb, rc, _ = naive_greedy(ids, 5)
    assert len(b) == 5 and np.array_equal(b, rb) and np.array_equal(c, rc)
    assert (c < 0).any()
    # one frame; isolated frames (radius 0 -> only duplicates); constant signal (all duplicates)
    b, c, d = greedy_cover(np.full((1, 4), -1), 0)
    assert b.tolist() == [0] and c.tolist() == [0] and d.tolist() == [1]
    b, c, _ = greedy_cover(np.full((7, 3), -1), 0)
    assert b.tolist() == list(range(7)) and c.tolist() == list(range(7))
    const = np.zeros((10, 3))
    _, ids = all_pairs_neighbours(const, 0.1, 4)  # capped: each row sees only frames 0..3
    b, c, _ = greedy_cover(ids, 0)
    rb, rc, _ = naive_greedy(ids)
    assert np.array_equal(b, rb) and np.array_equal(c, rc)


def test_select_base_poses_with_index_equals_quadratic():
    rng = np.random.default_rng(5)
    centres = rng.normal(scale=4.0, size=(6, 5))
    x = (centres[rng.integers(0, 6, 400)] + rng.normal(scale=0.3, size=(400, 5))).astype(np.float32)
    res = select_base_poses(x, 1.0, 32, CKDTreeIndex())
    _, ids = all_pairs_neighbours(x, 1.0, 32)
    rb, rc, _ = naive_greedy(ids)
    assert np.array_equal(res.bases, rb) and np.array_equal(res.cluster, rc)
    assert res.n_members.sum() == 400
    assert len(select_base_poses(np.zeros((0, 5), np.float32), 1.0, 4, CKDTreeIndex()).bases) == 0


def test_runs_and_transitions_respect_clip_boundaries():
    rng = np.random.default_rng(6)
    cluster = rng.integers(-1, 3, 60)
    offsets = np.array([0, 1, 20, 21, 60])  # includes one-frame clips
    rows, a, b = clip_transitions(cluster, offsets)
    clip = np.searchsorted(offsets, rows, side="right") - 1
    ref = naive_transitions(cluster, offsets)
    assert [(int(c), int(r - offsets[c]), int(x), int(y)) for c, r, x, y in zip(clip, rows, a, b, strict=True)] == ref
    s, e, c = cluster_runs(cluster, offsets)
    assert s[0] == 0 and e[-1] == 60 and np.all(e > s)
    assert set(offsets[:-1]) <= set(s.tolist())
    for st, en, cl in zip(s, e, c, strict=True):
        assert (cluster[st:en] == cl).all()


def test_tables_shape_and_graph_edges():
    clip_id = np.array([0] * 5 + [3] * 4, np.int32)
    frame = np.array([0, 1, 2, 3, 4, 0, 1, 2, 3], np.int32)
    res = BasePoses(np.array([1, 6]), np.array([0, 0, 1, 1, 0, 1, 1, 0, -1]), np.arange(9) + 1)
    t = FatGraph.tables(res, clip_id, frame, np.array([0, 5, 9]))
    assert t["transitions"].to_pylist() == [
        {"clip_id": 0, "frame": 2, "from_cluster": 0, "to_cluster": 1},
        {"clip_id": 0, "frame": 4, "from_cluster": 1, "to_cluster": 0},
        {"clip_id": 3, "frame": 2, "from_cluster": 1, "to_cluster": 0},
    ]
    assert t["edges"].to_pylist() == [
        {"from_cluster": 0, "to_cluster": 1, "n_transitions": 1},
        {"from_cluster": 1, "to_cluster": 0, "n_transitions": 2},
    ]
    assert t["base_poses"].column("n_members").to_pylist() == [4, 4]
    seg = t["segments"].to_pylist()
    assert seg[-1] == {"clip_id": 3, "start_frame": 3, "end_frame": 4, "cluster": -1}


def test_plot_writes_png(tmp_path):
    pytest.importorskip("matplotlib")
    from mocapflow.framework.joints import CANONICAL_JOINTS
    from mocapflow.plugins.similarity.applications.fat_graph import plot_base_poses

    pos = np.random.default_rng(0).normal(size=(3, len(CANONICAL_JOINTS), 3))
    plot_base_poses(pos, CANONICAL_JOINTS, tmp_path / "b.png", "t")
    assert (tmp_path / "b.png").stat().st_size > 1000


def test_pipeline_end_to_end(tmp_path):
    """pipelines/fat-graph.yaml on the bundled sample takes."""
    from conftest import REPO

    from mocapflow.framework import Dataset, get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    run_pipeline(
        REPO / "pipelines" / "fat-graph.yaml", workspace=tmp_path, jobs=1, pm=get_plugin_manager(entry_points=False)
    )
    out = Dataset(tmp_path / "fat_graph")
    data = out.table("data").to_pydict()
    bases = out.table("base_poses").to_pydict()
    n = len(data["frame"])
    assert n == 656 and min(data["cluster"]) == 0 and sum(bases["n_members"]) == n
    assert bases["n_neighbours"][0] == max(data["n_neighbours"])  # the first pick has the most neighbours
    assert (tmp_path / "fat_graph" / "base_poses.png").is_file()
    seg = out.table("segments").to_pydict()
    assert sum(e - s for s, e in zip(seg["start_frame"], seg["end_frame"], strict=True)) == n
