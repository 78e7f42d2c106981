"""Every pipeline shipped in pipelines/ is planned; the quickstart runs end to end."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocapflow.framework import get_plugin_manager
from mocapflow.framework.catalog import Catalog
from mocapflow.framework.plugins import build_registries
from mocapflow.framework.runner import plan_pipeline, run_pipeline

PIPELINES = sorted((Path(__file__).resolve().parents[2] / "pipelines").glob("*.yaml"))


@pytest.mark.parametrize("path", PIPELINES, ids=[p.stem for p in PIPELINES])
def test_shipped_pipeline_plans(path):
    plan = plan_pipeline(path, registries=build_registries(get_plugin_manager(entry_points=False)))
    assert plan.steps and len(plan.fingerprints()) == len(plan.steps)


def test_quickstart_end_to_end(tmp_path):
    path = next(p for p in PIPELINES if p.stem == "quickstart")
    pm = get_plugin_manager(entry_points=False)
    first = run_pipeline(path, workspace=tmp_path, pm=pm)
    assert all(r.status == "computed" for r in first)
    assert all(r.status == "up to date" for r in run_pipeline(path, workspace=tmp_path, pm=pm))
    with Catalog(tmp_path) as cat:
        assert cat.query("SELECT count(*) AS n FROM clips").column("n")[0].as_py() == 8
        assert cat.query("SELECT count(*) AS n FROM rejects").column("n")[0].as_py() == 0
        hits = cat.query(
            "SELECT c.name, s.start_frame, s.end_frame, s.cost, s.fps, s.start_frame_analysis, "
            "s.end_frame_analysis, s.start_s FROM search s JOIN clips c USING (clip_id)"
        ).to_pylist()
        # the query (16_15, seconds 1-2 at 30 Hz) does not find itself (exclude_self: span, zone 15 frames)
        assert len(hits) == 5 and all(h["cost"] > 0 for h in hits)
        assert all(
            h["name"] != "16_15" or h["end_frame_analysis"] <= 15 or h["start_frame_analysis"] >= 75 for h in hits
        )
        # frames of the take's own file (120 Hz AMC) and seconds; the 30-Hz rows in *_analysis
        assert all(h["fps"] == 120 and h["start_frame"] == 4 * h["start_frame_analysis"] for h in hits)
        assert all(h["start_s"] == h["start_frame"] / 120 for h in hits)
        nearest = cat.query("SELECT count(*) AS n FROM nearest").column("n")[0].as_py()
        assert nearest == 3 * 16
        assert cat.query("SELECT min(rank) AS r FROM hits").column("r")[0].as_py() == 1
        mdm = cat.query("SELECT min(value) AS lo, max(value) AS hi FROM clean").to_pylist()[0]
        assert 0.0 <= mdm["lo"] <= mdm["hi"] <= 1.0
    assert len(list((tmp_path / "clean").glob("*.mdm.png"))) == 8
    assert len(list((tmp_path / "search").rglob("*.png"))) >= 1
