"""The knn-study pipeline plans; a small variant runs end to end on the bundled sample takes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import EXAMPLES_DATA, REPO

SMALL = """
name: knn-small
workspace: {ws}
steps:
  motions: {{uses: formats.load, with: {{paths: ["{data}/cmu/02/*.amc"], fps: 30}}}}
  fe15x3:  {{uses: features.end_effectors, input: motions, with: {{joints: 5, samples: 3}}}}
  pca8:    {{uses: features.pca, inputs: {{motions: motions, reference: motions}}, with: {{n_components: 8}}}}
  pca8b:   {{uses: features.pca, inputs: {{motions: motions, reference: pca8}}, with: {{n_components: 8}}}}
  tree:    {{uses: indexes.kdtree, input: fe15x3}}
  poses:
    uses: analyses.nearest_poses
    inputs: {{index: tree, motions: motions}}
    with: {{queries: ["{clip}:10", "{clip_id}:5"], k: 16, exclude_frames: 0}}
  correlation:
    uses: analyses.distance_correlation
    input: motions
    with: {{samples: 8, k: 16, measures: [F_E15, F_E15x3, D_pc1]}}
"""


def test_knn_study_plans():
    from mocapflow.framework.runner import plan_pipeline

    plan_pipeline(REPO / "pipelines" / "knn-study.yaml")


def test_small_knn_pipeline_end_to_end(tmp_path):
    from mocapflow.framework import Dataset
    from mocapflow.framework.runner import run_pipeline

    files = sorted((EXAMPLES_DATA / "cmu" / "02").glob("*.amc"))
    if not files:
        import pytest

        pytest.skip("no bundled sample takes")
    y = tmp_path / "p.yaml"
    from mocapflow.framework.schema import clip_id_of

    # a query by clip id: the stable id of the second take (hash of its folder and name)
    cid = clip_id_of(f"02/{files[1].name}")
    y.write_text(SMALL.format(ws=tmp_path / "ws", data=EXAMPLES_DATA, clip=files[0].stem, clip_id=cid))
    run_pipeline(y)
    ws = tmp_path / "ws"
    poses = Dataset(ws / "poses").table()
    assert poses.num_rows == 32 and set(poses["rank"].to_pylist()) == set(range(16))
    assert {r["query_clip_id"] for r in poses.to_pylist() if r["query_id"] == 1} == {cid}
    q0 = [r for r in poses.to_pylist() if r["query_id"] == 0]
    assert all(not (r["clip_id"] == r["query_clip_id"] and r["frame"] == r["query_frame"]) for r in q0)
    d = [r["distance"] for r in q0]
    assert d == sorted(d)
    import mocapflow

    tree = Dataset(ws / "tree").index(mocapflow.registries())
    assert tree.method_ in ("kdtree", "brute")
    a = Dataset(ws / "pca8").features().x
    b = Dataset(ws / "pca8b").features().x
    np.testing.assert_array_equal(a, b)  # the model fitted by pca8 is reused by pca8b
    assert (ws / "correlation" / "correlation.png").is_file()
    m = Dataset(ws / "correlation").table("matrix").to_pylist()
    assert [r["row_measure"] for r in m] == ["F_E15", "F_E15x3", "D_pc1"] and m[0]["F_E15"] == 1.0
    assert Path(ws / "pca8" / "pca_model.npz").is_file()


def test_benchmark_corpus_cache_key_ignores_int_vs_float_fps(tmp_path):
    import sys

    from conftest import REPO

    sys.path.insert(0, str(REPO / "benchmarks"))
    from corpus import cache_path

    assert cache_path(1000, 30, 0, tmp_path) == cache_path(1000, 30.0, 0, tmp_path)
    assert cache_path(1000, 30, 0, tmp_path) != cache_path(1000, 60, 0, tmp_path)
