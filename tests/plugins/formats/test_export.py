"""Hits exported as clips in their source's format, rate and rig (``Matches.export``,
``mocapflow export``), match tables in the sources' units, ``exclude_self``, and
``mocapflow.read`` of marker files."""

from __future__ import annotations

import csv
import glob
import textwrap
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA

ROOT = Path(__file__).resolve().parents[3]
CMU = ROOT / "examples" / "data" / "cmu"
WALK, OTHER = CMU / "16" / "16_15.amc", CMU / "02" / "02_01.amc"


def _same_clip(written: Path, source, start: int, end: int) -> None:
    """The file re-reads as frames [start, end) of the source: rate, joint names, root, positions within 1e-4 m."""
    import mocapflow

    back = mocapflow.read(written)
    assert back.fps == pytest.approx(source.fps)
    assert back.skeleton.names == source.skeleton.names
    assert back.n_frames == end - start
    np.testing.assert_allclose(back.positions, source.positions[start:end], atol=1e-4, rtol=0)


@pytest.fixture(scope="module")
def walk_db():
    import mocapflow

    return mocapflow.Database([OTHER, WALK])


def test_search_answers_in_the_sources_units_and_excludes_the_query(walk_db):
    import mocapflow

    walk = mocapflow.read(WALK)
    q = walk.slice(120, 240)  # one second of the walk at 120 Hz, inside the database
    hits = walk_db.search(q, count=5)
    assert hits.query == "16_15:120-240"
    rows = hits.to_pylist()
    assert rows and {
        "fps",
        "start_frame",
        "end_frame",
        "start_s",
        "end_s",
        "path_analysis",
        "start_frame_analysis",
    } <= set(hits.column_names)
    for r in rows:
        assert r["fps"] == 120.0  # the take's own rate, not the database's 30 Hz
        assert r["start_s"] == pytest.approx(r["start_frame"] / 120) and r["end_s"] == pytest.approx(
            r["end_frame"] / 120
        )
        if r["clip"] == "16_15":  # nothing within half a query length (60 frames) of its span
            assert r["end_frame"] <= 120 - 60 or r["start_frame"] >= 240 + 60
    own = walk_db.search(q, count=5, exclude_self="off").to_pylist()[0]
    assert (own["clip"], own["start_frame"], own["end_frame"]) == ("16_15", 120, 240)
    clip = walk_db.search(q, count=5, exclude_self="clip").to_pylist()
    assert clip and all(r["clip"] == "02_01" for r in clip)
    # a take from elsewhere (same motion, another file) is not excluded
    other = walk.slice(120, 240).with_arrays(metadata={})
    assert walk_db.search(other, count=1).to_pylist()[0]["start_frame"] == 120


def test_matches_export_writes_amc_clips_at_the_source_rate(walk_db, tmp_path):
    import mocapflow

    hits = walk_db.search(mocapflow.read(WALK).slice(120, 240), count=3)
    index = hits.export(tmp_path, handle=8)
    assert index.num_rows == hits.num_rows
    assert sorted(p.name for p in tmp_path.iterdir()) == ["16_15_120-240", "index.csv"]
    with open(tmp_path / "index.csv") as f:
        assert [int(r["rank"]) for r in csv.DictReader(f)] == list(range(1, hits.num_rows + 1))
    sources = {}
    for r in index.to_pylist():
        src = sources.setdefault(r["source"], mocapflow.read(r["source"]))
        assert r["clip_start"] == max(0, r["start_frame"] - 8) and r["clip_end"] == min(
            src.n_frames, r["end_frame"] + 8
        )
        assert r["file"].endswith(".amc") and (tmp_path / r["file"]).with_suffix(".asf").is_file()
        _same_clip(tmp_path / r["file"], src, r["clip_start"], r["clip_end"])


def test_matches_export_writes_bvh_sources_as_bvh(tmp_path):
    import mocapflow

    src = mocapflow.read(WALK).slice(0, 300)
    mocapflow.write(src, tmp_path / "walk.bvh")
    bvh = mocapflow.read(tmp_path / "walk.bvh")
    hits = mocapflow.Database([tmp_path / "walk.bvh"]).search(bvh.slice(40, 100), count=2, exclude_self="off")
    index = hits.export(tmp_path / "out").to_pylist()
    assert index[0]["file"] == "walk_40-100/01_walk_40-100.bvh"
    for r in index:
        _same_clip(tmp_path / "out" / r["file"], bvh, r["start_frame"], r["end_frame"])


def test_read_and_write_markers(tmp_path):
    import mocapflow

    walk = mocapflow.read(WALK)
    m = mocapflow.Markers(walk.skeleton.names, walk.positions[:40], walk.fps, name="walk")
    mocapflow.write(m, tmp_path / "walk.trc")
    back = mocapflow.read(tmp_path / "walk.trc")
    assert isinstance(back, mocapflow.Markers) and back.labels == m.labels and back.fps == m.fps
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6)


@pytest.mark.parametrize("pattern", ["trc/opensim/*.trc", "c3d/cmu/*.c3d"])
def test_read_corpus_markers(pattern):
    import mocapflow

    files = sorted(glob.glob(str(SHARED_DATA / pattern)))
    if not files:
        pytest.skip(f"real corpus not found at {SHARED_DATA} (expected ../shared/data beside the repository)")
    if pattern.endswith("c3d"):
        pytest.importorskip("c3d")
    m = mocapflow.read(files[0])
    assert isinstance(m, mocapflow.Markers) and m.n_frames > 0 and m.positions.shape[1] == len(m.labels)


def _bandai() -> Path:
    files = sorted(glob.glob(str(SHARED_DATA / "bvh" / "bandai_namco_1" / "*.bvh")))
    if not files:
        pytest.skip(f"Bandai-Namco BVH not found under {SHARED_DATA} (expected ../shared/data beside the repository)")
    return Path(files[0])


def test_bandai_rig_survives_write_tables_and_export(tmp_path):
    """A BVH whose static root (joint_Root) the reader drops is written back with it: a rig
    that binds by name keeps its root and joint count, also after a motions dataset round trip."""
    import mocapflow
    from mocapflow.framework.motion_tables import database_from_tables, motions_to_tables
    from mocapflow.plugins.formats.bvh import read_bvh

    path = _bandai()
    raw = read_bvh(path, collapse_static_root=False)
    motion = mocapflow.read(path)
    assert raw.skeleton.names[0] == "joint_Root" and motion.skeleton.names[0] == "Hips"
    t = motions_to_tables([motion])
    stored = database_from_tables(t["clips"], t["skeletons"], t["data"], t["rotations"]).motions[0]
    mocapflow.write(stored.slice(10, 70), tmp_path / "clip.bvh")
    back = read_bvh(tmp_path / "clip.bvh", collapse_static_root=False)
    assert back.skeleton.names == raw.skeleton.names and back.fps == pytest.approx(raw.fps)
    np.testing.assert_allclose(back.positions, raw.positions[10:70], atol=1e-4, rtol=0)
    # an exported hit of that take, through the registry
    hits = mocapflow.Database([path], fps=None).search(motion.slice(20, 60), count=1, exclude_self="off")
    r = hits.export(tmp_path / "out", handle=5).to_pylist()[0]
    assert (r["clip_start"], r["clip_end"]) == (15, 65)
    out = read_bvh(tmp_path / "out" / r["file"], collapse_static_root=False)
    assert out.skeleton.names == raw.skeleton.names
    np.testing.assert_allclose(out.positions, raw.positions[15:65], atol=1e-4, rtol=0)


PIPELINE = """
name: export-test
workspace: {ws}
steps:
  motions:
    uses: formats.load
    with: {{paths: ["{cmu}/02/02_01.amc", "{cmu}/16/16_15.amc"], fps: 30}}
  fe:
    uses: features.end_effectors
    input: motions
    with: {{joints: 5}}
  tree:
    uses: indexes.kdtree
    input: fe
  search:
    uses: matchers.search
    inputs: {{database: tree, query: motions}}
    with: {{queries: ["16_15:120-240"], count: 3}}
"""


@pytest.fixture(scope="module")
def search_workspace(tmp_path_factory) -> Path:
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    d = tmp_path_factory.mktemp("export-ws")
    (d / "p.yaml").write_text(textwrap.dedent(PIPELINE.format(ws=d / "ws", cmu=CMU)))
    run_pipeline(d / "p.yaml", workspace=d / "ws", pm=get_plugin_manager(entry_points=False))
    return d / "ws"


def test_pipeline_search_excludes_the_query_span(search_workspace):
    import pyarrow.parquet as pq

    t = pq.read_table(search_workspace / "search" / "data.parquet").to_pylist()
    clip_16 = {
        r["clip_id"]
        for r in pq.read_table(search_workspace / "motions" / "clips.parquet").to_pylist()
        if r["name"] == "16_15"
    }
    assert t
    for r in t:  # the hit in the take's own units: 120-Hz frames of the AMC, seconds; 30 Hz in *_analysis
        assert r["fps"] == 120.0 and r["start_frame"] == 4 * r["start_frame_analysis"]
        assert r["fps_analysis"] == 30.0 and r["start_s"] == pytest.approx(r["start_frame_analysis"] / 30)
        assert r["end_s"] == pytest.approx(r["end_frame"] / 120)  # the take's end, when clamped
        # the deprecated duplicates of one release
        assert (r["source_fps"], r["source_start_frame"], r["source_end_frame"]) == (
            r["fps"],
            r["start_frame"],
            r["end_frame"],
        )
    for r in t:  # query source frames [120, 240) = [30, 60) at 30 Hz, zone 15 frames each side
        if r["clip_id"] in clip_16:
            assert r["end_frame_analysis"] <= 15 or r["start_frame_analysis"] >= 75


def test_cli_export_and_search_units(search_workspace, tmp_path, capsys):
    import mocapflow
    from mocapflow.framework.cli import main

    assert main(["export", str(search_workspace), "--output", str(tmp_path / "clips"), "--handle", "4"]) == 0
    with open(tmp_path / "clips" / "index.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows and {r["query"] for r in rows} == {"16_15:120-240"}
    for r in rows:
        src = mocapflow.read(r["source"])
        assert float(r["fps"]) == 120.0 and r["file"].startswith("16_15_120-240/")
        _same_clip(tmp_path / "clips" / r["file"], src, int(r["clip_start"]), int(r["clip_end"]))
    out = tmp_path / "hits.csv"
    argv = ["search", "--db", str(search_workspace), "--query", "16_15:120-240", "--no-server", "--out", str(out)]
    assert main(argv) == 0
    assert "its own span excluded" in capsys.readouterr().out
    with open(out) as f:
        hits = list(csv.DictReader(f))
    assert hits and all(float(h["fps"]) == 120.0 for h in hits)
    assert all(float(h["start_s"]) == pytest.approx(int(h["start_frame"]) / 120) for h in hits)
    assert main(["export", str(search_workspace), "--step", "nosuch"]) == 2
