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


MARKERS = """
name: report-markers
workspace: {ws}
steps:
  markers:
    uses: formats.load_markers
    with: {{paths: ["{take}"]}}
  prior:
    uses: formats.load
    with: {{paths: ["{cmu}/16/16_15.amc", "{cmu}/16/16_01.amc"], fps: 30}}
  recon:
    uses: analyses.reconstruct_markers
    inputs: {{prior: prior, markers: markers}}
    with: {{skeleton: "{cmu}/16/16.asf", k: 16}}
"""


@pytest.fixture(scope="module")
def markers_workspace(tmp_path_factory) -> Path:
    """A marker take (Plug-in-Gait-style markers around the joints of a CMU walk, z up as
    many C3D files are, written as TRC), and its reconstruction from a prior of CMU takes."""
    import numpy as np
    from test_reconstruct import vicon_markers

    import mocapflow
    from mocapflow.framework.markers import Markers
    from mocapflow.plugins.formats.trc import write_trc

    root = tmp_path_factory.getbasetemp()
    ws, take = root / "report-markers", root / "report-markers-take.trc"
    if not take.is_file():
        walk = mocapflow.read(CMU / "16" / "16_35.amc").slice(0, 120)
        mk = vicon_markers(walk)
        p = mk.positions  # y up -> z up (x, -z, y): the reader's up-axis guess turns it back
        zup = np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)
        write_trc(Markers(mk.labels, zup, mk.fps, name="walk_markers", metadata={"up_axis": "+z"}), take)
    yaml = root / "report-markers.yaml"
    yaml.write_text(MARKERS.format(ws=ws, take=take, cmu=CMU))
    return _run(yaml, ws)
