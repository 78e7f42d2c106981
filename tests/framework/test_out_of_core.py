"""The out-of-core workspace build: steps stream their tables in batches, motions'
rotations are stored compactly, the kd-tree keeps no copy of the features; bad input (an
older index, a changed features dataset, a full disk) gives one clear error and leaves
nothing half-written."""

from __future__ import annotations

import errno
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml
from conftest import EXAMPLES_DATA
from synthetic import random_motion

from mocapflow.framework import get_plugin_manager, quaternions
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.errors import DataError, PipelineError
from mocapflow.framework.runner import run_pipeline


def pm():
    return get_plugin_manager(entry_points=False)


def pipeline(tmp_path: Path, index: bool = True) -> Path:
    steps = {
        "motions": {
            "uses": "formats.load",
            "with": {"paths": [str(EXAMPLES_DATA / "cmu" / "**" / "*.amc")], "fps": 30},
        },
        "fe15": {"uses": "features.end_effectors", "input": "motions", "with": {"joints": 5}},
    }
    if index:
        steps["tree"] = {"uses": "indexes.kdtree", "input": "fe15"}
    tmp_path.mkdir(parents=True, exist_ok=True)
    p = tmp_path / "p.yaml"
    p.write_text(yaml.safe_dump({"name": "ooc", "workspace": str(tmp_path / "ws"), "steps": steps}))
    return p


def naive_rotations(q: np.ndarray) -> np.ndarray:
    """What a float32 store of unit quaternions can give back: each rounded to float32 and renormalised."""
    r = np.asarray(q, np.float32).astype(np.float64)
    return r / np.linalg.norm(r, axis=-1, keepdims=True)


def test_smallest_three_rotations_round_trip_to_float32_accuracy():
    from mocapflow.framework.motion_tables import pack_rotations, unpack_rotations

    rng = np.random.default_rng(0)
    q = quaternions.normalize(rng.normal(size=(50, 7, 4)))
    q[:, 0] = [1.0, 0.0, 0.0, 0.0]  # a joint that never rotates
    q[3, 1] = [0.0, 0.0, 0.0, -1.0]  # a half turn: w = 0, the largest component negative
    q[4, 2] = [0.5, -0.5, 0.5, -0.5]  # four equal magnitudes
    largest, quats = pack_rotations(q)
    assert len(largest) == 50 * 7 and len(quats) == 50 * 7 * 3 * 4
    back = unpack_rotations(largest, quats, 50, 7)
    want = naive_rotations(q)
    same = np.abs(np.einsum("tjk,tjk->tj", back, want))  # q and -q are one rotation
    assert np.all(np.abs(same - 1.0) < 1e-12)
    assert np.abs(np.abs(back) - np.abs(want)).max() < 2e-7
    with pytest.raises(DataError, match="values for"):
        unpack_rotations(largest, quats[:-4], 50, 7)


def test_table_writer_streams_row_groups_with_the_provenance(tmp_path):
    from mocapflow.framework.workspace import TableWriter

    schema = pa.schema([("clip_id", pa.int32()), ("x", pa.float32())])
    w = TableWriter(tmp_path / "t.parquet", schema, row_group_rows=10)
    parts = [
        pa.table({"clip_id": pa.array(np.full(n, i, np.int32)), "x": pa.array(np.arange(n, dtype=np.float32))})
        for i, n in enumerate([7, 0, 8, 12])
    ]
    for t in parts:
        w.write(t)
    w.close({"step": "s"})
    f = pq.ParquetFile(tmp_path / "t.parquet")
    assert [f.metadata.row_group(i).num_rows for i in range(f.metadata.num_row_groups)] == [10, 10, 7]
    assert json.loads(f.metadata.metadata[b"mocapflow"]) == {"step": "s"}
    assert f.read().replace_schema_metadata(None).equals(pa.concat_tables(parts))
    assert w.num_rows == 27


def test_batches_give_the_same_workspace_as_one_batch(tmp_path, monkeypatch):
    """Ingest a file at a time and features a clip at a time: the same tables as in one batch;
    the rotations are those of the motions read, to float32 accuracy."""
    from mocapflow.framework import clip_refs
    from mocapflow.plugins.formats import steps

    run_pipeline(pipeline(tmp_path / "one", index=False), pm=pm(), jobs=1)
    monkeypatch.setattr(steps, "BATCH_FILES_PER_WORKER", 1)
    monkeypatch.setattr(steps, "ROTATION_GROUP_FRAMES", 100)
    monkeypatch.setattr(clip_refs, "BATCH_FRAMES", 100)
    run_pipeline(pipeline(tmp_path / "many", index=False), pm=pm(), jobs=1)
    for step, tables in (("motions", ("data", "rotations", "clips", "skeletons")), ("fe15", ("data",))):
        for name in tables:
            a = pq.read_table(tmp_path / "one" / "ws" / step / f"{name}.parquet").replace_schema_metadata(None)
            b = pq.ParquetFile(tmp_path / "many" / "ws" / step / f"{name}.parquet")
            assert b.read().replace_schema_metadata(None).equals(a), (step, name)
            if (step, name) == ("motions", "rotations"):
                assert b.metadata.num_row_groups > 1  # a clip slice decodes only the groups it needs
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc

    db = Dataset(tmp_path / "many" / "ws" / "motions").motions()
    first = resample(read_amc(EXAMPLES_DATA / "cmu" / "02" / "02_01.amc"), 30.0)
    m = next(x for x in db.motions if x.name == first.name)
    same = np.abs(np.einsum("tjk,tjk->tj", m.rotations, naive_rotations(first.rotations)))
    assert np.all(np.abs(same - 1.0) < 1e-12)


def test_first_layout_motions_are_still_read(tmp_path):
    """A motions dataset of the first layout (rotations per frame in ``data``) reads as before."""
    from mocapflow.framework.clip_refs import ClipSlice
    from mocapflow.framework.motion_tables import motions_to_tables
    from mocapflow.framework.workspace import Workspace

    ms = [random_motion(5, seed=1), random_motion(3, seed=2)]
    t = motions_to_tables(ms, [11, 7])
    rot = np.concatenate([m.rotations.astype(np.float32).reshape(m.n_frames, -1) for m in ms])
    flat = pa.ListArray.from_arrays(
        pa.array(np.arange(0, rot.size + 1, rot.shape[1], dtype=np.int32)), pa.array(rot.reshape(-1))
    )
    ws = Workspace(tmp_path)
    tmp = ws.temp_dir("motions")
    tables = {"data": t["data"].append_column("rotations", flat), "clips": t["clips"], "skeletons": t["skeletons"]}
    ws.write_step(tmp, "motions", tables, {"step": "motions", "component": "formats.load", "fingerprint": "x"})
    ds = Dataset(tmp_path / "motions")
    for db in (ds.motions(), ClipSlice(str(ds.path), "x", 0, 2).motions()):
        for m, r in zip(ms, db.motions, strict=True):
            np.testing.assert_allclose(r.rotations, naive_rotations(m.rotations), atol=1e-12)


def test_index_keeps_no_copy_of_the_features_and_says_when_to_rebuild(tmp_path):
    from mocapflow.framework.plugins import build_registries
    from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

    run_pipeline(pipeline(tmp_path), pm=pm(), jobs=1)
    ws = tmp_path / "ws"
    files = sorted(p.name for p in (ws / "tree" / "index").iterdir())
    assert "data.npy" not in files and not any(f.startswith("rows_") for f in files)
    feats = Dataset(ws / "fe15").features()
    idx = Dataset(ws / "tree").index(build_registries(pm()))
    built = KDTreeIndex().build(feats.x, groups=feats.clip_id, frames=feats.frame)
    q = feats.x[::97] + 0.01
    for a, b in zip(idx.query(q, 8), built.query(q, 8), strict=True):
        np.testing.assert_array_equal(a, b)
    x, cid, frame = idx.rows()
    np.testing.assert_array_equal(x, feats.x)
    np.testing.assert_array_equal(cid, feats.clip_id)
    # a file of the tree missing: built by an older version or cut short
    (ws / "tree" / "index" / "sval.npy").rename(ws / "sval.npy")
    with pytest.raises(DataError, match="older version.*rebuild"):
        KDTreeIndex.load(ws / "tree" / "index")
    (ws / "sval.npy").rename(ws / "tree" / "index" / "sval.npy")
    # the features it reads changed since (another run replaced them without the index)
    man = ws / "fe15" / "_manifest.json"
    man.write_text(json.dumps({**json.loads(man.read_text()), "fingerprint": "other"}))
    with pytest.raises(DataError, match="has changed since.*rebuild"):
        KDTreeIndex.load(ws / "tree" / "index")
    # an index saved by hand (or a shard) keeps every array, and loads anywhere
    built.save(tmp_path / "alone")
    alone = KDTreeIndex.load(tmp_path / "alone")
    np.testing.assert_array_equal(alone.rows()[0], feats.x)


def test_a_full_disk_fails_the_step_with_one_message_and_nothing_half_written(tmp_path, monkeypatch):
    from mocapflow.framework import workspace

    real = workspace.TableWriter.write
    calls = []

    def write(self, table):
        calls.append(1)
        if len(calls) > 3:  # a few clips in: the disk fills
            raise OSError(errno.ENOSPC, "No space left on device", str(self.path))
        real(self, table)

    monkeypatch.setattr(workspace.TableWriter, "write", write)
    with pytest.raises(PipelineError, match=r"motions.*cannot write its output \(No space left on device"):
        run_pipeline(pipeline(tmp_path, index=False), pm=pm(), jobs=1)
    ws = tmp_path / "ws"
    assert not (ws / "motions").exists()
    assert not any((ws / ".mocapflow" / "tmp").iterdir()) if (ws / ".mocapflow" / "tmp").exists() else True
    # the same when the runner writes a table itself (the footer, a small table)
    monkeypatch.setattr(workspace.TableWriter, "write", real)
    monkeypatch.setattr(
        workspace, "write_table", lambda *a: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device"))
    )
    with pytest.raises(PipelineError, match="cannot write its output"):
        run_pipeline(pipeline(tmp_path, index=False), pm=pm(), jobs=1)
    assert not (ws / "motions").exists()


def test_adding_takes_reads_only_the_new_files(tmp_path, monkeypatch):
    """A library grown by a take: the ingest reads only that file (and one whose bytes
    changed), copies the others' rows, says so, and writes the tables a full ingest writes."""
    import shutil

    from mocapflow.plugins.formats import steps

    lib = tmp_path / "lib"
    shutil.copytree(EXAMPLES_DATA / "cmu" / "02", lib / "02")
    shutil.copytree(EXAMPLES_DATA / "cmu" / "16", lib / "16")
    moved = sorted((lib / "16").glob("*.amc"))[-1]
    held = tmp_path / moved.name
    moved.rename(held)

    def make(ws: str) -> Path:
        p = tmp_path / f"{ws}.yaml"
        steps_ = {
            "motions": {"uses": "formats.load", "with": {"paths": [str(lib / "**" / "*.amc")], "fps": 30}},
            "fe15": {"uses": "features.end_effectors", "input": "motions", "with": {"joints": 5}},
        }
        p.write_text(yaml.safe_dump({"name": "inc", "workspace": str(tmp_path / ws), "steps": steps_}))
        return p

    run_pipeline(make("ws"), pm=pm(), jobs=1)
    held.rename(moved)  # the new take
    read = []
    real = steps._read_motion_rows
    monkeypatch.setattr(steps, "_read_motion_rows", lambda job: read.append(Path(job[2]).name) or real(job))
    lines = []
    reports = run_pipeline(make("ws"), pm=pm(), jobs=1, echo=lines.append)
    assert read == [moved.name]
    n = len(list(lib.glob("**/*.amc")))
    assert reports[0].summary["reused_clips"] == n - 1 and reports[0].summary["read_files"] == 1
    assert reports[1].summary["reused_clips"] == n - 1  # the features of the copied clips copied too
    assert sum("unchanged clips copied" in line for line in lines) == 2
    monkeypatch.setattr(steps, "_read_motion_rows", real)
    run_pipeline(make("full"), pm=pm(), jobs=1)
    for step, name in [("motions", t) for t in ("data", "rotations", "clips", "skeletons", "warnings")] + [
        ("fe15", "data")
    ]:
        a = pq.read_table(tmp_path / "ws" / step / f"{name}.parquet").replace_schema_metadata(None)
        b = pq.read_table(tmp_path / "full" / step / f"{name}.parquet").replace_schema_metadata(None)
        assert a.equals(b), (step, name)
    # a file whose bytes changed is read again; other parameters (fps) read everything
    edited = sorted((lib / "02").glob("*.amc"))[0]
    edited.write_text(edited.read_text() + "\n")
    read.clear()
    monkeypatch.setattr(steps, "_read_motion_rows", lambda job: read.append(Path(job[2]).name) or real(job))
    run_pipeline(make("ws"), pm=pm(), jobs=1)
    assert read == [edited.name]
    p = make("ws")
    p.write_text(p.read_text().replace("fps: 30", "fps: 20"))
    read.clear()
    reports = run_pipeline(p, pm=pm(), jobs=1)
    assert len(read) == n and "reused_clips" not in reports[1].summary
