"""The ingest step ``formats.load`` on real files: counts, rejects, resampling, resume."""

from __future__ import annotations

import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from conftest import EXAMPLES_DATA, corpus_path

from mocapflow.framework import get_plugin_manager
from mocapflow.framework.catalog import Catalog
from mocapflow.framework.runner import run_pipeline


def pm():
    return get_plugin_manager(entry_points=False)


def pipeline(tmp_path: Path, paths: list[str], **extra) -> Path:
    with_ = {"paths": paths, **extra}
    p = tmp_path / "ingest.yaml"
    import yaml

    p.write_text(
        yaml.safe_dump(
            {
                "name": "ingest",
                "workspace": str(tmp_path / "ws"),
                "steps": {"motions": {"uses": "formats.load", "with": with_}},
            }
        )
    )
    return p


def test_sample_data_ingest_and_resample(tmp_path):
    p = pipeline(tmp_path, [str(EXAMPLES_DATA / "cmu" / "**" / "*.amc")], fps=30)
    run_pipeline(p, pm=pm())
    clips = pq.read_table(tmp_path / "ws" / "motions" / "clips.parquet").to_pylist()
    assert len(clips) == 8 and all(c["fps"] == 30 and c["source_fps"] == 120 for c in clips)
    for c in clips:
        assert c["n_frames"] == (c["source_frames"] - 1) // 4 + 1
        assert c["format"] == "amc" and len(c["checksum"]) == 40 and c["subject"] in {"02", "16", "35"}


def test_corrupted_files_land_in_rejects_and_the_rest_finishes(tmp_path):
    src = EXAMPLES_DATA / "cmu" / "02"
    bad = tmp_path / "data"
    bad.mkdir()
    shutil.copy(src / "02.asf", bad)
    shutil.copy(src / "02_01.amc", bad / "good.amc")
    lines = (src / "02_02.amc").read_text().splitlines(keepends=True)
    (bad / "truncated.amc").write_text("".join(lines[: len(lines) // 2 - 3]))
    text = (src / "02_03.amc").read_text().split("\n")
    text[40] = text[40].rsplit(" ", 1)[0] + " nan"
    (bad / "nanvalue.amc").write_text("\n".join(text))
    (bad / "garbage.amc").write_bytes(bytes(range(256)) * 40)
    (bad / "empty.amc").write_text("")
    p = pipeline(tmp_path, [str(bad / "*.amc")])
    reports = run_pipeline(p, pm=pm())
    assert reports[0].summary["clips"] == 1 and reports[0].summary["rejects"] == 4
    rejects = {
        Path(r["path"]).name: r for r in pq.read_table(tmp_path / "ws" / "motions" / "rejects.parquet").to_pylist()
    }
    assert set(rejects) == {"truncated.amc", "nanvalue.amc", "garbage.amc", "empty.amc"}
    assert rejects["nanvalue.amc"]["line"] == 41
    assert rejects["truncated.amc"]["line"] is not None
    for r in rejects.values():
        assert r["message"]
    # on_error: fail stops at the first bad file, naming it
    p = pipeline(tmp_path, [str(bad / "*.amc")], on_error="fail")
    from mocapflow.framework import PipelineError

    with pytest.raises(PipelineError, match=r"\.amc:\d+"):
        run_pipeline(p, pm=pm(), force=True)


def test_parallel_ingest_equals_serial(tmp_path):
    p = pipeline(tmp_path, [str(EXAMPLES_DATA / "cmu" / "**" / "*.amc")])
    run_pipeline(p, pm=pm(), jobs=1)
    serial = pq.read_table(tmp_path / "ws" / "motions" / "data.parquet")
    run_pipeline(p, pm=pm(), jobs=2, force=True)
    assert pq.read_table(tmp_path / "ws" / "motions" / "data.parquet").equals(serial)


def test_changed_file_recomputes(tmp_path):
    data = tmp_path / "d"
    shutil.copytree(EXAMPLES_DATA / "cmu" / "02", data)
    p = pipeline(tmp_path, [str(data / "*.amc")])
    run_pipeline(p, pm=pm())
    assert run_pipeline(p, pm=pm())[0].status == "up to date"
    (data / "02_01.amc").unlink()
    again = run_pipeline(p, pm=pm())
    assert again[0].status == "computed" and again[0].summary["clips"] == 3


@pytest.mark.slow
def test_whole_corpus_ingest_has_no_rejects_and_exact_frame_counts(tmp_path):
    root = corpus_path()
    p = pipeline(
        tmp_path,
        [
            str(root / "cmu" / "amc" / "**" / "*.amc"),
            str(root / "hdm05" / "amc" / "**" / "*.amc"),
            str(root / "bvh" / "**" / "*.bvh"),
        ],
    )
    run_pipeline(p, pm=pm(), jobs=2)
    with Catalog(tmp_path / "ws") as cat:
        assert cat.query("SELECT count(*) AS n FROM rejects").column("n")[0].as_py() == 0
        amc = cat.query(
            "SELECT count(*) AS clips, sum(n_frames) AS frames FROM clips WHERE format = 'amc'"
        ).to_pylist()[0]
        assert amc == {"clips": 169, "frames": 110109}
        bvh = cat.query("SELECT count(*) AS n FROM clips WHERE format = 'bvh'").column("n")[0].as_py()
        assert bvh == len(list((root / "bvh").rglob("*.bvh")))
        # every frame row is there
        assert (
            cat.query("SELECT count(*) AS n FROM motions").column("n")[0].as_py()
            == cat.query("SELECT sum(n_frames) AS n FROM clips").column("n")[0].as_py()
        )


def test_marker_files_ingest(tmp_path):
    root = corpus_path()
    files = sorted((root / "c3d").rglob("*.c3d")) + sorted((root / "trc").rglob("*.trc"))
    p = tmp_path / "m.yaml"
    import yaml

    p.write_text(
        yaml.safe_dump(
            {
                "name": "m",
                "workspace": str(tmp_path / "ws"),
                "steps": {"markers": {"uses": "formats.load_markers", "with": {"paths": [str(f) for f in files[:3]]}}},
            }
        )
    )
    run_pipeline(p, pm=pm())
    with Catalog(tmp_path / "ws") as cat:
        clips = cat.query("SELECT * FROM markers_clips ORDER BY clip_id").to_pylist()
        assert len(clips) == 3 and all(c["n_frames"] > 0 and c["n_markers"] == len(c["labels"]) for c in clips)
        n = cat.query("SELECT count(*) AS n FROM markers").column("n")[0].as_py()
        assert n == sum(c["n_frames"] for c in clips)
        sizes = cat.query("SELECT DISTINCT clip_id, len(positions) AS k FROM markers ORDER BY clip_id").to_pylist()
        assert [s["k"] for s in sizes] == [3 * c["n_markers"] for c in clips]


def test_clip_ids_are_stable_when_a_file_starts_failing(tmp_path):
    """clip_id comes from the file's path, not its rank: breaking one file renumbers no
    other clip, and the broken file is recorded in ``rejects`` with the id it would have."""
    from mocapflow.framework.schema import clip_id_of

    data = tmp_path / "d"
    shutil.copytree(EXAMPLES_DATA / "cmu" / "02", data)
    p = pipeline(tmp_path, ["d/*.amc"])
    run_pipeline(p, pm=pm())
    before = {r["name"]: r["clip_id"] for r in pq.read_table(tmp_path / "ws" / "motions" / "clips.parquet").to_pylist()}
    assert before["02_02"] == clip_id_of("d/02_02.amc")  # its folder and file name
    assert [c["name"] for c in pq.read_table(tmp_path / "ws" / "motions" / "clips.parquet").to_pylist()] == sorted(
        before
    )
    (data / "02_01.amc").write_text("")  # the first file (rank 0) breaks
    run_pipeline(p, pm=pm())
    after = {r["name"]: r["clip_id"] for r in pq.read_table(tmp_path / "ws" / "motions" / "clips.parquet").to_pylist()}
    assert after == {k: v for k, v in before.items() if k != "02_01"}
    (reject,) = pq.read_table(tmp_path / "ws" / "motions" / "rejects.parquet").to_pylist()
    assert Path(reject["path"]).name == "02_01.amc" and reject["clip_id"] == before["02_01"]
    frames = pq.read_table(tmp_path / "ws" / "motions" / "data.parquet")
    assert set(frames["clip_id"].to_pylist()) == set(after.values()) and "positions" not in frames.column_names


def test_clip_id_collisions_are_resolved_deterministically():
    from mocapflow.framework.schema import clip_id_of, clip_ids_of

    # two keys whose 31-bit hashes collide, found by search once: key + "#1" rehash for the later one
    keys = [f"k{i}" for i in range(200_000)]
    seen: dict[int, str] = {}
    pair = None
    for k in keys:
        c = clip_id_of(k)
        if c in seen:
            pair = (seen[c], k)
            break
        seen[c] = k
    assert pair is not None
    a, b = sorted(pair)
    ids = clip_ids_of([b, "other", a])
    assert ids[2] == clip_id_of(a) and ids[0] == clip_id_of(f"{b}#1") and len(set(ids)) == 3
    assert clip_ids_of([a, b]) == [ids[2], ids[0]]  # order of the input does not matter
    assert all(0 <= c < 2**31 for c in ids)


def test_rows_built_in_the_workers_equal_motions_to_tables(tmp_path, monkeypatch):
    """formats.load builds each clip's rows where the file is read: the tables are
    exactly motions_to_tables of the motions read and checked one by one, and the inputs are
    listed once by the fingerprint, whose listing the run reuses."""
    from mocapflow.framework.motion_tables import motions_to_tables
    from mocapflow.plugins.formats import steps

    files = sorted((EXAMPLES_DATA / "cmu").glob("**/*.amc"))
    p = pipeline(tmp_path, [str(EXAMPLES_DATA / "cmu" / "**" / "*.amc"), str(EXAMPLES_DATA / "**" / "*.bvh")], fps=30)
    calls = []
    real = steps._expand
    monkeypatch.setattr(steps, "_expand", lambda *a: calls.append(a) or real(*a))
    run_pipeline(p, pm=pm(), jobs=1)
    assert len(calls) == 1  # check_plan globs pattern by pattern; the fingerprint lists, the run reuses it
    ws = tmp_path / "ws" / "motions"
    from mocapflow.framework.plugins import build_registries

    reg = build_registries(pm())
    step = steps.LoadMotions(
        {"paths": [str(EXAMPLES_DATA / "cmu" / "**" / "*.amc"), str(EXAMPLES_DATA / "**" / "*.bvh")], "fps": 30}
    )
    listed = step._files(p.parent)
    by_ext = {e: c for _, c in reg["formats"] if getattr(c, "produces", "") == "motion" for e in c.extensions}
    motions = [steps._read_file((by_ext[f.suffix.lower()], {}, str(f), 30.0)) for f in listed]
    assert files and all(not isinstance(m, tuple) for m in motions)
    want = motions_to_tables(motions, step.clip_ids(listed))
    for name in ("data", "rotations", "clips", "skeletons"):
        got = pq.read_table(ws / f"{name}.parquet").replace_schema_metadata(None)
        assert got.equals(want[name].replace_schema_metadata(None)), name
