"""The daily loop's paper cuts: one clip id per take whichever ingest reads it, every
command on a workspace of motions and markers without an internal error, component
parameter errors by name, a folder given to the Python API, clip labels."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from mocapflow.framework.cli import main
from mocapflow.framework.errors import ConfigError

REPO = Path(__file__).resolve().parents[2]
CMU = REPO / "examples" / "data" / "cmu"

PIPELINE = """
name: loop
workspace: ws
steps:
  motions:
    uses: formats.load
    with: {{paths: ["data/**/*.amc"], fps: 30, labels: labels.csv, label_pattern: "^(?P<label>\\\\d+)_"}}
  one:
    uses: formats.load
    with: {{paths: ["data/02/*.amc"], fps: 30}}
  markers:
    uses: formats.load_markers
    with: {{paths: ["markers/*.trc"]}}
  summary: {{uses: analyses.clip_summary, input: one}}
  fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
  tree: {{uses: indexes.kdtree, input: fe15}}
  poses:
    uses: analyses.nearest_poses
    inputs: {{index: tree, motions: motions}}
    with: {{queries: ["02_01:30"], k: 4, exclude_frames: 0}}
"""


@pytest.fixture(scope="module")
def loop_workspace(tmp_path_factory) -> Path:
    """Motions from two ingests (one file in both), markers (TRC), labels from a CSV and a
    name pattern; the pipeline run once."""
    from mocapflow.framework.markers import Markers
    from mocapflow.plugins.formats.trc import write_trc

    root = tmp_path_factory.mktemp("loop")
    for sub in ("02", "16"):
        (root / "data" / sub).mkdir(parents=True)
        shutil.copy(CMU / sub / f"{sub}.asf", root / "data" / sub)
    shutil.copy(CMU / "02" / "02_01.amc", root / "data" / "02")
    shutil.copy(CMU / "16" / "16_15.amc", root / "data" / "16")
    (root / "markers").mkdir()
    rng = np.random.default_rng(0)
    mk = Markers(labels=("A", "B", "C"), positions=rng.normal(size=(40, 3, 3)), fps=60.0, name="walk")
    write_trc(mk, root / "markers" / "walk.trc")
    (root / "labels.csv").write_text("clip,label,start,end\n02_01,walk,,\n16/16_15.amc,run,0.5,1.5\nnot_here,x,,\n")
    (root / "p.yaml").write_text(PIPELINE.format())
    assert main(["--no-entry-points", "run", str(root / "p.yaml")]) == 0
    return root


def test_one_take_read_by_two_ingests_has_one_clip_id(loop_workspace):
    ws = loop_workspace / "ws"
    ids = {}
    for step in ("motions", "one"):
        for r in pq.read_table(ws / step / "clips.parquet").to_pylist():
            ids.setdefault(r["name"], set()).add(r["clip_id"])
    assert len(ids["02_01"]) == 1  # read by both ingests, under two different pattern roots


def test_steps_join_clips_whichever_ingest_comes_first(loop_workspace, capsys):
    out = loop_workspace / "poses.csv"
    sql = "SELECT count(*) AS n, count(c.name) AS named FROM poses p JOIN clips c USING (clip_id)"
    assert main(["sql", str(loop_workspace / "ws"), sql, "--output", str(out)]) == 0
    n, named = out.read_text().splitlines()[1].split(",")
    assert int(n) == int(named) == 4


def test_every_command_on_a_workspace_with_markers_ends_without_an_internal_error(loop_workspace, capsys, tmp_path):
    """Every command a user runs on the workspace: exit 0 (or 2 for a user error), never the
    internal-error exit (3)."""
    ws, p = str(loop_workspace / "ws"), str(loop_workspace / "p.yaml")
    from mocapflow.framework.catalog import Catalog

    with Catalog(ws) as cat:
        views = sorted(cat.views)
    runs = [
        ["--no-entry-points", "plan", p],
        ["--no-entry-points", "run", p],
        ["--no-entry-points", "plugins"],
        ["report", ws, "--output", str(tmp_path / "site")],
        ["search", "--db", ws, "--query", str(loop_workspace / "data" / "16" / "16_15.amc") + ":0-30", "--no-server"],
        *(["sql", ws, f'SELECT * FROM "{v}" LIMIT 1'] for v in views),
    ]
    for args in runs:
        code = main(args)
        err = capsys.readouterr().err
        assert code == 0, (args, err)
    assert (tmp_path / "site" / "index.html").is_file()
    assert main(["search", "--db", ws, "--query", str(loop_workspace / "markers" / "walk.trc"), "--no-server"]) in (
        0,
        2,
    )
    assert "internal error" not in capsys.readouterr().err


def test_labels_table_from_a_csv_and_a_pattern(loop_workspace):
    ws = loop_workspace / "ws"
    rows = pq.read_table(ws / "motions" / "labels.parquet").to_pylist()
    by_name = {(r["name"], r["label"]): r for r in rows}
    assert by_name["02_01", "walk"]["start_frame"] is None  # a whole-clip label from the CSV
    run = by_name["16_15", "run"]
    assert (run["start_frame"], run["end_frame"]) == (15, 45)  # seconds 0.5-1.5 at 30 Hz
    assert ("16_15", "16") not in by_name  # the CSV labelled it: the pattern is not used for it
    assert not (ws / "one" / "labels.parquet").exists()
    from mocapflow.framework.labels import clip_labels_from_table

    table = pq.read_table(ws / "motions" / "labels.parquet")
    ids = {r["name"]: r["clip_id"] for r in rows}
    assert clip_labels_from_table(table, [ids["02_01"], ids["16_15"], 7]) == ["walk", "run", None]


def test_pattern_labels_and_csv_errors(tmp_path):
    from mocapflow.framework.errors import ParseError
    from mocapflow.framework.labels import csv_labels, labels_table, pattern_labels

    clips = [{"clip_id": 1, "name": "HDM_bd_kick_001_120", "path": "/d/bd/HDM_bd_kick_001_120.amc", "fps": 30.0}]
    assert pattern_labels(r"^HDM_[a-z]+_(?P<label>[a-z]+)_", clips)["label"].to_pylist() == ["kick"]
    assert pattern_labels(r"^HDM_[a-z]+_([a-z]+)_", clips)["label"].to_pylist() == ["kick"]  # first group
    assert labels_table(clips) is None
    bad = tmp_path / "bad.csv"
    bad.write_text("clip,label,start\nHDM_bd_kick_001_120,kick,soon\n")
    with pytest.raises(ParseError, match=r"bad.csv:2: column 'start': expected seconds"):
        csv_labels(bad, clips)
    bad.write_text("name,class\n")
    with pytest.raises(ParseError, match=r"bad.csv:1: expected a header with columns clip,label"):
        csv_labels(bad, clips)
    bad.write_text("clip,label\nother,kick\n")
    with pytest.raises(Exception, match="no row names a clip of this ingest"):
        csv_labels(bad, clips)


def test_templates_take_labels_from_the_labels_table(tmp_path):
    """matchers.template learns the classes the labels table gives (a CSV here), not the
    ones its label_pattern would parse from the names."""
    from mocapflow.framework.datasets import Dataset
    from mocapflow.framework.runner import run_pipeline

    data = tmp_path / "data"
    for sub, take in (("02", "02_01"), ("02", "02_02"), ("16", "16_15"), ("16", "16_16")):
        (data / sub).mkdir(parents=True, exist_ok=True)
        if (CMU / sub / f"{take}.amc").is_file():
            shutil.copy(CMU / sub / f"{take}.amc", data / sub)
        shutil.copy(CMU / sub / f"{sub}.asf", data / sub)
    takes = sorted(p.stem for p in data.rglob("*.amc"))
    (tmp_path / "labels.csv").write_text("clip,label\n" + "".join(f"{t},c{t[:2]}\n" for t in takes))
    (tmp_path / "t.yaml").write_text(
        "name: t\nworkspace: ws\nsteps:\n"
        '  motions: {uses: formats.load, with: {paths: ["data/**/*.amc"], fps: 30, labels: labels.csv}}\n'
        "  rel: {uses: features.relational, input: motions}\n"
        "  templates:\n    uses: matchers.template\n    inputs: {database: rel, motions: motions}\n"
        "    with: {group_pattern: null, plots: false}\n"
    )
    run_pipeline(tmp_path / "t.yaml")
    labels = set(Dataset(tmp_path / "ws" / "templates").table("templates")["label"].to_pylist())
    assert labels == {f"c{t[:2]}" for t in takes}


def test_block_of_an_unknown_plugin_is_an_error_naming_the_plugins(capsys):
    assert main(["--block", "nosuch", "--no-entry-points", "plugins"]) == 2
    err = capsys.readouterr().err
    assert "--block nosuch: no plugin of that name" in err and "mocapflow.plugins.similarity.plugin" in err
    assert main(["--block", "mocapflow.plugins.similarity.plugin", "--no-entry-points", "plugins"]) == 0
    assert "indexes.kdtree" not in capsys.readouterr().out


def test_component_parameter_errors_name_the_component_and_parameter():
    from mocapflow.framework.plugins import default_registries

    cls = default_registries()["features"].get("end_effectors")
    with pytest.raises(ConfigError, match=r"parameter 'joints' of features.end_effectors: .*got 'many'"):
        cls({"joints": "many"})
    with pytest.raises(
        ConfigError, match=r"unknown parameter 'jionts' for features.end_effectors \(did you mean 'joints'\?\)"
    ):
        cls(jionts=5)


def test_a_long_list_of_known_names_is_cut_short():
    from mocapflow.framework.registry import known_names

    names = [f"parameter_{i}" for i in range(80)]
    text = known_names(names)
    assert "80 in all" in text and len(text) < 300
    assert known_names(["a", "b"]) == "a, b"


def test_the_python_api_reads_a_folder_and_names_what_it_cannot_read(tmp_path):
    import mocapflow.api as api

    db = api.Database(CMU / "35", index="kdtree")
    assert sorted(db.clip_names.values()) == sorted(p.stem for p in (CMU / "35").glob("*.amc"))
    (tmp_path / "take").write_text("")
    with pytest.raises(ConfigError, match="without a file extension; motion files: .*\\.bvh"):
        api.read(tmp_path / "take")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="no motion file in this folder"):
        api.Database(tmp_path / "empty")


def test_heartbeat_moves_for_a_step_without_a_bar_and_yields_to_bars(capsys):
    import time

    from mocapflow.framework.progress import heartbeat, progress

    with heartbeat("  step", expected=10.0, after=0.1, enabled=True):
        time.sleep(0.8)
    err = capsys.readouterr().err
    assert "  step: [" in err and "left (last run 10 s)" in err and err.endswith("\r\x1b[K")
    with heartbeat("  quiet", after=0.1, enabled=True):
        for _ in progress(range(3), desc="own", enabled=True, weights=[1, 1, 1]):  # a bar of its own
            time.sleep(0.3)
    assert "quiet" not in capsys.readouterr().err
    with heartbeat("  off", after=0.0, enabled=False):
        time.sleep(0.6)
    assert capsys.readouterr().err == ""
