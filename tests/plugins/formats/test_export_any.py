"""AMC export from any source (FBX, glTF, BVH) writes the ASF made from its skeleton and
re-reads with the source's joint positions; a refused export creates nothing."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import mocapflow
from mocapflow.framework.errors import DataError
from mocapflow.framework.export import Segment, export_segments
from mocapflow.framework.plugins import default_registries as registries
from mocapflow.plugins.formats.asf_amc import read_amc

ROOT = Path(__file__).resolve().parents[3]
BLENDER = ROOT / "tests" / "data" / "blender"
CMU = ROOT / "examples" / "data" / "cmu"


def _by_name(back, src) -> float:
    idx = [back.skeleton.names.index(n) for n in src.skeleton.names[1:]]
    err = np.abs(back.positions[:, idx] - src.positions[:, 1:]).max()
    return max(err, float(np.abs(back.positions[:, 0] - src.positions[:, 0]).max()))


@pytest.mark.parametrize("source", ["walk_120.fbx", "jump_60.glb", "walk_120.gltf"])
def test_amc_export_from_scene_formats(tmp_path, source):
    path = BLENDER / source
    src = mocapflow.read(path)
    segs = [Segment("q", 1, path.stem, str(path), 5, src.n_frames - 5)]
    index = export_segments(segs, tmp_path, registries(), handle=2, format="amc").to_pylist()
    out = tmp_path / index[0]["file"]
    assert out.suffix == ".amc" and out.with_suffix(".asf").is_file()
    back = read_amc(out, fps=src.fps)
    assert back.n_frames == src.n_frames - 6
    assert _by_name(back, src.slice(3, src.n_frames - 3)) < 1e-4


def test_amc_export_from_bvh(tmp_path):
    amc = mocapflow.read(CMU / "02" / "02_01.amc").slice(0, 100)
    mocapflow.write(amc, tmp_path / "walk.bvh")
    src = mocapflow.read(tmp_path / "walk.bvh")
    mocapflow.write(src, tmp_path / "again.amc")
    back = read_amc(tmp_path / "again.amc", fps=src.fps)
    assert _by_name(back, src) < 1e-4


def test_a_refused_export_creates_nothing(tmp_path):
    src = mocapflow.read(BLENDER / "walk_120.gltf")
    lt = np.broadcast_to(src.skeleton.offsets, (src.n_frames, src.n_joints, 3)).copy()
    lt[:, 3] *= 1.0 + 0.1 * np.sin(np.arange(src.n_frames))[:, None]  # a stretching bone: not AMC
    stretchy = src.with_arrays(local_translations=lt)
    out = tmp_path / "export"
    segs = [Segment("q", 1, "s", "s", 0, 10)]
    with pytest.raises(DataError, match="AMC"):
        export_segments(segs, out, registries(), format="amc", load=lambda _k: stretchy)
    assert not out.exists()
