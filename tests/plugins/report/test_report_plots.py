"""Every PNG the pipelines write explains itself: titles, axis labels with units, colour bar
labels, legends for every mark, clip names instead of ids.

Each plot is drawn for real; the figure is captured when it is saved and its texts read.
"""

from __future__ import annotations

import numpy as np
import pytest
from report_workspaces import extras_workspace, quickstart_workspace  # noqa: F401 (fixtures)

pytest.importorskip("matplotlib")


@pytest.fixture
def saved(monkeypatch):
    """Figures passed to savefig, with their texts (titles, labels, legends, colour bars)."""
    from matplotlib.figure import Figure

    figs = []
    real = Figure.savefig

    def spy(self, *a, **kw):
        figs.append(self)
        return real(self, *a, **kw)

    monkeypatch.setattr(Figure, "savefig", spy)
    return figs


def texts(fig) -> dict[str, list[str]]:
    out = {"title": [], "xlabel": [], "ylabel": [], "legend": [], "suptitle": []}
    for ax in fig.axes:
        out["title"].append(ax.get_title())
        out["xlabel"].append(ax.get_xlabel())
        out["ylabel"].append(ax.get_ylabel())
        leg = ax.get_legend()
        if leg is not None:
            out["legend"] += [t.get_text() for t in leg.get_texts()]
    for leg in fig.legends:
        out["legend"] += [t.get_text() for t in leg.get_texts()]
    for name in ("_suptitle", "_supxlabel", "_supylabel"):
        t = getattr(fig, name, None)
        if t is not None:
            out["suptitle"].append(t.get_text())
    return out


def test_lng_plot_names_the_clip_and_explains_every_mark(quickstart_workspace, tmp_path, saved):
    from mocapflow.framework.cli import main

    assert (
        main(
            [
                "search",
                "--db",
                str(quickstart_workspace),
                "--query",
                "16_15:30-60",
                "--count",
                "5",
                "--exclude-self",
                "off",  # the query's own clip is the match this plot explains
                "--plot",
                str(tmp_path / "lng.png"),
            ]
        )
        == 0
    )
    t = texts(saved[-1])
    assert (tmp_path / "lng.png").read_bytes()[:4] == b"\x89PNG"
    assert t["ylabel"][0] == "frame of database clip 16_15" and "query frame" in t["xlabel"][0]
    assert any("not among the k = " in s and "nearest neighbours" in s for s in t["legend"])
    assert any(s.startswith("this match: rank 1") for s in t["legend"])
    colorbar = [y for y in t["ylabel"][1:] if y]
    assert colorbar and "distance" in colorbar[0] and "metres" in colorbar[0]


def test_mdm_heatmap_labels_its_colour_bar_and_white_squares(tmp_path, saved):
    from mocapflow.plugins.selfsim.plots import mdm_heatmap

    mdm = np.zeros((60, 3))
    mdm[10:14, 1] = 0.9
    mdm_heatmap(mdm, ["lknee", "lelbow", "head"], tmp_path / "m.png", fps=30.0, threshold=0.5, title="02_01: map")
    t = texts(saved[-1])
    assert t["title"][0] == "02_01: map" and t["xlabel"][0] == "time (s)" and t["ylabel"][0] == "joint"
    assert any("MDM value" in y and "dimensionless" in y for y in t["ylabel"][1:])
    assert t["legend"] == [
        "white square: MDM > 0.5, cell flagged as erroneous (4 cells at 30 fps; the repair changes these)"
    ]


def test_base_poses_are_labelled_with_clip_frame_and_members(extras_workspace, tmp_path, saved):
    from mocapflow.framework.datasets import Dataset
    from mocapflow.plugins.similarity.applications.fat_graph import FatGraph

    bp = Dataset(extras_workspace / "fat_graph").table("base_poses")
    clip_id, frame = bp["clip_id"].to_numpy(), bp["frame"].to_numpy()
    members = bp["n_members"].to_numpy()
    names = dict(
        zip(
            *(Dataset(extras_workspace / "motions").table("clips")[c].to_pylist() for c in ("clip_id", "name")),
            strict=True,
        )
    )
    FatGraph._plot(
        Dataset(extras_workspace / "motions"), clip_id, frame, np.arange(len(bp)), tmp_path / "b.png", members
    )
    t = texts(saved[-1])
    titles = [s for s in t["title"] if s]
    assert len(titles) == len(bp)
    m0 = int(members[0])
    assert titles[0] == f"#0 {names[int(clip_id[0])]} frame {int(frame[0])}\n{m0} member{'s' if m0 != 1 else ''}"
    assert any("(m)" in s and "lateral" in s for s in t["suptitle"]) and any("height" in s for s in t["suptitle"])
