"""Workspaces the report tests read: the shipped quickstart, and a small fat-graph plus
reconstruction run. Each lives under pytest's base temp directory; a second test module
asking for it reruns the pipeline, which finds every step up to date."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
CMU = REPO / "examples" / "data" / "cmu"

EXTRAS = """
name: report-extras
workspace: {ws}
steps:
  motions:
    uses: formats.load
    with: {{paths: ["{cmu}/02/02_01.amc", "{cmu}/16/16_15.amc", "{cmu}/35/35_01.amc"], fps: 30}}
  test:
    uses: formats.load
    with: {{paths: ["{cmu}/02/02_01.amc", "{cmu}/16/16_15.amc"], fps: 30}}
  fe15:
    uses: features.end_effectors
    input: motions
    with: {{joints: 5}}
  fat_graph:
    uses: analyses.fat_graph
    inputs: {{features: fe15, motions: motions}}
    with: {{radius: 0.3, k: 64}}
  probe:
    uses: formats.load
    with: {{paths: ["{cmu}/35/35_01.amc"], fps: 30}}
  tree:
    uses: indexes.kdtree
    input: fe15
  probe_search:
    uses: matchers.search
    inputs: {{database: tree, query: probe}}
    with: {{queries: ["35_01:0-30"], count: 3, exclude_self: "off"}}
  reconstruction:
    uses: analyses.reconstruct
    inputs: {{prior: motions, test: test}}
    with: {{leave_out: clip, k: 16}}
"""


def _run(pipeline: Path, workspace: Path) -> Path:
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    run_pipeline(pipeline, workspace=workspace, pm=get_plugin_manager(entry_points=False))
    return workspace


@pytest.fixture(scope="module")
def quickstart_workspace(tmp_path_factory) -> Path:
    """``mocapflow run pipelines/quickstart.yaml`` into a temporary workspace."""
    return _run(REPO / "pipelines" / "quickstart.yaml", tmp_path_factory.getbasetemp() / "report-quickstart")


@pytest.fixture(scope="module")
def extras_workspace(tmp_path_factory) -> Path:
    """Fat-graph base poses, reconstructions, and a search whose queries come from another
    motions dataset than the database (clip ids that mean other clips there)."""
    root = tmp_path_factory.getbasetemp()
    ws = root / "report-extras"
    yaml = root / "report-extras.yaml"
    yaml.write_text(EXTRAS.format(ws=ws, cmu=CMU))
    return _run(yaml, ws)
