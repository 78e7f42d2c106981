"""Exported Euler curves stay continuous and in the source's branch: an AMC or BVH clip
written from a take re-reads with the source's channel values (within 1e-3 degrees), also
where the source turns past 180 degrees or keeps a middle angle beyond +-90."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocapflow.framework import quaternions as quat
from mocapflow.plugins.formats._amc_write import write_amc
from mocapflow.plugins.formats._bvh_write import write_bvh
from mocapflow.plugins.formats.asf_amc import read_amc
from mocapflow.plugins.formats.bvh import read_bvh
from mocapflow.plugins.formats.gltf import read_gltf

CMU = Path(__file__).resolve().parents[3] / "examples" / "data" / "cmu" / "02"
BLENDER = Path(__file__).resolve().parents[2] / "data" / "blender"


def _amc_values(path: Path) -> dict[str, np.ndarray]:
    rows: dict[str, list[list[float]]] = {}
    for line in path.read_text(encoding="latin-1").splitlines():
        w = line.split()
        if not w or w[0].startswith((":", "#")) or w[0].isdigit():
            continue
        rows.setdefault(w[0], []).append([float(x) for x in w[1:]])
    return {k: np.array(v) for k, v in rows.items()}


def _spinning_amc(tmp_path: Path) -> Path:
    """CMU 02_01 with its root turning from 360 + rx to 760 + rx about x over the take."""
    lines = (CMU / "02_01.amc").read_text(encoding="latin-1").splitlines()
    n = sum(1 for ln in lines if ln.strip().isdigit())
    out, f = [], -1
    for ln in lines:
        w = ln.split()
        if w and w[0].isdigit():
            f += 1
        if w and w[0] == "root":
            v = [float(x) for x in w[1:]]
            v[3] += 360.0 + 400.0 * f / (n - 1)
            ln = "root " + " ".join(repr(x) for x in v)
        out.append(ln)
    (tmp_path / "spin.asf").write_bytes((CMU / "02.asf").read_bytes())
    p = tmp_path / "spin.amc"
    p.write_text("\n".join(out) + "\n", encoding="latin-1")
    return p


@pytest.mark.parametrize("cut", [(0, None), (37, 120), (150, 260)])
def test_amc_export_keeps_the_sources_branch(tmp_path, cut):
    src_path = _spinning_amc(tmp_path)
    src = read_amc(src_path)
    a, b = cut[0], cut[1] or src.n_frames
    out = tmp_path / "clip.amc"
    write_amc(src.slice(a, b), out)
    got, want = _amc_values(out), _amc_values(src_path)
    assert want["root"][:, 3].max() > 700  # the source is beyond two turns
    for bone, v in got.items():
        assert np.abs(v - want[bone][a:b]).max() < 1e-3, bone


BVH = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT Spine
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 10 0
\t\t}
\t}
}
MOTION
Frames: %d
Frame Time: 0.0333333
"""


def test_bvh_export_keeps_turns_and_flipped_triples(tmp_path):
    n = 90
    t = np.linspace(0, 1, n)
    vals = np.zeros((n, 9))
    vals[:, 1] = 90.0
    vals[:, 3] = 170 + 400 * t  # root z turning past 180 and 540
    vals[:, 4] = 100 + 30 * t  # middle angle beyond 90: the flipped triple
    vals[:, 5] = -20 + 10 * t
    vals[:, 6] = -170 - 40 * t  # spine z crossing -180
    vals[:, 7] = 30 * np.sin(6 * t)
    vals[:, 8] = 5.0
    p = tmp_path / "turn.bvh"
    p.write_text(BVH % n + "\n".join(" ".join(f"{x:.10g}" for x in r) for r in vals) + "\n")
    src = read_bvh(p, scale=0.01)
    for a, b in [(0, n), (20, 70)]:
        out = tmp_path / f"clip_{a}.bvh"
        write_bvh(src.slice(a, b), out)
        text = out.read_text().split("Frame Time:")[1].splitlines()[1:]
        got = np.array([[float(x) for x in ln.split()] for ln in text if ln.strip()])
        assert np.abs(got - vals[a:b]).max() < 1e-3


def test_bvh_from_a_gltf_source_is_continuous(tmp_path):
    m = read_gltf(BLENDER / "walk_120.gltf")
    spin = quat.from_axis_angle(np.array([0.0, 1.0, 0.0]), np.linspace(0, 4 * np.pi, m.n_frames))
    m = m.with_arrays(
        rotations=np.concatenate([quat.mul(spin[:, None], m.rotations[:, :1]), m.rotations[:, 1:]], axis=1)
    )
    out = tmp_path / "spin.bvh"
    write_bvh(m, out)
    text = out.read_text().split("Frame Time:")[1].splitlines()[1:]
    got = np.array([[float(x) for x in ln.split()] for ln in text if ln.strip()])
    assert np.abs(np.diff(got[:, 3:], axis=0)).max() < 180  # no 360-degree steps
    back = read_bvh(out, scale=1.0)
    idx = [back.skeleton.names.index(n) for n in m.skeleton.names]
    assert np.abs(back.positions[:, idx] - m.positions).max() < 1e-4
