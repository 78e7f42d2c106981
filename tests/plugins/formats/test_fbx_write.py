"""The FBX 7.4 writer: files re-read by mocapflow and by ufbx (in a subprocess; skipped
without it) with the source's joint positions within 1e-4 m, rate and frames equal."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mocapflow.framework.export import Segment, export_segments
from mocapflow.framework.plugins import default_registries
from mocapflow.plugins.formats.asf_amc import read_amc
from mocapflow.plugins.formats.fbx import read_fbx, write_fbx
from mocapflow.plugins.formats.gltf import read_gltf

ROOT = Path(__file__).resolve().parents[3]
CMU = ROOT / "examples" / "data" / "cmu"
BLENDER = ROOT / "tests" / "data" / "blender"


def _sources():
    amc = read_amc(CMU / "02" / "02_01.amc").slice(0, 150)
    gl = read_gltf(BLENDER / "jump_60.glb")
    odd = gl.with_arrays(fps=119.9952)
    lt = np.broadcast_to(amc.skeleton.offsets, (amc.n_frames, amc.n_joints, 3)).copy()
    lt[:, 5] *= 1.0 + 0.1 * np.sin(np.arange(amc.n_frames))[:, None]
    return {"cmu_amc": amc, "blender_glb": gl, "odd_rate": odd, "stretch": amc.with_arrays(local_translations=lt)}


SOURCES = _sources()


def _err(back, src) -> float:
    idx = [back.skeleton.names.index(n) for n in src.skeleton.names]
    return float(np.abs(back.positions[:, idx] - src.positions).max())


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_round_trip(tmp_path, name):
    src = SOURCES[name]
    out = tmp_path / "m.fbx"
    write_fbx(src, out)
    back = read_fbx(out)
    assert back.n_frames == src.n_frames
    assert back.fps == pytest.approx(src.fps, rel=1e-12)
    assert _err(back, src) < 1e-4


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_ufbx_reads_the_written_file(tmp_path, name):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import _ufbx_ref

    if not _ufbx_ref.available():
        pytest.skip("ufbx is not installed (pip install ufbx)")
    src = SOURCES[name]
    out = tmp_path / "m.fbx"
    write_fbx(src, out)
    ref = _ufbx_ref.ufbx_positions(out, list(src.skeleton.names), np.arange(src.n_frames) / src.fps)
    assert float(ref["fps"]) == pytest.approx(src.fps, rel=1e-6)
    assert round((float(ref["end"]) - float(ref["begin"])) * src.fps) + 1 == src.n_frames
    assert np.abs(ref["pos"] / 100.0 - src.positions).max() < 1e-4  # centimetres, y up


def test_export_format_fbx(tmp_path):
    src = SOURCES["cmu_amc"]
    segs = [Segment("q", 1, "walk", "walk", 10, 90)]
    index = export_segments(segs, tmp_path, default_registries(), format="fbx", load=lambda _k: src).to_pylist()
    back = read_fbx(tmp_path / index[0]["file"])
    assert back.n_frames == 80 and _err(back, src.slice(10, 90)) < 1e-4
