"""``mocapflow index FOLDER -w WS``: a folder of takes as a searchable library, brought up to
date by reading only the files added or changed (``formats.library``), then searched and its
hits exported (docs/search-your-takes.md)."""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest

from mocapflow.framework.cli import main

ROOT = Path(__file__).resolve().parents[3]
BLENDER = ROOT / "tests" / "data" / "blender"


def _index(folder: Path, ws: Path, capsys) -> tuple[str, dict]:
    assert main(["--no-entry-points", "index", str(folder), "-w", str(ws)]) == 0
    out = capsys.readouterr().out
    summary = json.loads((ws / "motions" / "_manifest.json").read_text())["summary"]
    return out, summary


@pytest.fixture
def takes(tmp_path: Path) -> Path:
    folder = tmp_path / "takes"
    (folder / "sub").mkdir(parents=True)
    shutil.copy(BLENDER / "walk_120.fbx", folder / "walk_120.fbx")
    shutil.copy(BLENDER / "jump_60.glb", folder / "sub" / "jump_60.glb")
    (folder / "notes.txt").write_text("not a take\n")
    (folder / ".hidden.bvh").write_text("ignored\n")
    return folder


def _motions(ws: Path) -> dict[str, tuple]:
    """path -> (clip row without its id, frame rows without clip ids) of the library."""
    clips = pq.read_table(ws / "motions" / "clips.parquet").to_pylist()
    data = pq.read_table(ws / "motions" / "data.parquet")
    out = {}
    for c in clips:
        rows = data.filter(pc.equal(data["clip_id"], c["clip_id"])).drop_columns(["clip_id"]).to_pylist()
        out[c["path"]] = ({k: v for k, v in c.items() if k != "clip_id"}, rows)
    return out


def test_index_reads_only_what_moved_and_matches_a_fresh_index(takes: Path, tmp_path: Path, capsys) -> None:
    ws = tmp_path / "lib"
    out, s = _index(takes, ws, capsys)
    assert (s["added"], s["read"], s["clips"], s["rejects"]) == (2, 2, 2, 1)
    assert "2 added, 0 changed, 0 removed, 0 unchanged" in out
    assert "notes.txt: no motion reader for '.txt'" in out  # the reject and its reason
    assert ".hidden" not in out

    out, s = _index(takes, ws, capsys)  # nothing moved: every step up to date
    assert "0 added, 0 changed, 0 removed, 2 unchanged" in out

    shutil.copy(BLENDER / "run_30_zup_cm.fbx", takes / "sub" / "run.fbx")  # one new take
    os.utime(takes / "walk_120.fbx")  # touched, same bytes: not read again
    out, s = _index(takes, ws, capsys)
    assert (s["added"], s["changed"], s["unchanged"], s["read"], s["clips"]) == (1, 0, 2, 1, 3)
    assert "added: sub/run.fbx" in out

    shutil.copy(BLENDER / "walk_120.fbx", takes / "sub" / "jump_60.glb.bak")  # unsupported
    (takes / "sub" / "jump_60.glb").unlink()
    shutil.copy(BLENDER / "jump_60.glb", takes / "jump.glb")  # moved: removed + added
    out, s = _index(takes, ws, capsys)
    assert (s["added"], s["removed"], s["read"], s["clips"]) == (1, 1, 1, 3)
    assert "removed: sub/jump_60.glb" in out

    # kept rows equal a fresh index of the same folder (the incremental path's twin)
    fresh = tmp_path / "fresh"
    _index(takes, fresh, capsys)
    assert _motions(ws) == _motions(fresh)

    # a take whose new bytes do not parse: changed, rejected with its line, the rest kept
    (takes / "walk_120.fbx").write_bytes(b"not an fbx file at all")
    out, s = _index(takes, ws, capsys)
    assert (s["changed"], s["read"], s["clips"]) == (1, 1, 2)
    assert "walk_120.fbx" in out.split("rejected")[1]


def test_index_then_search_then_export(takes: Path, tmp_path: Path, capsys) -> None:
    ws = tmp_path / "lib"
    shutil.copy(BLENDER / "run_30_zup_cm.fbx", takes / "run.fbx")
    _index(takes, ws, capsys)
    hits = tmp_path / "hits.csv"
    query = f"{takes / 'walk_120.fbx'}:0s-0.4s"
    search = ["search", "--db", str(ws), "--query", query, "--out", str(hits), "--no-server", "--exclude-self", "clip"]
    assert main(["--no-entry-points", *search]) == 0
    rows = list(csv.DictReader(hits.open()))
    assert rows
    assert main(["--no-entry-points", "export", str(ws), "--hits", str(hits), "--top", "2", "--format", "bvh"]) == 0
    index = list(csv.DictReader((ws / "export" / "hits" / "index.csv").open()))
    assert [r["rank"] for r in index] == [r["rank"] for r in rows[:2]]
    for r, h in zip(index, rows, strict=False):
        assert (r["start_frame"], r["end_frame"]) == (h["start_frame"], h["end_frame"])
        assert (ws / "export" / "hits" / r["file"]).is_file()
    assert main(["--no-entry-points", "report", str(ws)]) == 0
    assert (ws / "report" / "index.html").is_file()


def test_index_refuses_a_workspace_inside_the_folder_and_a_missing_folder(takes: Path, tmp_path, capsys) -> None:
    assert main(["index", str(takes), "-w", str(takes / "lib")]) == 2
    assert "inside" in capsys.readouterr().err
    assert main(["index", str(tmp_path / "nope"), "-w", str(tmp_path / "lib")]) == 2
    assert "no such folder" in capsys.readouterr().err
    other = tmp_path / "other" / "motions"
    other.mkdir(parents=True)
    (other / "_manifest.json").write_text('{"component": "formats.load", "step": "motions"}')
    assert main(["index", str(takes), "-w", str(tmp_path / "other")]) == 2
    assert "another pipeline" in capsys.readouterr().err
