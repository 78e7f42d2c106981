"""BVH reader and writer: handmade files (no corpus needed), real files of every source,
and the AMC/BVH cross-format check on CMU 01_01."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import corpus_path

from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.testing import synthetic_motion
from mocapflow.plugins.formats.asf_amc import read_amc
from mocapflow.plugins.formats.bvh import BvhFormat, read_bvh, write_bvh

TINY_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Head
    {
      OFFSET 0 50 0
      CHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
      End Site
      {
        OFFSET 0 20 0
      }
    }
  }
  JOINT LeftUpLeg
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -90 0
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.04
"""


def tiny_bvh(rows: list[list[float]], eol: str = "\n") -> str:
    return (TINY_BVH + "\n".join(" ".join(str(v) for v in r) for r in rows) + "\n").replace("\n", eol)


REST = [0, 90, 0, 0, 0, 0, 0, 0, 0, 0, 50, 0, 0, 0, 0, 0, 0, 0]


def test_bvh_structure_and_rotation_order(tmp_path: Path) -> None:
    r1 = list(REST)
    r1[3] = 90  # root Zrotation: the spine (0, 10, 0) turns to (-10, 0, 0)
    r2 = list(REST)
    r2[6], r2[7] = 90, 90  # Spine Xrotation then Yrotation (intrinsic: R = Rx Ry)
    (tmp_path / "t.bvh").write_text(tiny_bvh([REST, r1, r2]))
    m = read_bvh(tmp_path / "t.bvh")
    sk = m.skeleton
    assert sk.names == ("Hips", "Spine", "Head", "Head_end", "LeftUpLeg", "LeftUpLeg_end")
    assert m.n_frames == 3 and m.fps == pytest.approx(25.0)
    assert m.metadata["unit"] == "cm" and m.metadata["scale"] == 0.01  # 170 units tall
    assert m.local_translations is None  # Head's position channels equal its OFFSET
    p = m.positions
    np.testing.assert_allclose(p[0, [1, 2, 3, 5]], [[0, 1.0, 0], [0, 1.5, 0], [0, 1.7, 0], [0.1, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(p[1, 1], [-0.1, 0.9, 0], atol=1e-12)
    # R = Rx(90) Ry(90): Head offset (0, .5, 0) -> Ry keeps it -> Rx(90) gives (0, 0, .5)
    np.testing.assert_allclose(p[2, 2] - p[2, 1], [0, 0, 0.5], atol=1e-12)
    assert {"root", "head", "headtop", "lhip"} <= set(sk.canonical)


def test_bvh_animated_joint_translation(tmp_path: Path) -> None:
    r = list(REST)
    r[10] = 60  # Head Yposition differs from its OFFSET (50)
    (tmp_path / "s.bvh").write_text(tiny_bvh([REST, r, REST]))
    m = read_bvh(tmp_path / "s.bvh", scale=0.01)
    assert m.local_translations is not None
    np.testing.assert_allclose(m.positions[1, 2], [0, 1.6, 0], atol=1e-12)
    np.testing.assert_allclose(m.positions[0, 2], [0, 1.5, 0], atol=1e-12)


def test_bvh_crlf_and_explicit_scale(tmp_path: Path) -> None:
    (tmp_path / "a.bvh").write_text(tiny_bvh([REST] * 3))
    (tmp_path / "b.bvh").write_bytes(tiny_bvh([REST] * 3, "\r\n").encode())
    a, b = read_bvh(tmp_path / "a.bvh"), BvhFormat(scale=0.01).read(tmp_path / "b.bvh")
    np.testing.assert_array_equal(a.positions, b.positions)
    assert read_bvh(tmp_path / "a.bvh", scale=1.0).positions[0, 3, 1] == pytest.approx(170.0)


def test_bvh_write_any_motion(tmp_path: Path) -> None:
    m = synthetic_motion(12, seed=5)
    write_bvh(m, tmp_path / "syn.bvh")
    back = read_bvh(tmp_path / "syn.bvh", scale=1.0)
    np.testing.assert_allclose(back.canonical_positions(), m.canonical_positions(), atol=1e-8)


# --- real corpus -------------------------------------------------------------------------

SOURCES = [
    ("cmu_cgspeed", "131_03.bvh"),
    ("bandai_namco_1", "dataset-1_walk_happy_001.bvh"),
    ("xia_style", "angry_13_000.bvh"),
    ("pymo_demo", "AV_8Walk_Meredith_HVHA_Rep1.bvh"),
]


@pytest.mark.parametrize("source, name", SOURCES)
def test_corpus_round_trip(source: str, name: str, tmp_path: Path) -> None:
    src = corpus_path("bvh", source, name)
    m = read_bvh(src)
    write_bvh(m, tmp_path / name)
    back = read_bvh(tmp_path / name)
    assert back.skeleton.names == m.skeleton.names and back.skeleton.channels == m.skeleton.channels
    assert back.metadata["scale"] == m.metadata["scale"] and back.fps == pytest.approx(m.fps, rel=1e-9)
    assert (back.local_translations is None) == (m.local_translations is None)
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6)
    np.testing.assert_allclose(np.abs((back.rotations * m.rotations).sum(-1)), 1.0, atol=1e-9)


def test_amc_to_bvh_conversion(tmp_path: Path) -> None:
    m = read_amc(corpus_path("cmu", "amc", "01", "01_01.amc")).slice(0, 200)
    write_bvh(m, tmp_path / "conv.bvh")
    back = read_bvh(tmp_path / "conv.bvh", scale=1.0)
    np.testing.assert_allclose(back.canonical_positions(), m.canonical_positions(), atol=1e-8)


def test_cross_format_cmu_01_01() -> None:
    """CMU 01_01 as AMC and as the cgspeed BVH (first BVH frame is an extra T-pose).

    Measured (metres, all 2751 frames): root, legs and trunk up to the chest agree to
    < 1e-5 (max 5.2e-6 at rtoes, mean about 1.7e-6: the BVH keeps 5 decimals). Every
    joint above the chest is off by a constant 0.1166 m: the cgspeed skeleton puts the
    neck and clavicles at the *start* of the thorax bone (``Neck OFFSET 0 0 0``),
    dropping its length (2.06488 * 0.0254 / 0.45 = 0.11655 m). Relative to the neck,
    head and arms agree to < 1e-5 (max 2.3e-6) and the fingers are off by the dropped
    wrist bone (0.0983 m left, 0.0972 m right: the wrist lengths of 01.asf): the same
    retarget rule at the wrist, whose bone has two children (hand, thumb).
    """
    a = read_amc(corpus_path("cmu", "amc", "01", "01_01.amc"))
    b = read_bvh(corpus_path("bvh", "cmu_cgspeed", "01_01.bvh"))
    assert b.metadata["unit"] == "asf_cmu" and b.n_frames == a.n_frames + 1
    pa, pb = a.canonical_positions(), b.canonical_positions()[1:]
    idx = {n: k for k, n in enumerate(CANONICAL_JOINTS)}
    err = np.linalg.norm(pa - pb, axis=-1)
    lower = [
        "root",
        "lhip",
        "lknee",
        "lankle",
        "ltoes",
        "rhip",
        "rknee",
        "rankle",
        "rtoes",
        "lowerback",
        "upperback",
        "chest",
    ]
    assert err[:, [idx[j] for j in lower]].max() < 1e-4
    thorax = 2.06488 * 0.0254 / 0.45
    upper = ["neck", "head", "headtop", "lclavicle", "lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist"]
    np.testing.assert_allclose(err[:, [idx[j] for j in upper]], thorax, atol=1e-4)
    rel = np.linalg.norm((pa - pa[:, [idx["neck"]]]) - (pb - pb[:, [idx["neck"]]]), axis=-1)
    assert rel[:, [idx[j] for j in upper]].max() < 1e-4
    bones = {bn["name"]: bn["length"] * 0.0254 / 0.45 for bn in a.skeleton.meta["bones"]}
    np.testing.assert_allclose(rel[:, idx["lfingers"]], bones["lwrist"], atol=1e-4)
    np.testing.assert_allclose(rel[:, idx["rfingers"]], bones["rwrist"], atol=1e-4)


def test_positions_match_pybvh() -> None:
    """An independent reader (pybvh, optional) gives the same joint positions."""
    pybvh = pytest.importorskip("pybvh")
    for source, name in SOURCES[:1] + SOURCES[2:]:
        path = corpus_path("bvh", source, name)
        ref = pybvh.read_bvh_file(path, warn_on_world_up_disagreement=False).node_positions()
        m = read_bvh(path, scale=1.0)
        np.testing.assert_allclose(m.positions, ref, atol=1e-9)


def test_static_root_is_collapsed(tmp_path: Path) -> None:
    """A never-moving root above translating hips (Bandai-Namco layout) is dropped."""
    text = """HIERARCHY
ROOT joint_Root
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Hips
  {
    OFFSET 0 90 0
    CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
    JOINT Head
    {
      OFFSET 0 80 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 10 0
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
5 0 0 0 90 0 0 90 0 0 0 0 0 0 0
5 0 0 0 90 0 10 95 0 90 0 0 0 0 0
"""
    (tmp_path / "r.bvh").write_text(text)
    m = read_bvh(tmp_path / "r.bvh")
    full = read_bvh(tmp_path / "r.bvh", collapse_static_root=False)
    assert m.skeleton.names == ("Hips", "Head", "Head_end") and m.metadata["collapsed_root"] == "joint_Root"
    assert m.local_translations is None and full.local_translations is not None
    np.testing.assert_allclose(m.positions, full.positions[:, 1:], atol=1e-12)
    # the static root turned everything 90 degrees about x: hips at (5, 0, 90) cm, then moving
    np.testing.assert_allclose(m.root_translation, [[0.05, 0, 0.9], [0.15, 0, 0.95]], atol=1e-12)
    write_bvh(m, tmp_path / "w.bvh")
    np.testing.assert_allclose(read_bvh(tmp_path / "w.bvh", scale=0.01).positions, m.positions, atol=1e-9)
