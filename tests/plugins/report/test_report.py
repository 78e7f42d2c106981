"""``mocapflow report``: data encoding, the cleaned takes, the page model, the site on disk.

The browser half (the page in headless Chromium) is tests/plugins/report/test_report_browser.py.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from naive.cleaning import synthetic_walk
from report_workspaces import extras_workspace, quickstart_workspace  # noqa: F401 (fixtures)

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import ConfigError
from mocapflow.plugins.report.blobs import decode_positions, encode_positions, pack, read_blob, unpack, write_blob
from mocapflow.plugins.report.cleaned import DEFAULT_CUE, apply_edits, mdm_grid
from mocapflow.plugins.report.model import _relative_path


def page_model(site: Path) -> dict:
    html = (site / "index.html").read_text()
    m = re.search(r'<script type="application/json" id="model">(.*?)</script>', html, re.S)
    return json.loads(m.group(1))


# --- data files ----------------------------------------------------------------------------
def test_positions_round_trip_within_half_a_quantisation_step_and_keep_nan():
    rng = np.random.default_rng(0)
    pos = rng.normal(0, 0.5, (40, 25, 3)) + np.array([3.0, 1.0, -20.0])
    pos[:, 7] = np.nan  # a joint the skeleton lacks
    parts, scale = encode_positions(pos)
    assert parts["root"].dtype == np.float32 and parts["rel"].dtype == np.int16
    back = decode_positions(parts["root"], parts["rel"], scale)
    assert np.isnan(back[:, 7]).all() and not np.isnan(np.delete(back, 7, axis=1)).any()
    ok = np.isfinite(pos)
    # float32 root (metres near 20: ~1e-6) plus half an int16 step
    assert np.abs(back[ok] - pos[ok]).max() <= scale / 2 + 4e-6
    assert scale < 1e-4  # a body ~3 m across: better than 0.1 mm


def test_blob_parts_are_aligned_and_read_back(tmp_path):
    parts = {
        "a": np.arange(5, dtype=np.uint8),
        "b": np.array([[1.5, -2.0]], np.float32),
        "c": np.arange(3, dtype=np.int16),
    }
    blob, table = pack(parts)
    assert all(p["offset"] % 4 == 0 for p in table)
    assert all(np.array_equal(unpack(blob, table)[k], v) for k, v in parts.items())
    n = write_blob(tmp_path / "x.js", "k/1", {"kind": "test"}, parts)
    assert n == (tmp_path / "x.js").stat().st_size
    key, meta, back = read_blob(tmp_path / "x.js")
    assert key == "k/1" and meta["kind"] == "test" and np.array_equal(back["b"], parts["b"])


# --- cleaned takes and MDM grids -----------------------------------------------------------
def test_edits_applied_to_the_original_give_the_cleaners_take():
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner
    from mocapflow.plugins.selfsim.outputs import clean_and_write_clip

    walk = synthetic_walk(240, seed=5)
    rot = walk.rotations.copy()
    j = walk.skeleton.canonical["lelbow"]
    rot[120:126, j] = quat.mul(rot[120:126, j], quat.from_axis_angle(np.array([0, 0, 1.0]), np.array(1.2)))
    bad = walk.with_arrays(rotations=rot)
    out = clean_and_write_clip(MDMCleaner(), bad, None, 3, None)
    assert out["edits"].num_rows > 0
    mine = apply_edits(bad, out["edits"], 3)
    np.testing.assert_allclose(mine.rotations, out["cleaned"].rotations, atol=1e-12)
    assert apply_edits(bad, out["edits"], 4) is bad  # another clip's edits change nothing


def _mdm_table(cue=None):
    cols = {
        "clip_id": pa.array([1] * 4 + [2], pa.int32()),
        "frame": pa.array([0, 0, 1, 1, 0], pa.int32()),
        "joint_name": ["lknee", "head", "lknee", "head", "lknee"],
        "value": pa.array([0.25, 0.75, 0.625, 0.0, 1.0], pa.float32()),
        "flagged": [False, True, True, False, True],
    }
    if cue is not None:
        cols["cue"] = cue
    return pa.table(cols)


def test_mdm_grid_without_a_cue_column_falls_back_to_the_threshold():
    g = mdm_grid(_mdm_table(), 1, n_frames=3, threshold=0.5)
    assert g["joints"] == ["lknee", "head"] and g["values"].shape == (3, 2)
    np.testing.assert_allclose(g["values"] * g["scale"], [[0.25, 0.75], [0.625, 0.0], [0.0, 0.0]], atol=1e-5)
    assert g["cues"] == [DEFAULT_CUE] and g["cue"][:2].tolist() == [[0, 1], [1, 0]]
    assert g["canonical"][1] == 13 and g["n_flagged"] == 2  # CANONICAL_JOINTS.index("head")
    assert mdm_grid(_mdm_table(), 9, 3, 0.5) is None


def test_mdm_grid_names_the_cue_that_flagged_each_cell():
    g = mdm_grid(_mdm_table(cue=[None, "mdm", "velocity spike", None, "mdm"]), 1, 2, 0.5)
    assert g["cues"] == ["mdm", "velocity spike"]
    assert g["cue"].tolist() == [[0, 1], [2, 0]]
    # a flagged cell whose cue is null still shows as flagged, by the threshold
    g = mdm_grid(_mdm_table(cue=[None, None, "range", None, None]), 1, 2, 0.5)
    assert g["cues"] == [DEFAULT_CUE, "range"] and g["cue"].tolist() == [[0, 1], [2, 0]]


def test_mdm_grid_keeps_values_above_one():
    t = _mdm_table().set_column(3, "value", pa.array([0.25, 3.5, 0.625, 0.0, 1.0], pa.float32()))
    g = mdm_grid(t, 1, 2, 0.5)
    assert abs(g["values"][0, 1] * g["scale"] - 3.5) < 1e-4


def test_warping_paths_become_relative_to_the_query():
    q = {"start": 30, "end": 60}
    assert _relative_path([[0, 5], [29, 40]], q) == [[0, 5], [29, 40]]  # LNG: already relative
    assert _relative_path([[30, 5], [59, 40]], q) == [[0, 5], [29, 40]]  # relational refinement: within the clip
    assert _relative_path(None, q) is None


# --- the report of real workspaces ---------------------------------------------------------
@pytest.fixture(scope="module")
def quickstart_site(quickstart_workspace, tmp_path_factory):
    from mocapflow.framework.cli import main

    out = tmp_path_factory.mktemp("site") / "report"
    assert main(["report", str(quickstart_workspace), "--output", str(out)]) == 0
    return out


def test_quickstart_report_lists_clips_steps_and_provenance(quickstart_site, quickstart_workspace):
    from mocapflow.framework.catalog import Catalog
    from mocapflow.framework.datasets import Dataset

    m = page_model(quickstart_site)
    with Catalog(quickstart_workspace) as cat:
        names = sorted(cat.query("SELECT name FROM clips").column("name").to_pylist())
    cols = m["clips"]["columns"]
    assert sorted(r[cols.index("name")] for r in m["clips"]["rows"]) == names
    assert {"fps", "n_frames", "duration_s", "path"} <= set(cols) and m["rejects"]["n_rows"] == 0
    steps = {s["id"]: s for s in m["steps"]}
    assert set(steps) == {
        "motions",
        "summary",
        "fe15",
        "tree",
        "nearest",
        "search",
        "relational",
        "inverted",
        "hits",
        "clean",
    }
    s = steps["search"]
    assert (
        s["component"] == "matchers.search"
        and s["params"]["count"] == 5
        and s["inputs"] == {"database": "tree", "query": "motions"}
    )
    assert s["input_fingerprints"]["query"] == Dataset(quickstart_workspace / "motions").fingerprint
    assert s["images"] == ["plots/q0_m1.png"] and (quickstart_site / "img" / "search" / "plots" / "q0_m1.png").is_file()


def test_search_hits_carry_their_warping_path_and_play_real_motion(quickstart_site, quickstart_workspace):
    from mocapflow.framework.datasets import Dataset

    m = page_model(quickstart_site)
    view = next(s for s in m["steps"] if s["id"] == "search")["views"][0]
    assert view["type"] == "retrieval" and len(view["hits"]) == 5
    (q,) = view["queries"]
    assert (q["clip"], q["start"], q["end"]) == ("16_15", 30, 60)
    best = view["hits"][0]
    # the query does not find itself: no hit within half its length (15 frames) of its span
    assert all(x["clip"] != "16_15" or x["end"] <= 15 or x["start"] >= 75 for x in view["hits"])
    assert best["cost"] > 0 and best["path"][0] == [0, best["start"]] and best["path"][-1][0] == 29
    assert best["start_s"] == round(best["start"] / 30, 3) and view["export"].startswith("mocapflow export ")
    # the data file of the query's take decodes to the canonical positions of its stored motion
    from mocapflow.framework.joints import CANONICAL_JOINTS

    key, meta, parts = read_blob(quickstart_site / m["data_files"][q["motion"]]["file"])
    db = Dataset(quickstart_workspace / "motions").motions()
    want = db.motions[db.clip_ids.tolist().index(q["clip_id"])].canonical_positions(CANONICAL_JOINTS)
    got = decode_positions(parts["root"], parts["rel"], meta["scale"])
    ok = np.isfinite(want)
    assert key == q["motion"] and got.shape == want.shape and np.abs(got[ok] - want[ok]).max() < 1e-4
    rel = next(s for s in m["steps"] if s["id"] == "hits")["views"][0]
    assert rel["queries"][0]["clip"] == "02_01" and rel["hits"][0]["clip"] == "02_01"
    near = next(s for s in m["steps"] if s["id"] == "nearest")["views"][0]
    assert len(near["queries"]) == 3 and len(near["hits"]) == 48 and near["cost_label"] == "distance"


def test_cleaning_view_has_every_take_with_its_map_and_cleaned_motion(quickstart_site):
    m = page_model(quickstart_site)
    view = next(s for s in m["steps"] if s["id"] == "clean")["views"][0]
    assert view["type"] == "cleaning" and len(view["clips"]) == 8 and view["threshold"] == 0.5
    # the takes are clean: the take the cleaner flags most (35_01 with the defaults)
    c = max(view["clips"], key=lambda c: c["n_flagged"])
    key, meta, parts = read_blob(quickstart_site / m["data_files"][c["data"]]["file"])
    assert parts["mdm"].shape == (c["n_frames"], len(meta["joints"])) and meta["cues"]
    assert (parts["cue"] > 0).sum() == c["n_flagged"] > 0 and c["n_edits"] > 0
    assert parts["rel"].shape == (c["n_frames"], 25, 3)


def test_site_uses_no_network_and_is_replaced_atomically(quickstart_site, quickstart_workspace, tmp_path):
    from mocapflow.plugins.report.plugin import build_report

    for name in ("index.html", "report.js", "player.js", "report.css"):
        text = (quickstart_site / name).read_text()
        assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", text), name
        assert "fetch(" not in text and "XMLHttpRequest" not in text
    assert "Copyright" in (quickstart_site / "player.js").read_text()[:400]
    # a second report replaces the first; a directory that is not a report is refused
    first = build_report(quickstart_workspace, tmp_path / "r")
    again = build_report(quickstart_workspace, tmp_path / "r")
    assert again["files"] == first["files"] and not list(tmp_path.glob(".r.*"))
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    with pytest.raises(ConfigError, match="not a mocapflow report"):
        build_report(quickstart_workspace, other)
    assert (other / "notes.txt").read_text() == "keep me"
    with pytest.raises(ConfigError, match="dataset"):
        build_report(quickstart_workspace, quickstart_workspace / "clean")


def test_base_poses_and_reconstructions_are_shown(extras_workspace, tmp_path):
    from mocapflow.framework.datasets import Dataset
    from mocapflow.plugins.report.plugin import build_report

    build_report(extras_workspace, tmp_path / "r")
    m = page_model(tmp_path / "r")
    steps = {s["id"]: s for s in m["steps"]}
    bp = steps["fat_graph"]["views"][0]
    table = Dataset(extras_workspace / "fat_graph").table("base_poses").to_pylist()
    assert bp["type"] == "base_poses" and bp["n_base_poses"] == len(table) > 0
    p0 = bp["poses"][0]
    assert (p0["clip_id"], p0["frame"], p0["n_members"]) == (
        table[0]["clip_id"],
        table[0]["frame"],
        table[0]["n_members"],
    )
    assert p0["clip"] in {"02_01", "16_15", "35_01"} and len(p0["positions"]) == 75 and abs(p0["positions"][0]) < 1e-6
    rec = next(v for v in steps["reconstruction"]["views"] if v["type"] == "derived")
    assert sorted(p["source_clip"] for p in rec["pairs"]) == ["02_01", "16_15"]
    assert all(p["source_step"] == "test" for p in rec["pairs"])
    assert "clip_errors" in steps["reconstruction"]["small_tables"]


def test_hits_and_queries_are_named_from_their_own_motions(extras_workspace, tmp_path):
    from mocapflow.plugins.report.plugin import build_report

    build_report(extras_workspace, tmp_path / "r")
    view = next(s for s in page_model(tmp_path / "r")["steps"] if s["id"] == "probe_search")["views"][0]
    (q,) = view["queries"]
    from mocapflow.framework.schema import clip_id_of

    # the query is named from 'probe', the hit from 'motions': two ingests of one take, one id
    assert (q["clip"], view["query_motions"], view["motions"]) == ("35_01", "probe", "motions")
    best = view["hits"][0]
    assert (best["clip"], best["start"], best["cost"]) == ("35_01", 0, 0.0)
    assert q["clip_id"] == best["clip_id"] == clip_id_of("35/35_01.amc")
    assert best["motion"] == f"m/motions/{best['clip_id']}" and q["motion"] == f"m/probe/{q['clip_id']}"


def test_cli_errors_name_the_workspace(tmp_path, capsys):
    from mocapflow.framework.cli import main

    assert main(["report", str(tmp_path / "nowhere")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["report", str(tmp_path)]) == 2
    assert "no finished dataset" in capsys.readouterr().err


def test_export_of_a_cleaning_and_a_search_step(quickstart_workspace, tmp_path):
    """`mocapflow export` of the cleaner's flagged runs and of the search hits: clips of the
    source takes at 120 Hz that re-read as those source frames."""
    import csv

    import mocapflow
    from mocapflow.framework.cli import main

    for step in ("clean", "search"):
        out = tmp_path / step
        assert (
            main(
                ["--no-entry-points", "export", str(quickstart_workspace), "--step", step, "--top", "2", "-o", str(out)]
            )
            == 0
        )
        with open(out / "index.csv") as f:
            rows = list(csv.DictReader(f))
        assert rows and all(int(r["rank"]) <= 2 for r in rows)
        r = rows[0]
        src, back = mocapflow.read(r["source"]), mocapflow.read(out / r["file"])
        a, b = int(r["clip_start"]), int(r["clip_end"])
        assert back.fps == src.fps == 120 and back.skeleton.names == src.skeleton.names
        np.testing.assert_allclose(back.positions, src.positions[a:b], atol=1e-4, rtol=0)
    assert {r["query"] for r in rows} == {"16_15.amc:1s-2s"}
