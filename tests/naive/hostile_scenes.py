"""Hostile glTF, GLB, FBX files and search-server requests, one per class of attack: the
generator shared by ``tests/plugins/formats/test_robust_readers.py`` (a test per class) and
``benchmarks/_hostile.py`` (the same classes timed, memory-traced and audited for files
opened outside the case's folder).

Each maker writes its case into an empty folder and returns a :class:`Case`: the file to
read and a regular expression the ParseError must match. Bases are built here: a glTF of
:func:`mocapflow.framework.synthetic.synthetic_motion` written by mocapflow (its buffer moved
to a ``.bin`` beside it when a case needs one), and binary FBX files re-serialized from the
Blender-made ``tests/data/blender/walk_120.fbx`` with a small record writer
(:func:`fbx_bytes`), so FBX cases need no FBX writer.
"""

from __future__ import annotations

import base64
import json
import os
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
WALK_FBX = ROOT / "tests" / "data" / "blender" / "walk_120.fbx"
MIB = 1 << 20


@dataclass
class Case:
    name: str
    path: Path
    expect: str  # regular expression the ParseError's message must match
    big: bool = False  # a large sparse file: benchmark only (and removed right after)


# --- glTF ----------------------------------------------------------------------------------
def gltf_doc(frames: int = 30) -> tuple[dict, bytes]:
    """A small valid glTF (JSON, buffer bytes) of a synthetic take."""
    import tempfile

    from mocapflow.framework.synthetic import synthetic_motion
    from mocapflow.plugins.formats.gltf import write_gltf

    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "a.gltf"
        write_gltf(synthetic_motion(frames, fps=30.0), p)
        doc = json.loads(p.read_text())
    buf = base64.b64decode(doc["buffers"][0]["uri"].split(",", 1)[1])
    return doc, buf


def write_gltf_case(folder: Path, doc: dict, buf: bytes | None = None, uri: str = "a.bin", name: str = "a") -> Path:
    """``doc`` as ``folder/name.gltf``; ``buf``: written to ``folder/uri`` (when a plain
    name) and referenced by buffer 0."""
    if buf is not None:
        doc["buffers"][0]["uri"] = uri
        if "/" not in uri and ":" not in uri:
            (folder / uri).write_bytes(buf)
    p = folder / f"{name}.gltf"
    p.write_text(json.dumps(doc))
    return p


def _uri_case(folder: Path, uri: str, expect: str) -> Case:
    doc, buf = gltf_doc()
    secret = folder.parent / "secret.bin"
    if not secret.exists():
        secret.write_bytes(buf)  # a file outside the case's folder, readable: it must not be read
    return Case(f"uri {uri[:40]}", write_gltf_case(folder, doc, buf, uri=uri), expect)


def uri_absolute(folder: Path) -> Case:
    return _uri_case(folder, str(folder.parent / "secret.bin"), "relative path inside the file's folder")


def uri_etc_passwd(folder: Path) -> Case:
    return _uri_case(folder, "/etc/passwd", "relative path inside the file's folder")


def uri_dotdot(folder: Path) -> Case:
    return _uri_case(folder, "../secret.bin", "relative path inside the file's folder")


def uri_percent_dotdot(folder: Path) -> Case:
    return _uri_case(folder, "sub/%2e%2e/%2E%2E/secret.bin", "relative path inside the file's folder")


def uri_file_scheme(folder: Path) -> Case:
    return _uri_case(folder, "file:///etc/passwd", "relative path inside the file's folder")


def uri_symlink_out(folder: Path) -> Case:
    case = _uri_case(folder, "link.bin", "outside the file's folder")
    (folder / "link.bin").unlink(missing_ok=True)
    (folder / "link.bin").symlink_to(folder.parent / "secret.bin")
    return case


def uri_symlink_dev_zero(folder: Path) -> Case:
    case = _uri_case(folder, "zero.bin", "outside the file's folder")
    (folder / "zero.bin").unlink(missing_ok=True)
    (folder / "zero.bin").symlink_to("/dev/zero")
    return case


def uri_symlinked_folder_out(folder: Path) -> Case:
    case = _uri_case(folder, "d/secret.bin", "outside the file's folder")
    (folder / "d").symlink_to(folder.parent, target_is_directory=True)
    return case


def uri_fifo(folder: Path) -> Case:
    case = _uri_case(folder, "pipe.bin", "not a regular file")
    (folder / "pipe.bin").unlink(missing_ok=True)
    os.mkfifo(folder / "pipe.bin")
    return case


def uri_folder(folder: Path) -> Case:
    case = _uri_case(folder, "sub", "not a regular file|outside")
    (folder / "sub").unlink(missing_ok=True)
    (folder / "sub").mkdir()
    return case


def uri_big_sidecar(folder: Path) -> Case:
    """A 1.5 GiB sparse .bin declared in full: over the per-file cap before any read."""
    doc, buf = gltf_doc()
    doc["buffers"][0]["byteLength"] = 3 * (1 << 29)
    p = write_gltf_case(folder, doc, buf)
    with open(folder / "a.bin", "r+b") as f:
        f.truncate(3 * (1 << 29))
    return Case("sidecar 1.5 GiB", p, "byteLength|MiB per file", big=True)


def data_uri_too_long(folder: Path) -> Case:
    doc, buf = gltf_doc()
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(buf * 200).decode()
    return Case("data URI over byteLength", write_gltf_case(folder, doc), "base64 characters")


def byte_length_huge(folder: Path) -> Case:
    doc, buf = gltf_doc()
    doc["buffers"][0]["byteLength"] = 1 << 40
    return Case("buffer byteLength 2^40", write_gltf_case(folder, doc, buf), "byteLength")


def accessor_negative_offset(folder: Path) -> Case:
    doc, buf = gltf_doc()
    k = doc["animations"][0]["samplers"][0]["output"]
    doc["accessors"][k]["byteOffset"] = -8
    return Case("accessor byteOffset -8", write_gltf_case(folder, doc, buf), "byteOffset.*>= 0")


def view_negative_offset(folder: Path) -> Case:
    doc, buf = gltf_doc()
    doc["bufferViews"][0]["byteOffset"] = -(1 << 62)
    return Case("bufferView byteOffset -2^62", write_gltf_case(folder, doc, buf), "byteOffset.*>= 0")


def view_past_buffer(folder: Path) -> Case:
    doc, buf = gltf_doc()
    k = doc["animations"][0]["samplers"][0]["output"]
    doc["bufferViews"][doc["accessors"][k]["bufferView"]]["byteLength"] = 1 << 62
    return Case("bufferView past its buffer", write_gltf_case(folder, doc, buf), "past its buffer")


def accessor_huge_zeros(folder: Path) -> Case:
    doc, buf = gltf_doc()
    k = doc["animations"][0]["samplers"][0]["output"]
    del doc["accessors"][k]["bufferView"]
    doc["accessors"][k]["count"] = 1 << 31
    return Case("accessor 2^31 zeros", write_gltf_case(folder, doc, buf), "without a bufferView")


def json_nested(folder: Path) -> Case:
    doc, buf = gltf_doc()
    text = json.dumps(doc)
    text = text[:-1] + ', "extras": ' + "[" * 100_000 + "]" * 100_000 + "}"
    p = folder / "a.gltf"
    p.write_text(text)
    return Case("JSON nested 100,000 deep", p, "nested more than")


def json_huge_int(folder: Path) -> Case:
    p = folder / "a.gltf"
    p.write_text('{"asset": {"version": "2.0"}, "extras": ' + "9" * 100_000 + "}")
    return Case("JSON integer of 100,000 digits", p, "expected JSON")


def node_chain(folder: Path, depth: int = 100_000) -> Case:
    doc, buf = gltf_doc()
    base = len(doc["nodes"])
    chain = [{"name": f"c{i}", "children": [base + i + 1]} for i in range(depth - 1)] + [{"name": "end"}]
    doc["nodes"] += chain
    doc["skins"][0]["joints"] = list(range(base, base + depth))
    return Case(f"node chain {depth:,} deep", write_gltf_case(folder, doc, buf), "ancestors")


def node_wide(folder: Path, n: int = 100_000) -> Case:
    """A root with ``n`` joint children: linear work, refused by the node-frame budget."""
    doc, buf = gltf_doc()
    base = len(doc["nodes"])
    doc["nodes"].append({"name": "hub", "children": list(range(base + 1, base + 1 + n))})
    doc["nodes"] += [{"name": f"leaf{i}"} for i in range(n)]
    doc["skins"][0]["joints"] = list(range(base, base + 1 + n))
    return Case(f"skin of {n:,} sibling joints", write_gltf_case(folder, doc, buf), "skeleton of")


def node_cycle(folder: Path) -> Case:
    doc, buf = gltf_doc()
    n = len(doc["nodes"])
    doc["nodes"] += [{"name": "x", "children": [n + 1]}, {"name": "y", "children": [n]}]
    return Case("node cycle", write_gltf_case(folder, doc, buf), "cycle|two parents")


def _far_key(doc: dict, buf: bytes, at: float) -> bytes:
    """The last key time of the input accessor of sampler 0 moved to ``at`` seconds."""
    acc = doc["accessors"][doc["animations"][0]["samplers"][0]["input"]]
    view = doc["bufferViews"][acc["bufferView"]]
    off = view.get("byteOffset", 0) + acc.get("byteOffset", 0) + 4 * (acc["count"] - 1)
    b = bytearray(buf)
    b[off : off + 4] = struct.pack("<f", at)
    acc["max"] = [at]
    return bytes(b)


def far_key_auto_fps(folder: Path) -> Case:
    doc, buf = gltf_doc(61)
    del doc["animations"][0]["extras"]
    buf = _far_key(doc, buf, 83_000.0)
    return Case("glTF far key, fps auto", write_gltf_case(folder, doc, buf), "far or corrupt key")


def far_key_given_rate(folder: Path) -> Case:
    doc, buf = gltf_doc(61)
    buf = _far_key(doc, buf, 83_000.0)
    return Case("glTF far key, extras.fps", write_gltf_case(folder, doc, buf), "far or corrupt key")


def glb_length_lies(folder: Path) -> Case:
    from mocapflow.framework.synthetic import synthetic_motion
    from mocapflow.plugins.formats.gltf import write_gltf

    p = folder / "a.glb"
    write_gltf(synthetic_motion(10), p)
    data = bytearray(p.read_bytes())
    data[8:12] = struct.pack("<I", 900 * MIB)
    p.write_bytes(bytes(data))
    return Case("GLB header length 900 MiB", p, "GLB header")


def huge_invalid(ext: str) -> Callable[[Path], Case]:
    """A 900 MiB sparse file of extension ``ext`` whose first byte is invalid."""

    def make(folder: Path) -> Case:
        p = folder / f"huge.{ext}"
        with open(p, "wb") as f:
            f.write(
                b"\x00" + {"gltf": b'{"asset": {}}', "glb": b"lTF", "fbx": b"Kaydara FBX Binary  \x00"}.get(ext, b"")
            )
            f.truncate(900 * MIB)
        return Case(f"900 MiB .{ext}, invalid first byte", p, "expected", big=True)

    return make


def huge_valid_head(ext: str) -> Callable[[Path], Case]:
    """A 900 MiB sparse file whose header is valid and whose body is zeros."""

    def make(folder: Path) -> Case:
        p = folder / f"huge_head.{ext}"
        size = 900 * MIB
        if ext == "glb":
            head = struct.pack("<III", 0x46546C67, 2, size) + struct.pack("<II", size - 20, 0x4E4F534A)
        elif ext == "gltf":
            head = b'{"asset": {"version": "2.0"}, "x": "'
        else:
            head = b"Kaydara FBX Binary  \x00\x1a\x00" + struct.pack("<I", 7400)
        with open(p, "wb") as f:
            f.write(head)
            f.truncate(size)
        return Case(f"900 MiB .{ext}, valid header, zero body", p, "expected|control byte|JSON chunk", big=True)

    return make


# --- FBX -----------------------------------------------------------------------------------
class Raw:
    """An FBX array property written as given: ``code``, declared element ``count``,
    encoding and payload bytes (a zlib bomb, a lying count)."""

    def __init__(self, code: bytes, count: int, enc: int, payload: bytes) -> None:
        self.code, self.count, self.enc, self.payload = code, count, enc, payload


_ARRAY_CODES = {np.dtype("<f4"): b"f", np.dtype("<f8"): b"d", np.dtype("<i8"): b"l", np.dtype("<i4"): b"i"}


def _prop(v) -> bytes:
    if isinstance(v, Raw):
        return v.code + struct.pack("<III", v.count, v.enc, len(v.payload)) + v.payload
    if isinstance(v, bool):
        return b"C" + struct.pack("<?", v)
    if isinstance(v, int):
        return b"L" + struct.pack("<q", v)
    if isinstance(v, float):
        return b"D" + struct.pack("<d", v)
    if isinstance(v, str):
        b = v.encode("utf-8")
        return b"S" + struct.pack("<I", len(b)) + b
    if isinstance(v, bytes):
        return b"R" + struct.pack("<I", len(v)) + v
    if isinstance(v, np.ndarray):
        a = np.ascontiguousarray(v)
        code = _ARRAY_CODES.get(a.dtype, b"b")
        raw = a.astype(np.uint8).tobytes() if code == b"b" else a.tobytes()
        return code + struct.pack("<III", len(a), 0, len(raw)) + raw
    raise TypeError(type(v))


def fbx_bytes(root, version: int = 7400) -> bytes:
    """A binary FBX file of a node tree (``root.children``; nodes of
    :mod:`mocapflow.plugins.formats._fbx_parse`). Ints become ``L``, floats ``D``; enough for
    the reader, which checks kinds, not widths."""
    wide = version >= 7500
    head = struct.Struct("<QQQB" if wide else "<IIIB")
    null = b"\x00" * head.size
    out = bytearray(b"Kaydara FBX Binary  \x00\x1a\x00" + struct.pack("<I", version))

    def node(n) -> None:
        start = len(out)
        props = b"".join(_prop(v) for v in n.props)
        name = n.name.encode("latin-1")
        out.extend(head.pack(0, len(n.props), len(props), len(name)) + name + props)
        if n.children:
            for c in n.children:
                node(c)
            out.extend(null)
        out[start : start + head.size] = head.pack(len(out), len(n.props), len(props), len(name))

    for c in root.children:
        node(c)
    out.extend(null)
    return bytes(out)


def walk_fbx():
    """(version, root) of the Blender-made FBX take."""
    from mocapflow.plugins.formats._fbx_parse import parse_fbx

    return parse_fbx(WALK_FBX, WALK_FBX.read_bytes())


def _curves(root) -> list:
    objects = next(c for c in root.children if c.name == "Objects")
    return [o for o in objects.children if o.name == "AnimationCurve"]


def fbx_roundtrip(folder: Path) -> Path:
    """The walk take re-serialized (must read as the original)."""
    _v, root = walk_fbx()
    p = folder / "walk.fbx"
    p.write_bytes(fbx_bytes(root))
    return p


def fbx_array_bomb(folder: Path) -> Case:
    """A KeyValueFloat array declaring 2^28 floats (1 GiB) in a small zlib stream."""
    _v, root = walk_fbx()
    curve = _curves(root)[0]
    kv = next(c for c in curve.children if c.name == "KeyValueFloat")
    stream = zlib.compressobj(9)
    payload = b"".join(stream.compress(bytes(1 << 24)) for _ in range(8)) + stream.flush()
    kv.props[0] = Raw(b"f", 1 << 28, 1, payload)
    p = folder / "bomb.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case("FBX array declaring 1 GiB", p, "inflate")


def fbx_array_longer_than_declared(folder: Path) -> Case:
    """A 60-float array whose zlib stream inflates to 128 MiB: stops at the declared length."""
    _v, root = walk_fbx()
    curve = _curves(root)[0]
    kv = next(c for c in curve.children if c.name == "KeyValueFloat")
    n = len(kv.props[0])
    stream = zlib.compressobj(9)
    payload = b"".join(stream.compress(bytes(1 << 24)) for _ in range(8)) + stream.flush()
    kv.props[0] = Raw(b"f", n, 1, payload)
    p = folder / "long.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case("FBX array inflating past its length", p, "array elements")


def fbx_many_bombs(folder: Path) -> Case:
    """Every curve's values declared at 2^23 floats (32 MiB each), in small zlib streams of
    exactly that length: the file's total inflation budget ends it."""
    _v, root = walk_fbx()
    payload = zlib.compress(bytes(4 << 23), 9)
    for curve in _curves(root):
        kv = next(c for c in curve.children if c.name == "KeyValueFloat")
        kv.props[0] = Raw(b"f", 1 << 23, 1, payload)
    p = folder / "bombs.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case("FBX arrays over the inflation budget", p, "inflate")


def fbx_far_key(folder: Path) -> Case:
    """One key time of one curve moved to +83,000 s, and the take's stop with it (a take
    span is the timeline the reader follows; keys past it are outside the take)."""
    _v, root = walk_fbx()
    curve = _curves(root)[0]
    kt = next(c for c in curve.children if c.name == "KeyTime")
    kt.props[0] = kt.props[0].copy()
    kt.props[0][-1] = 83_000 * 46_186_158_000
    objects = next(c for c in root.children if c.name == "Objects")
    stack = [n for n in objects.children if n.name == "AnimationStack"]
    for p70 in (c for n in stack for c in n.children if c.name == "Properties70"):
        for prop in p70.children:
            if prop.props and prop.props[0] in ("LocalStop", "ReferenceStop"):
                prop.props[-1] = 83_000 * 46_186_158_000
    p = folder / "far.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case("FBX key at +83,000 s", p, "far or corrupt key")


def fbx_float_key_times(folder: Path) -> Case:
    _v, root = walk_fbx()
    kt = next(c for c in _curves(root)[0].children if c.name == "KeyTime")
    kt.props[0] = np.full(len(kt.props[0]), np.nan)
    p = folder / "nan.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case("FBX NaN key times", p, "integer key times")


def fbx_model_chain(folder: Path, depth: int = 100_000) -> Case:
    """``depth`` LimbNode models, each the parent of the next."""
    from mocapflow.plugins.formats._fbx_parse import Node

    _v, root = walk_fbx()
    objects = next(c for c in root.children if c.name == "Objects")
    conns = next(c for c in root.children if c.name == "Connections")
    limb = next(o for o in objects.children if o.name == "Model" and o.props[2:3] == ["LimbNode"])
    base = 10**12
    conns.children.append(Node("C", ["OO", base, limb.props[0]], [], 0))
    for i in range(depth):
        objects.children.append(Node("Model", [base + i, f"c{i}\x00\x01Model", "LimbNode"], [], 0))
        if i:
            conns.children.append(Node("C", ["OO", base + i, base + i - 1], [], 0))
    p = folder / "chain.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case(f"FBX model chain {depth:,} deep", p, "ancestors|skeleton of")


def fbx_nested_records(folder: Path) -> Case:
    from mocapflow.plugins.formats._fbx_parse import Node

    _v, root = walk_fbx()
    n = Node("Deep", [], [], 0)
    top = n
    for _ in range(200):
        n.children.append(Node("Deep", [1], [], 0))
        n = n.children[0]
    root.children.append(top)
    p = folder / "nested.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case("FBX records nested 200 deep", p, "nested at most")


def fbx_record_flood(folder: Path, n: int = 600_000) -> Case:
    """``n`` tiny records inside a Model (a kind the reader parses): the record cap."""
    from mocapflow.plugins.formats._fbx_parse import Node

    _v, root = walk_fbx()
    objects = next(c for c in root.children if c.name == "Objects")
    model = next(o for o in objects.children if o.name == "Model")
    model.children.append(Node("X", [], [Node("P", [1], [], 0) for _ in range(n)], 0))
    p = folder / "flood.fbx"
    p.write_bytes(fbx_bytes(root))
    return Case(f"FBX {n:,} records in a model", p, "node records")


GLTF_CASES = [
    uri_absolute,
    uri_etc_passwd,
    uri_dotdot,
    uri_percent_dotdot,
    uri_file_scheme,
    uri_symlink_out,
    uri_symlink_dev_zero,
    uri_symlinked_folder_out,
    uri_fifo,
    uri_folder,
    data_uri_too_long,
    byte_length_huge,
    accessor_negative_offset,
    view_negative_offset,
    view_past_buffer,
    accessor_huge_zeros,
    json_nested,
    json_huge_int,
    node_chain,
    node_wide,
    node_cycle,
    far_key_auto_fps,
    far_key_given_rate,
    glb_length_lies,
]
FBX_CASES = [
    fbx_array_bomb,
    fbx_array_longer_than_declared,
    fbx_many_bombs,
    fbx_far_key,
    fbx_float_key_times,
    fbx_model_chain,
    fbx_nested_records,
    fbx_record_flood,
]
BIG_CASES = (
    [uri_big_sidecar]
    + [f(ext) for ext in ("gltf", "glb", "fbx", "bvh", "trc", "amc", "c3d") for f in (huge_invalid,)]
    + [huge_valid_head(ext) for ext in ("gltf", "glb", "fbx")]
)


# --- search server requests ----------------------------------------------------------------
def server_requests() -> list[tuple[str, bytes, bool]]:
    """Hostile requests ``(name, bytes, valid)``: an invalid one must be a ConfigError
    (never another exception), a valid one (brackets inside a string) parsed."""
    ok = json.dumps({"args": {"query": "q.bvh"}, "cwd": "/"})
    return [
        ("nested 100,000 arrays", b"[" * 100_000 + b"]" * 100_000, False),
        ("nested 100,000 objects", b'{"a":' * 100_000 + b"1" + b"}" * 100_000, False),
        ("nested in args", ok[:-1].encode() + b', "x": ' + b"[" * 50_000 + b"]" * 50_000 + b"}", False),
        ("integer of 100,000 digits", b'{"args": {"k": ' + b"9" * 100_000 + b'}, "cwd": "/"}', False),
        ("not UTF-8", b'{"args": {"query": "\xff"}, "cwd": "/"}', False),
        ("unterminated string", b'{"args": {"query": "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[', False),
        ("brackets in strings", json.dumps({"args": {"query": "[" * 100_000}, "cwd": "/"}).encode(), True),
    ]
