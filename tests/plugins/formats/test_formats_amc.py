"""ASF/AMC reader and writers: handmade files (no corpus needed) and real CMU/HDM05 files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import corpus_path

from mocapflow.framework import quaternions as quat
from mocapflow.framework.joints import REQUIRED_JOINTS
from mocapflow.plugins.formats.asf_amc import AmcFormat, find_asf, read_amc, read_asf, write_amc, write_asf

# :units length 0.0254 makes file values metres (metres = value * 0.0254 / length).
TINY_ASF = """# tiny test skeleton
:version 1.10
:name TINY
:units
  mass 1.0
  length 0.0254
  angle deg
:documentation
   handmade
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name a
     direction 1 0 0
     length 1
     axis 0 0 90  XYZ
    dof rx
    limits (-180 180)
  end
  begin
     id 2
     name b
     direction 0 1 0
     length 2
     axis 0 0 0 XYZ
    dof rz ry
    limits (-180 180)
           (-180 180)
  end
  begin
     id 3
     name c
     direction 0 0 1
     length 0.5
     axis 0 0 0 XYZ
  end
:hierarchy
  begin
    root a c
    a b
  end
"""


def tiny_amc(frames: list[tuple[float, ...]], eol: str = "\n", frame_eol: str | None = None) -> str:
    frame_eol = eol if frame_eol is None else frame_eol
    out = [":FULLY-SPECIFIED", ":DEGREES"]
    text = eol.join(out) + eol
    for i, (tx, ty, tz, rx, ry, rz, a, bz, by) in enumerate(frames, start=1):
        text += f"{i}{frame_eol}"
        text += eol.join([f"root {tx} {ty} {tz} {rx} {ry} {rz}", f"a {a}", f"b {bz} {by}"]) + eol
    return text


@pytest.fixture
def tiny(tmp_path: Path) -> Path:
    (tmp_path / "tiny.asf").write_text(TINY_ASF)
    return tmp_path


def test_asf_joints_offsets_and_rest_pose(tiny: Path) -> None:
    sk = read_asf(tiny / "tiny.asf")
    assert sk.names == ("root", "a", "b", "b_end", "c", "c_end")
    assert sk.name == "tiny" and sk.meta["asf_name"] == "TINY"
    np.testing.assert_array_equal(sk.parents, [-1, 0, 1, 2, 0, 4])
    # joint b sits at the end of bone a; b_end at the end of b; c starts at the root
    np.testing.assert_allclose(sk.offsets, [[0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 0], [0, 0, 0.5]])
    assert sk.channels[1] == ("rx",) and sk.channels[2] == ("rz", "ry") and sk.channels[4] == ()
    assert sk.rotation_orders[2] == "zy"


def test_amc_rotation_convention(tiny: Path) -> None:
    """Bone a: axis z=90 turns its local x into global y; rx=90 then rotates bone a's
    children about global y; b's dofs are applied in listed order about fixed axes."""
    (tiny / "t.amc").write_text(
        tiny_amc([(0, 0, 0, 0, 0, 0, 0, 0, 0), (1, 2, 3, 0, 0, 0, 90, 0, 0), (0, 0, 0, 0, 0, 0, 0, 90, 90)])
    )
    m = read_amc(tiny / "t.amc")
    assert m.n_frames == 3 and m.fps == 120.0
    p = m.positions
    # frame 0: rest pose = directions * lengths chained
    np.testing.assert_allclose(p[0, [1, 2, 3, 5]], [[0, 0, 0], [1, 0, 0], [1, 2, 0], [0, 0, 0.5]], atol=1e-12)
    # frame 1: root at (1,2,3); R_y(90) turns bone a, (1,0,0) -> (0,0,-1), and keeps b's (0,2,0)
    np.testing.assert_allclose(p[1, 2], [1, 2, 2], atol=1e-12)
    np.testing.assert_allclose(p[1, 3], [1, 4, 2], atol=1e-12)
    # frame 2: b: rz=90 first, then ry=90 (fixed axes): (0,2,0) -> (-2,0,0) -> (0,0,2)
    np.testing.assert_allclose(p[2, 3], [1, 0, 2], atol=1e-12)


def test_amc_line_endings_agree(tiny: Path) -> None:
    frames = [(0.1, 0.9, -0.2, 10, 20, 30, 40, -50, 60), (0.2, 0.8, -0.1, 11, 21, 31, 41, -51, 61)]
    ref = None
    for k, (eol, feol) in enumerate([("\n", None), ("\r\n", None), ("\r\n", "\n")]):
        f = tiny / f"e{k}.amc"
        f.write_bytes(tiny_amc(frames, eol, feol).encode())
        m = read_amc(f, skeleton=tiny / "tiny.asf")
        if ref is None:
            ref = m.positions
        np.testing.assert_array_equal(m.positions, ref)


def test_amc_bones_in_any_order_per_frame(tiny: Path) -> None:
    text = ":DEGREES\n1\nroot 0 0 0 0 0 0\na 10\nb 20 30\n2\nb 21 31\nroot 0 0 0 0 0 0\na 11\n"
    (tiny / "o.amc").write_text(text)
    m = read_amc(tiny / "o.amc")
    (tiny / "p.amc").write_text(
        text.replace("2\nb 21 31\nroot 0 0 0 0 0 0\na 11\n", "2\nroot 0 0 0 0 0 0\na 11\nb 21 31\n")
    )
    np.testing.assert_allclose(m.rotations, read_amc(tiny / "p.amc").rotations)


def test_amc_radians_and_fps(tiny: Path) -> None:
    (tiny / "r.amc").write_text(":RADIANS\n1\nroot 0 0 0 0 0 0\na 1.5707963267948966\nb 0 0\n")
    m = AmcFormat(fps=60).read(tiny / "r.amc")
    assert m.fps == 60.0 and m.metadata["source_fps"] == 60.0
    np.testing.assert_allclose(m.positions[0, 2], [0, 0, -1], atol=1e-12)  # bone a turned about y
    np.testing.assert_allclose(m.positions[0, 3], [0, 2, -1], atol=1e-12)


def test_find_asf_prefix_rule(tmp_path: Path) -> None:
    for name in ("01.asf", "011.asf", "HDM.asf"):
        (tmp_path / name).write_text(TINY_ASF)
    assert find_asf(tmp_path / "01_01.amc").name == "01.asf"
    assert find_asf(tmp_path / "011_02.amc").name == "011.asf"


def test_handmade_round_trip(tiny: Path) -> None:
    rng = np.random.default_rng(3)
    frames = [tuple(rng.uniform(-170, 170, 9)) for _ in range(5)]
    (tiny / "x.amc").write_text(tiny_amc(frames))
    m = read_amc(tiny / "x.amc")
    write_amc(m, tiny / "y.amc")
    back = read_amc(tiny / "y.amc")
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-9)
    np.testing.assert_allclose(np.abs((back.rotations * m.rotations).sum(-1)), 1.0, atol=1e-12)


# --- real corpus -------------------------------------------------------------------------


@pytest.mark.parametrize("rel", [("cmu", "amc", "01", "01_01.amc"), ("hdm05", "amc", "bd")])
def test_corpus_round_trip(rel: tuple[str, ...], tmp_path: Path) -> None:
    src = corpus_path(*rel)
    if src.is_dir():  # the first HDM05 file of the actor (mixed CRLF/LF)
        src = sorted(src.glob("*.amc"))[0]
    m = read_amc(src)
    write_amc(m, tmp_path / src.name)
    write_asf(m.skeleton, tmp_path / "skel.asf")
    back = read_amc(tmp_path / src.name, skeleton=tmp_path / "skel.asf")
    assert back.n_frames == m.n_frames
    np.testing.assert_allclose(back.skeleton.offsets, m.skeleton.offsets, atol=1e-12)
    np.testing.assert_allclose(back.skeleton.axes, m.skeleton.axes, atol=1e-12)
    assert back.skeleton.channels == m.skeleton.channels
    # 1e-6 of the stored precision: AMC stores 6 significant digits, positions in metres
    np.testing.assert_allclose(back.positions, m.positions, atol=1e-6)
    np.testing.assert_allclose(np.abs((back.rotations * m.rotations).sum(-1)), 1.0, atol=1e-9)


def test_corpus_asf_rest_pose_chains_directions(tmp_path: Path) -> None:
    """Rest positions equal the ASF bone vectors chained from the root (CMU 01)."""
    path = corpus_path("cmu", "amc", "01", "01.asf")
    sk = read_asf(path)
    bones = {b["name"]: b for b in sk.meta["bones"]}
    scale = 0.0254 / 0.45
    rest = np.zeros((sk.n_joints, 3))
    for j in range(1, sk.n_joints):
        rest[j] = rest[sk.parents[j]] + sk.offsets[j]
    chain = ["lowerback", "upperback", "thorax", "lclavicle", "lhumerus", "lradius", "lwrist", "lhand", "lfingers"]
    want = sum(np.asarray(bones[b]["direction"]) * bones[b]["length"] for b in chain) * scale
    np.testing.assert_allclose(rest[sk.names.index("lfingers_end")], want, atol=1e-12)
    assert all(r in sk.canonical for r in REQUIRED_JOINTS)


def test_corpus_quaternions_are_unit_and_metadata() -> None:
    m = read_amc(corpus_path("cmu", "amc", "01", "01_01.amc"))
    np.testing.assert_allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-12)
    md = m.metadata
    assert md["format"] == "amc" and md["subject"] == "01" and md["source_frames"] == 2751 == m.n_frames
    assert len(md["checksum"]) == 40 and md["source_fps"] == 120.0
    h = read_amc(sorted(corpus_path("hdm05", "amc", "bk").glob("*.amc"))[0])
    assert h.metadata["subject"] == "bk" and h.skeleton.name == "HDM_bk"
    assert np.allclose(quat.normalize(h.rotations), h.rotations)
