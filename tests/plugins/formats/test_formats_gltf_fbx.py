"""glTF/GLB and FBX readers and the glTF writer.

* against Blender: files Blender exported from bundled CMU takes, with the joint positions
  Blender's own importer computes (``tests/data/blender``, made by ``make_blender_files.py``);
* against the slow glTF twin (``tests/naive/gltf.py``) on files with LINEAR, STEP and
  CUBICSPLINE samplers at key times off the frame grid;
* writer round trips; malformed files raise ParseError naming the file.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

import mocapflow
from mocapflow.framework.errors import ParseError
from mocapflow.plugins.formats.asf_amc import read_amc
from mocapflow.plugins.formats.fbx import read_fbx
from mocapflow.plugins.formats.gltf import read_gltf, write_gltf

ROOT = Path(__file__).resolve().parents[3]
BLENDER = ROOT / "tests" / "data" / "blender"
FILES = sorted(p for p in BLENDER.iterdir() if p.suffix in (".gltf", ".glb", ".fbx"))
CMU = ROOT / "examples" / "data" / "cmu"


def test_blender_files_are_there():
    kinds = {p.suffix for p in FILES}
    assert kinds == {".gltf", ".glb", ".fbx"}
    rates = {float(np.load(f"{p}.npz")["fps"]) for p in FILES}
    assert rates - {30.0}, "at least one file not at 30 fps"


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_positions_equal_blenders_importer(path):
    ref = np.load(f"{path}.npz")
    m = mocapflow.read(path)
    assert m.fps == pytest.approx(float(ref["fps"]), rel=1e-9)
    pos = ref["positions"]
    assert m.n_frames == pos.shape[0]
    names = [str(n) for n in ref["names"]]
    assert set(names) <= set(m.skeleton.names)
    idx = [m.skeleton.names.index(n) for n in names]
    err = np.abs(m.positions[:, idx] - pos).max()
    assert err < 1e-4, f"{path.name}: {err:.2e} m from Blender"
    assert m.positions[:, 0, 1].mean() > 0.5  # y up, metres: the hips are about a metre up


def test_zup_centimetre_fbx_is_converted():
    zup = BLENDER / "run_30_zup_cm.fbx"
    m = read_fbx(zup)
    assert m.metadata["unit_scale"] == pytest.approx(0.01)
    assert m.fps == 30.0


@pytest.mark.parametrize("ext", [".gltf", ".glb"])
def test_writer_round_trip(tmp_path, ext):
    src = read_amc(CMU / "02" / "02_01.amc").slice(0, 90)
    out = tmp_path / f"walk{ext}"
    mocapflow.write(src, out)
    back = mocapflow.read(out)
    assert back.fps == src.fps and back.n_frames == src.n_frames
    assert back.skeleton.names == src.skeleton.names
    assert np.array_equal(back.skeleton.parents, src.skeleton.parents)
    assert np.abs(back.positions - src.positions).max() < 1e-5  # float32 in the file
    assert (out.read_bytes()[:4] == b"glTF") == (ext == ".glb")


def test_rewrite_keeps_the_rigs_rest_orientations(tmp_path):
    src = BLENDER / "jump_60.glb"
    m = read_gltf(src)
    out = tmp_path / "again.glb"
    write_gltf(m, out)
    back = read_gltf(out)
    assert np.abs(back.positions - m.positions).max() < 1e-5
    assert np.abs(back.rotations - m.rotations).max() < 1e-5

    def node_rotations(p: Path) -> dict[str, np.ndarray]:
        data = p.read_bytes()
        doc = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
        return {n["name"]: np.array(n.get("rotation", [0, 0, 0, 1])) for n in doc["nodes"]}

    a, b = node_rotations(src), node_rotations(out)
    for name in m.skeleton.names[1:]:
        q, r = a[name], b[name]
        assert min(np.abs(q - r).max(), np.abs(q + r).max()) < 1e-6, name


def test_local_translations_round_trip(tmp_path):
    src = read_amc(CMU / "02" / "02_01.amc").slice(0, 20)
    lt = np.broadcast_to(src.skeleton.offsets, (20, src.n_joints, 3)).copy()
    lt[:, 5] *= 1.0 + 0.1 * np.sin(np.arange(20))[:, None]  # a stretching bone
    src = src.with_arrays(local_translations=lt)
    write_gltf(src, tmp_path / "s.gltf")
    back = read_gltf(tmp_path / "s.gltf")
    assert back.local_translations is not None
    assert np.abs(back.positions - src.positions).max() < 1e-5


def _interp_file(tmp_path: Path, interp: str) -> Path:
    """A three-node chain whose samplers key at uneven times off any frame grid."""
    rng = np.random.default_rng(7)
    times = np.array([0.0, 0.013, 0.05, 0.051, 0.2, 0.33], dtype=np.float32)
    k = len(times)
    width = 3 if interp == "CUBICSPLINE" else 1
    q = rng.normal(size=(k * width, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    t = rng.normal(size=(k * width, 3)).astype(np.float32) * 0.2
    s = np.abs(rng.normal(size=(k * width, 1))).astype(np.float32).repeat(3, axis=1) + 0.5
    blobs = [times.tobytes(), q.tobytes(), t.tobytes(), s.tobytes()]
    views, off = [], 0
    for b in blobs:
        views.append({"buffer": 0, "byteOffset": off, "byteLength": len(b)})
        off += len(b)
    acc = [
        {"bufferView": 0, "componentType": 5126, "count": k, "type": "SCALAR", "min": [0.0], "max": [0.33]},
        {"bufferView": 1, "componentType": 5126, "count": k * width, "type": "VEC4"},
        {"bufferView": 2, "componentType": 5126, "count": k * width, "type": "VEC3"},
        {"bufferView": 3, "componentType": 5126, "count": k * width, "type": "VEC3"},
    ]
    doc = {
        "asset": {"version": "2.0"},
        "nodes": [
            {"name": "root", "children": [1], "translation": [0, 1, 0]},
            {"name": "mid", "children": [2], "translation": [0, 0.4, 0.1], "rotation": [0, 0.3826834, 0, 0.9238795]},
            {"name": "tip", "translation": [0.1, 0.3, 0]},
        ],
        "animations": [
            {
                "samplers": [
                    {"input": 0, "output": 1, "interpolation": interp},
                    {"input": 0, "output": 2, "interpolation": interp},
                    {"input": 0, "output": 3, "interpolation": interp},
                ],
                "channels": [
                    {"sampler": 0, "target": {"node": 1, "path": "rotation"}},
                    {"sampler": 1, "target": {"node": 0, "path": "translation"}},
                    {"sampler": 0, "target": {"node": 0, "path": "rotation"}},
                    {"sampler": 2, "target": {"node": 1, "path": "scale"}},
                ],
            }
        ],
        "accessors": acc,
        "bufferViews": views,
        "buffers": [{"byteLength": off, "uri": "chain.bin"}],
    }
    (tmp_path / "chain.bin").write_bytes(b"".join(blobs))
    p = tmp_path / "chain.gltf"
    p.write_text(json.dumps(doc))
    return p


@pytest.mark.parametrize("interp", ["LINEAR", "STEP", "CUBICSPLINE"])
def test_sampling_equals_the_slow_twin(tmp_path, interp):
    from naive.gltf import naive_gltf_positions

    p = _interp_file(tmp_path, interp)
    m = read_gltf(p, fps=100.0)
    times = m.metadata["start_time"] + np.arange(m.n_frames) / m.fps
    ref = naive_gltf_positions(p, times)
    for j, name in enumerate(m.skeleton.names):
        assert np.abs(m.positions[:, j] - ref[name]).max() < 1e-6, (interp, name)


def test_fps_from_key_spacing(tmp_path):
    src = read_amc(CMU / "02" / "02_01.amc").slice(0, 30)
    for fps in (24.0, 30000 / 1001, 120.0):
        write_gltf(src.with_arrays(fps=fps), tmp_path / "a.gltf")
        doc = json.loads((tmp_path / "a.gltf").read_text())
        del doc["animations"][0]["extras"]
        (tmp_path / "a.gltf").write_text(json.dumps(doc))
        m = read_gltf(tmp_path / "a.gltf")
        assert m.metadata["fps_source"] == "key times"
        assert m.fps == pytest.approx(fps, rel=1e-9) and m.n_frames == 30


def _mutants(data: bytes, rng: np.random.Generator, n: int):
    for i in range(n):
        kind = i % 4
        if kind == 0:
            yield data[: int(rng.integers(0, len(data)))]
        elif kind == 1:
            b = bytearray(data)
            for _ in range(int(rng.integers(1, 8))):
                b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
            yield bytes(b)
        elif kind == 2:
            at = int(rng.integers(0, len(data)))
            yield data[:at] + bytes(rng.integers(0, 256, int(rng.integers(1, 16)), dtype=np.uint8)) + data[at:]
        else:
            at = int(rng.integers(0, len(data) - 8))
            yield data[:at] + data[at + int(rng.integers(1, 64)) :]


@pytest.mark.parametrize("name", ["jump_60.glb", "walk_120.fbx"])
def test_malformed_files_raise_parse_errors(tmp_path, name):
    data = (BLENDER / name).read_bytes()
    rng = np.random.default_rng(0)
    target = tmp_path / name
    refused = 0
    for case in _mutants(data, rng, 60 if name.endswith(".fbx") else 120):
        target.write_bytes(case)
        try:
            m = mocapflow.read(target)
        except ParseError as exc:
            assert exc.path == str(target) and exc.message
            refused += 1
            continue
        assert np.all(np.isfinite(m.positions))
    assert refused > 10


def test_clear_errors(tmp_path):
    p = tmp_path / "a.gltf"
    p.write_text('{"asset": {"version": "2.0"}, "nodes": [{"name": "x"}]}')
    with pytest.raises(ParseError, match="expected at least one animation"):
        read_gltf(p)
    p.write_text('{"asset": {"version": "2.0"},\n "nodes": [}')
    with pytest.raises(ParseError, match="expected JSON") as e:
        read_gltf(p)
    assert e.value.line == 2
    src = read_amc(CMU / "02" / "02_01.amc").slice(0, 5)
    write_gltf(src, tmp_path / "b.gltf")
    doc = json.loads((tmp_path / "b.gltf").read_text())
    doc["buffers"][0]["uri"] = "missing.bin"
    (tmp_path / "b.gltf").write_text(json.dumps(doc))
    with pytest.raises(ParseError, match="missing.bin"):
        read_gltf(tmp_path / "b.gltf")
    f = tmp_path / "ascii.fbx"
    f.write_bytes(b"; FBX 7.4.0 project file\nFBXHeaderExtension:  {\n}\n")
    with pytest.raises(ParseError, match="ASCII FBX"):
        read_fbx(f)
    f.write_bytes(b"not an fbx at all")
    with pytest.raises(ParseError, match="binary FBX"):
        read_fbx(f)
