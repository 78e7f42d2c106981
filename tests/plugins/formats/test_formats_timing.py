"""Timing of scene formats: glTF keys read at their own times (no resampling unless
``fps=`` asks), the rate as read, ``extras.fps`` written and honoured."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mocapflow.plugins.formats.gltf import read_gltf, write_gltf

BLENDER = Path(__file__).resolve().parents[2] / "data" / "blender"


def _long_take(n: int, fps: float):
    """A Blender-made walk tiled to ``n`` frames with a drifting, turning root."""
    m = read_gltf(BLENDER / "walk_120.gltf")
    idx = np.arange(n) % m.n_frames
    k = np.arange(n)
    root = m.root_translation[idx] + np.stack([0.001 * k, 0 * k, 0.1 * np.sin(k / 50)], axis=1)
    return m.with_arrays(rotations=m.rotations[idx], root_translation=root, fps=fps)


def _strip_fps(path: Path) -> None:
    doc = json.loads(path.read_text())
    for a in doc["animations"]:
        a.pop("extras", None)
    path.write_text(json.dumps(doc))


def test_non_standard_key_spacing_is_kept_at_every_key(tmp_path):
    fps = 119.9952  # Blender's key spacing
    src = _long_take(10_000, fps)
    out = tmp_path / "long.gltf"
    write_gltf(src, out)
    _strip_fps(out)
    back = read_gltf(out)
    assert back.metadata["fps_source"] == "key times"
    assert back.n_frames == src.n_frames
    assert back.fps == pytest.approx(fps, rel=1e-6)  # as read, not snapped to 120
    assert np.abs(back.positions - src.positions).max() <= 1e-5


def test_extras_fps_written_and_honoured(tmp_path):
    src = _long_take(300, 119.9952)
    out = tmp_path / "x.glb"
    write_gltf(src, out)
    back = read_gltf(out)
    assert back.metadata["fps_source"] == "extras"
    assert back.fps == 119.9952
    assert np.abs(back.positions - src.positions).max() <= 1e-5


def test_standard_rate_in_float32_times_is_recognised(tmp_path):
    src = _long_take(2_000, 30.0)
    out = tmp_path / "s.gltf"
    write_gltf(src, out)
    _strip_fps(out)
    back = read_gltf(out)
    assert back.fps == 30.0 and back.n_frames == 2_000


def test_resampling_only_when_asked(tmp_path):
    src = _long_take(600, 119.9952)
    out = tmp_path / "r.gltf"
    write_gltf(src, out)
    back = read_gltf(out, fps=30)
    assert back.fps == 30.0 and back.metadata["fps_source"] == "given"
    assert back.n_frames == int(round((600 - 1) / 119.9952 * 30)) + 1
