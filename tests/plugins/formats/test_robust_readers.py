"""Readers on files from the wild: a huge or foreign file refused at its header in bounded
memory; C3D residuals compared as floats and every package error a ParseError naming the
file; a header the data contradict read as the data say (with a warning; ``strict``
refuses); BVH keywords in one case; ASF errors with their line; BVH units stable across
a character's clips."""

from __future__ import annotations

import functools
import io
import json
import os
import struct
import sys
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
import pytest
from naive import hostile_scenes as HS
from test_formats_bvh import REST, tiny_bvh

from mocapflow.framework.errors import ParseError
from mocapflow.plugins.formats import _common
from mocapflow.plugins.formats.bvh import read_bvh
from mocapflow.plugins.formats.trc import read_trc, write_trc

HUGE = 2 * 1024**3
BLENDER = Path(__file__).resolve().parents[2] / "data" / "blender"


def _sparse(path: Path, size: int, head: bytes) -> Path:
    """A sparse file of ``size`` bytes starting with ``head`` (no disk used for the rest)."""
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def _peak_bytes(fn) -> int:
    tracemalloc.start()
    try:
        fn()
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak


# --- size and header checks before the body is read ----------------------------------------
@pytest.mark.parametrize(
    "ext, head",
    [("bvh", b"\x00HIERARCHY\n"), ("trc", b"\x01PathFileType\t4\n"), ("c3d", b"\x02\x00"), ("amc", b"\x00:DEG\n")],
)
def test_huge_file_rejected_before_reading(tmp_path, ext, head):
    from mocapflow.framework.plugins import default_registries

    path = _sparse(tmp_path / f"huge.{ext}", HUGE, head)
    fmt = default_registries()["formats"]
    reader = {"bvh": "bvh", "trc": "trc", "c3d": "c3d", "amc": "amc"}[ext]
    if reader == "c3d":
        pytest.importorskip("c3d")
    if reader == "amc":
        (tmp_path / "huge.asf").write_text(":version 1.10\n")
    cls = fmt.get(reader)

    def go():
        with pytest.raises(ParseError, match="MiB") as err:
            cls().read(path)
        assert err.value.path == str(path)

    peak = _peak_bytes(go)
    assert peak < 20 * 2**20


@pytest.mark.parametrize(
    "ext, head, expect",
    [
        ("bvh", b"\x00HIERARCHY\n", "binary byte 0x00"),
        ("bvh", b"MOTION\nFrames: 1\n", "HIERARCHY"),
        ("trc", b"\x01PathFileType\t4\n", "binary byte 0x01"),
        ("trc", b"Frame#\tTime\n", "PathFileType"),
        ("c3d", b"\x02\x00", "0x50"),
    ],
)
def test_file_within_the_limit_rejected_at_its_header_reads_only_the_head(tmp_path, ext, head, expect):
    if ext == "c3d":
        pytest.importorskip("c3d")
        from mocapflow.plugins.formats.c3d import read_c3d as read
    else:
        read = {"bvh": read_bvh, "trc": read_trc}[ext]
    path = _sparse(tmp_path / f"big.{ext}", 300 * 2**20, head)

    def go():
        with pytest.raises(ParseError, match=expect) as err:
            read(path)
        assert err.value.path == str(path)

    peak = _peak_bytes(go)
    assert peak < 2 * _common.HEAD_BYTES + 2**20


def test_size_limit_is_documented_and_named(tmp_path, monkeypatch):
    monkeypatch.setattr(_common, "MAX_FILE_BYTES", 1000)
    p = tmp_path / "a.bvh"
    p.write_bytes(b"HIERARCHY\n" + b" " * 2000)
    with pytest.raises(ParseError, match="at most 0 MiB per file"):
        read_bvh(p)


def test_not_a_regular_file(tmp_path):
    import os

    fifo = tmp_path / "pipe.bvh"
    os.mkfifo(fifo)
    with pytest.raises(ParseError, match="regular file"):
        read_bvh(fifo)


# --- C3D ------------------------------------------------------------------------------------
def _c3d_bytes(n=29, labels=True, units="mm  ", analog_only=False) -> bytes:
    c3d = pytest.importorskip("c3d")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        w = c3d.Writer(point_rate=100.0, analog_rate=100.0 if analog_only else 0.0, point_scale=-1.0, point_units=units)
        if analog_only:
            w.add_frames([(np.zeros((0, 5), np.float32), np.ones((2, 1), np.float32))] * n)
        else:
            pts = np.zeros((3, 5), np.float32)
            pts[:, :3] = [[100, 200, 1000], [150, 250, 1100], [120, 220, 1500]]
            frames = []
            for k in range(n):
                p = pts.copy()
                p[:, 0] += k
                frames.append((p, np.zeros((0, 0))))
            w.add_frames(frames)
            if labels:
                w.set_point_labels(["a", "b", "c"])
        b = io.BytesIO()
        w.write(b)
    return b.getvalue()


def _data_start(data: bytes) -> int:
    c3d = pytest.importorskip("c3d")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = c3d.Reader(io.BytesIO(data))
    return (int(r.header.data_block) - 1) * 512


def test_c3d_huge_positive_residual_is_a_valid_sample(tmp_path):
    from mocapflow.plugins.formats.c3d import read_c3d

    data = bytearray(_c3d_bytes(n=4))
    start = _data_start(bytes(data))
    stride = 3 * 4 * 4
    for f in range(4):  # every sample of point 2: residual 1.7e38 (a peer reads them all)
        struct.pack_into("<f", data, start + f * stride + 1 * 16 + 12, 1.7e38)
    struct.pack_into("<f", data, start + 2 * stride + 0 * 16 + 12, -1.0)  # one real gap
    (tmp_path / "r.c3d").write_bytes(bytes(data))
    m = read_c3d(tmp_path / "r.c3d")
    assert np.isfinite(m.positions[:, 1]).all()
    assert np.allclose(m.positions[:, 1, 1], 0.25)
    assert np.isnan(m.positions[2, 0]).all() and np.isfinite(np.delete(m.positions, 2, axis=0)[:, 0]).all()


def test_c3d_odd_files_read_or_refused_naming_the_file(tmp_path):
    from mocapflow.plugins.formats.c3d import read_c3d

    p = tmp_path / "nolabels.c3d"
    p.write_bytes(_c3d_bytes(labels=False))
    m = read_c3d(p)
    assert m.labels == ("point1", "point2", "point3")
    assert any("POINT:LABELS" in w for w in m.metadata["warnings"])
    p = tmp_path / "analog.c3d"
    p.write_bytes(_c3d_bytes(analog_only=True))
    with pytest.raises(ParseError, match="expected 3-D points") as err:
        read_c3d(p)
    assert err.value.path == str(p)
    p = tmp_path / "nul.c3d"
    p.write_bytes(_c3d_bytes(units="mm\x00\x00"))
    assert read_c3d(p).metadata["units"] == "mm"
    # a garbled parameter section: the file's ParseError
    data = bytearray(_c3d_bytes())
    data[512 + 4 :] = bytes([0xFF]) * (len(data) - 512 - 4)
    p = tmp_path / "garbled.c3d"
    p.write_bytes(bytes(data))
    with pytest.raises(ParseError, match="expected") as err:
        read_c3d(p)
    assert err.value.path == str(p)


def test_c3d_header_last_frame_contradicted_by_point_frames_and_the_data(tmp_path):
    from mocapflow.plugins.formats.c3d import read_c3d

    data = bytearray(_c3d_bytes(n=29))
    struct.pack_into("<H", data, 8, 1149)  # header word 5: last frame
    p = tmp_path / "h.c3d"
    p.write_bytes(bytes(data))
    m = read_c3d(p)
    assert m.n_frames == 29 and np.allclose(m.positions[:, 0, 0], (100 + np.arange(29)) / 1000)
    assert any("POINT:FRAMES" in w for w in m.metadata["warnings"])
    with pytest.raises(ParseError, match="truncated"):
        read_c3d(p, strict=True)
    cut = tmp_path / "cut.c3d"  # really truncated: POINT:FRAMES says 29 too, the file holds 10
    cut.write_bytes(bytes(data[: _data_start(bytes(data)) + 10 * 48]))
    short = read_c3d(cut)  # the whole frames held, with a warning naming both counts
    assert short.n_frames == 10 and "holds 10 whole frames" in short.metadata["warnings"][0]
    np.testing.assert_array_equal(short.positions, m.positions[:10])
    with pytest.raises(ParseError, match="truncated"):
        read_c3d(cut, strict=True)


# --- TRC, BVH, ASF --------------------------------------------------------------------------
def test_trc_numframes_above_the_rows_present(tmp_path):
    from test_formats_markers import small_markers

    p = tmp_path / "a.trc"
    mk = small_markers(t=4)
    write_trc(mk, p)
    lines = p.read_text().split("\n")
    lines[2] = lines[2].replace("\t4\t", "\t9\t", 1)
    p.write_text("\n".join(lines))
    m = read_trc(p)
    assert m.n_frames == 4
    assert np.allclose(np.nan_to_num(m.positions), np.nan_to_num(mk.positions))
    assert any("NumFrames says 9" in w for w in m.metadata["warnings"])
    with pytest.raises(ParseError, match="expected 9 data rows"):
        read_trc(p, strict=True)


def test_bvh_blank_lines_after_motion(tmp_path):
    p = tmp_path / "tiny.bvh"
    p.write_text(tiny_bvh([REST] * 3))
    ref = read_bvh(p)
    text = p.read_text().replace("MOTION\n", "MOTION\n\n   \n", 1)
    q = tmp_path / "blank.bvh"
    q.write_text(text)
    m = read_bvh(q)
    assert np.array_equal(m.rotations, ref.rotations) and np.array_equal(m.root_translation, ref.root_translation)


def test_bvh_keywords_in_one_case_only(tmp_path):
    p = tmp_path / "tiny.bvh"
    p.write_text(tiny_bvh([REST] * 3))
    text = p.read_text()
    for ok in ("channels", "Channels"):
        q = tmp_path / f"{ok}.bvh"
        q.write_text(text.replace("CHANNELS", ok))
        read_bvh(q)
    q = tmp_path / "mixed.bvh"
    q.write_text(text.replace("CHANNELS", "CHANnELS", 1))
    with pytest.raises(ParseError, match="found 'CHANnELS'") as err:
        read_bvh(q)
    assert err.value.line == text[: text.index("CHANNELS")].count("\n") + 1


def test_asf_hierarchy_naming_an_undefined_bone_has_its_line(tmp_path):
    from test_formats_amc import TINY_ASF

    from mocapflow.plugins.formats.asf_amc import read_asf

    lines = TINY_ASF.split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.strip().startswith("root "))
    lines.insert(k + 1, "    b phantom#comment")  # a comment right after the name
    p = tmp_path / "g.asf"
    p.write_text("\n".join(lines))
    with pytest.raises(ParseError, match="'phantom'") as err:
        read_asf(p)
    assert err.value.line == k + 2


def _character(scale: float, sitting: bool) -> str:
    """One character (same bone lengths) with its rest pose standing or sitting (shins
    forward: an exporter that writes a clip's first frame as the rest pose)."""
    arm = [(1, 0, 0)] * 3
    bones = {
        "Hips": ((0, 0, 0), None),
        "Spine": ((0, 10, 0), "Hips"),
        "Head": ((0, 12, 0), "Spine"),
        "LArm": ((3, 8, 0), "Spine"),
        "LFore": (tuple(11 * np.array(arm[0])), "LArm"),
        "LHand": (tuple(10 * np.array(arm[1])), "LFore"),
        "LLeg": ((4, -2, 0), "Hips"),
        "LShin": ((0, 0, 17) if sitting else (0, -17, 0), "LLeg"),
        "LFoot": ((0, -16, 0), "LShin"),
    }
    out = ["HIERARCHY"]

    def emit(name, level):
        off, parent = bones[name]
        kw = "ROOT" if parent is None else "JOINT"
        ind = "  " * level
        out.append(f"{ind}{kw} {name}")
        out.append(f"{ind}{{")
        out.append(f"{ind}  OFFSET {' '.join(f'{v * scale:g}' for v in off)}")
        chans = (
            "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
            if parent is None
            else "3 Zrotation Xrotation Yrotation"
        )
        out.append(f"{ind}  CHANNELS {chans}")
        kids = [k for k, (_o, p) in bones.items() if p == name]
        for k in kids:
            emit(k, level + 1)
        if not kids:
            out.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET 0 {-3 * scale:g} 0", f"{ind}  }}"])
        out.append(f"{ind}}}")

    emit("Hips", 0)
    n_ch = 6 + 3 * (len(bones) - 1)
    out += ["MOTION", "Frames: 2", "Frame Time: 0.0333333"]
    out += [" ".join(["0"] * n_ch)] * 2
    return "\n".join(out) + "\n"


def test_bvh_units_stable_across_a_characters_rest_poses(tmp_path):
    """Sibling clips of one character whose OFFSETs describe different rest poses: the
    rest pose's height put them on both sides of the inch / CMU-unit boundary."""
    got = {}
    for sitting in (False, True):  # rest-pose heights 53.6 and 39.1 units: the old rule said inch, asf_cmu
        p = tmp_path / f"c{sitting}.bvh"
        p.write_text(_character(0.85, sitting))
        m = read_bvh(p)
        got[sitting] = (m.metadata["unit"], m.metadata["scale"])
        assert m.metadata["unit_source"] == "guessed from the bone lengths" and m.metadata["span"] > 0
    assert got[False] == got[True]
    forced = read_bvh(tmp_path / "cFalse.bvh", scale="cm")
    assert forced.metadata["unit"] == "cm" and forced.metadata["unit_source"] == "given"


def test_skeleton_span_is_the_longest_bone_path():
    from mocapflow.plugins.formats.bvh import skeleton_span

    parents = np.array([-1, 0, 1, 0, 3])
    offsets = np.array([[5, 5, 5], [0, 3, 0], [0, 4, 0], [2, 0, 0], [0, 0, 1]], float)
    # 2-1-0-3-4: 4 + 3 + 2 + 1 = 10 (the root's own offset is no bone)
    assert skeleton_span(parents, offsets) == pytest.approx(10.0)


# --- glTF, GLB and FBX: hostile files (one case per class, tests/naive/hostile_scenes.py) ------
_OPENED: list[str] | None = None  # paths opened while a case is read (None: not recording)


def _audit(event: str, args: tuple) -> None:
    if _OPENED is not None and event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
        _OPENED.append(os.fsdecode(args[0]))


sys.addaudithook(_audit)

_SCENE_CASES = [
    *HS.GLTF_CASES[:18],
    functools.partial(HS.node_chain, depth=2_000),
    functools.partial(HS.node_wide, n=5_000),
    *HS.GLTF_CASES[20:],
    *HS.FBX_CASES[:5],
    functools.partial(HS.fbx_model_chain, depth=5_000),
    *HS.FBX_CASES[6:-1],
    HS.uri_big_sidecar,
    *(HS.huge_invalid(ext) for ext in ("gltf", "glb", "fbx")),
    *(HS.huge_valid_head(ext) for ext in ("gltf", "glb", "fbx")),
]


def _case_id(make) -> str:
    f = make.func if isinstance(make, functools.partial) else make
    return f.__qualname__.split(".")[0] + ("" if f.__closure__ is None else f"_{f.__closure__[0].cell_contents}")


@pytest.mark.parametrize("make", _SCENE_CASES, ids=[_case_id(m) for m in _SCENE_CASES])
def test_hostile_scene_file_refused_inside_its_folder(tmp_path, make):
    """Each class: a ParseError naming the file and what was expected, no file opened
    outside the case's folder, bounded memory; huge files refused at their header."""
    global _OPENED
    import mocapflow

    mocapflow.read(BLENDER / "jump_60.glb")  # lazy imports and registries loaded before recording
    folder = tmp_path / "case"
    folder.mkdir()
    case = make(folder)
    _OPENED = []
    try:
        peak = _peak_bytes(lambda: _expect_refused(case))
        opened = list(_OPENED)
    finally:
        _OPENED = None
    outside = [p for p in opened if not Path(p).resolve().is_relative_to(folder.resolve())]
    assert not outside, f"{case.name}: opened {outside[:3]}"
    assert peak < (2**20 if case.big else 300 * 2**20), f"{case.name}: traced peak {peak / 2**20:.0f} MB"


def _expect_refused(case) -> None:
    import mocapflow

    with pytest.raises(ParseError, match=case.expect) as err:
        mocapflow.read(case.path)
    assert err.value.path == str(case.path)


def test_sidecar_buffers_inside_the_folder_are_read(tmp_path):
    """The confinement keeps what is legitimate: a buffer in a subfolder, a percent-encoded
    name, a symbolic link to a file inside the folder; bytes beyond byteLength are not read."""
    import mocapflow

    doc, buf = HS.gltf_doc()
    (tmp_path / "sub dir").mkdir()
    (tmp_path / "sub dir" / "b.bin").write_bytes(buf + b"\0" * 100)
    ref = mocapflow.read(HS.write_gltf_case(tmp_path, json.loads(json.dumps(doc)), buf, name="ref"))
    p = HS.write_gltf_case(tmp_path, json.loads(json.dumps(doc)), None, name="x")
    for uri in ("sub%20dir/b.bin", "./sub dir/b.bin", "link.bin"):
        if uri == "link.bin":
            (tmp_path / "link.bin").symlink_to(tmp_path / "sub dir" / "b.bin")
        d = json.loads(p.read_text())
        d["buffers"][0]["uri"] = uri
        p.write_text(json.dumps(d))
        assert np.array_equal(mocapflow.read(p).positions, ref.positions), uri


def test_sidecar_counts_in_the_size_cap(tmp_path, monkeypatch):
    doc, buf = HS.gltf_doc()
    p = HS.write_gltf_case(tmp_path, doc, buf)
    monkeypatch.setattr(_common, "MAX_FILE_BYTES", p.stat().st_size + len(buf) - 1)
    with pytest.raises(ParseError, match="MiB per file"):
        from mocapflow.plugins.formats.gltf import read_gltf

        read_gltf(p)


def test_fbx_reserialized_reads_as_the_original(tmp_path):
    """The hostile FBX cases are edits of a faithful re-serialization of a Blender file."""
    import mocapflow

    a = mocapflow.read(HS.fbx_roundtrip(tmp_path))
    b = mocapflow.read(HS.WALK_FBX)
    assert np.array_equal(a.positions, b.positions)


def test_far_key_refused_with_its_gap_and_a_timeline_within_the_keys_read(tmp_path):
    from mocapflow.plugins.formats.gltf import read_gltf

    doc, buf = HS.gltf_doc(61)
    p = HS.write_gltf_case(tmp_path, json.loads(json.dumps(doc)), HS._far_key(doc, buf, 60.0))
    m = read_gltf(p)  # 2 s of keys then one key at 60 s: 1,801 frames from 61 keys, within the bound
    assert m.n_frames == 1801
    p = HS.write_gltf_case(tmp_path, json.loads(json.dumps(doc)), HS._far_key(doc, buf, 83_000.0))
    with pytest.raises(ParseError, match="largest gap between keys is 82998 s"):
        read_gltf(p)


def test_gltf_top_level_arrays_of_the_wrong_type(tmp_path):
    """Fuzzer finds (seed 0, cases 12682 and 26256): ``"buffers": 0`` or ``"accessors": true``
    were a TypeError."""
    from mocapflow.plugins.formats.gltf import read_gltf

    for key, value in (("buffers", 0), ("accessors", True), ("bufferViews", "x"), ("skins", 5)):
        doc, buf = HS.gltf_doc()
        doc[key] = value
        p = HS.write_gltf_case(tmp_path, doc) if key == "buffers" else HS.write_gltf_case(tmp_path, doc, buf)
        with pytest.raises(ParseError, match=f"expected '{key}' to be an array"):
            read_gltf(p)


def test_fbx_record_cap_and_unread_objects_skipped(tmp_path, monkeypatch):
    """Records of the kinds the reader parses are capped; other object kinds (meshes) are
    skipped unparsed, so a zlib bomb inside one is never inflated."""
    import zlib

    from mocapflow.plugins.formats import _fbx_parse
    from mocapflow.plugins.formats._fbx_parse import Node
    from mocapflow.plugins.formats.fbx import read_fbx

    monkeypatch.setattr(_fbx_parse, "MAX_RECORDS", 8_000)
    case = HS.fbx_record_flood(tmp_path, n=10_000)
    with pytest.raises(ParseError, match="at most 8,000 node records"):
        read_fbx(case.path)
    monkeypatch.setattr(_fbx_parse, "MAX_RECORDS", 500_000)
    _v, root = HS.walk_fbx()
    objects = next(c for c in root.children if c.name == "Objects")
    bomb = HS.Raw(b"d", 1 << 28, 1, zlib.compress(bytes(1 << 24), 9))
    objects.children.append(Node("Geometry", [1, "mesh\x00\x01Geometry", "Mesh"], [Node("Vertices", [bomb], [], 0)], 0))
    p = tmp_path / "mesh.fbx"
    p.write_bytes(HS.fbx_bytes(root))
    peak = _peak_bytes(lambda: read_fbx(p))
    assert peak < 50 * 2**20


def test_gltf_document_over_the_json_cap_is_refused_from_its_size(tmp_path):
    """A .gltf whose head is valid JSON text but which is larger than the JSON cap (an endless
    string behind a valid head, or a huge embedded buffer) is refused before its body is read."""
    from mocapflow.plugins.formats.gltf import MAX_GLB_JSON, read_gltf

    p = tmp_path / "endless.gltf"
    with open(p, "wb") as f:
        f.write(b'{"asset": {"version": "2.0"}, "x": "' + b"a" * (1 << 17))
        f.truncate(MAX_GLB_JSON + 1)

    def go():
        with pytest.raises(ParseError, match="at most 64 MiB") as err:
            read_gltf(p)
        assert err.value.path == str(p)

    assert _peak_bytes(go) < 2 * _common.HEAD_BYTES + 2**20


def test_gltf_writer_refuses_what_its_reader_would(tmp_path, monkeypatch):
    """The .gltf writer refuses a take whose embedded buffer would pass the JSON cap, before
    writing anything (the message names .glb)."""
    from mocapflow.framework.errors import DataError
    from mocapflow.framework.synthetic import synthetic_motion
    from mocapflow.plugins.formats import _common
    from mocapflow.plugins.formats.gltf import write_gltf

    monkeypatch.setattr(_common, "MAX_GLB_JSON", 10_000)
    with pytest.raises(DataError, match=r"\.glb"):
        write_gltf(synthetic_motion(200), tmp_path / "big.gltf")
    assert not (tmp_path / "big.gltf").exists()
    write_gltf(synthetic_motion(200), tmp_path / "big.glb")  # the container takes it
