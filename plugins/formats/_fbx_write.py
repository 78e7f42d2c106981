"""Binary FBX 7.4 writer: a skeleton of ``LimbNode`` models and its baked animation.

* **Container**: FBX binary 7400 (32-bit record offsets; arrays zlib-compressed), the
  header records (``FBXHeaderExtension``, ``FileId``, ``CreationTime``, ``Creator``),
  ``GlobalSettings``, ``Documents``, ``References``, ``Definitions``, ``Objects``,
  ``Connections``, ``Takes`` and the usual footer.
* **Scene**: y up, front +z, right-handed (mocapflow's axes: the reader maps them back to
  themselves), centimetres (``UnitScaleFactor`` 1); ``TimeMode`` 14 with
  ``CustomFrameRate`` the motion's rate; one ``AnimationStack`` / ``AnimationLayer`` spanning
  the frames.
* **Skeleton**: one ``Model`` (``LimbNode``, with a ``Skeleton`` node attribute) per joint,
  parented as the skeleton; rest rotations identity (mocapflow's convention; Blender
  builds its bones from the rest pose, and a bone rotated at rest comes back up to
  0.2 mm off along a 2.7 m walk, its bone-roll arithmetic being float32), so
  ``Lcl Translation`` is the joint's offset (or the root translation) and ``Lcl Rotation``
  its local rotation as ``RotationOrder`` 0 (XYZ: ``Rz Ry Rx``) Euler angles in degrees,
  continuous along time (:mod:`._euler_branch`).
* **Animation**: every frame keyed (``KeyTime`` in KTime ticks, ``k / fps`` seconds;
  linear keys): root translation, every joint's rotation, and the translations of joints
  whose ``local_translations`` move.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.motion import Motion

from . import _euler_branch as euler_branch

KTIME = 46_186_158_000
VERSION = 7400
_HEAD = b"Kaydara FBX Binary  \x00\x1a\x00"
_FOOT_ID = bytes.fromhex("fabcab09d0c8d466b176fb831cf7267e")
_FOOT_MAGIC = bytes.fromhex("f85a8c6adef5d97eece90ce3758f290b")
_NULL = b"\x00" * 13
_LINEAR = 0x4 | 0x100  # linear interpolation, auto tangent bits as exporters write them
CM = 100.0  # file units (cm) per metre


class _N:
    """A record: name, properties, children."""

    __slots__ = ("name", "props", "kids")

    def __init__(self, name: str, *props: Any, kids: list[_N] | None = None) -> None:
        self.name, self.props, self.kids = name, props, kids or []

    def add(self, name: str, *props: Any) -> _N:
        n = _N(name, *props)
        self.kids.append(n)
        return n


class _Raw(bytes):
    """A property written with type code ``R`` (raw bytes)."""


class _Int16(int):
    """A property written with type code ``Y``."""


class _Int32(int):
    """A property written with type code ``I``."""


def _prop(v: Any) -> bytes:
    if isinstance(v, bool):
        return b"C" + struct.pack("<?", v)
    if isinstance(v, _Int16):
        return b"Y" + struct.pack("<h", v)
    if isinstance(v, _Int32):
        return b"I" + struct.pack("<i", v)
    if isinstance(v, int):
        return b"L" + struct.pack("<q", v)
    if isinstance(v, float):
        return b"D" + struct.pack("<d", v)
    if isinstance(v, _Raw):
        return b"R" + struct.pack("<I", len(v)) + bytes(v)
    if isinstance(v, str):
        b = v.encode("utf-8")
        return b"S" + struct.pack("<I", len(b)) + b
    if isinstance(v, np.ndarray):
        code = {np.dtype("float32"): b"f", np.dtype("float64"): b"d", np.dtype("int64"): b"l", np.dtype("int32"): b"i"}[
            v.dtype
        ]
        raw = np.ascontiguousarray(v).astype(v.dtype.newbyteorder("<")).tobytes()
        packed = zlib.compress(raw)
        return code + struct.pack("<III", len(v), 1, len(packed)) + packed
    raise TypeError(f"cannot write {type(v).__name__} as an FBX property")


def _record(n: _N, offset: int) -> bytes:
    props = b"".join(_prop(p) for p in n.props)
    name = n.name.encode("ascii")
    start = offset + 13 + len(name) + len(props)
    body = bytearray()
    for k in n.kids:
        body += _record(k, start + len(body))
    if n.kids or not n.props:
        body += _NULL
    end = start + len(body)
    return struct.pack("<IIIB", end, len(n.props), len(props), len(name)) + name + props + bytes(body)


def _p70(*entries: tuple[Any, ...]) -> _N:
    p = _N("Properties70")
    for e in entries:
        p.add("P", *e)
    return p


def _euler_xyz(q: np.ndarray) -> np.ndarray:
    """FBX ``eEulerXYZ`` angles (degrees, x applied first: ``Rz Ry Rx``) of quaternions."""
    return quat.to_euler(q, "zyx")[..., ::-1]


def fbx_bytes(motion: Motion) -> bytes:
    """The FBX 7.4 binary file of a motion (module doc)."""
    sk = motion.skeleton
    nj, n = sk.n_joints, motion.n_frames
    fps = float(motion.fps)
    ticks = np.round(np.arange(n) * (KTIME / fps)).astype(np.int64)
    stop = int(ticks[-1]) if n else 0
    ids = iter(range(1_000_000, 10**12))
    model_ids = [next(ids) for _ in range(nj)]
    objects = _N("Objects")
    conns = _N("Connections")
    lt = motion.local_translations
    stack_id, layer_id = next(ids), next(ids)
    stack = objects.add("AnimationStack", stack_id, "Take 001\x00\x01AnimStack", "")
    stack.kids.append(
        _p70(
            ("LocalStart", "KTime", "Time", "", 0),
            ("LocalStop", "KTime", "Time", "", stop),
            ("ReferenceStart", "KTime", "Time", "", 0),
            ("ReferenceStop", "KTime", "Time", "", stop),
        )
    )
    objects.add("AnimationLayer", layer_id, "BaseLayer\x00\x01AnimLayer", "")
    conns.add("C", "OO", layer_id, stack_id)
    n_curves = n_nodes = 0

    def animate(model: int, prop: str, tag: str, values: np.ndarray) -> None:
        nonlocal n_curves, n_nodes
        cn = next(ids)
        node = objects.add("AnimationCurveNode", cn, f"{tag}\x00\x01AnimCurveNode", "")
        node.kids.append(_p70(*((f"d|{a}", "Number", "", "A", float(values[0, k])) for k, a in enumerate("XYZ"))))
        conns.add("C", "OO", cn, layer_id)
        conns.add("C", "OP", cn, model, prop)
        n_nodes += 1
        for k, a in enumerate("XYZ"):
            cid = next(ids)
            c = objects.add("AnimationCurve", cid, "\x00\x01AnimCurve", "")
            c.add("Default", float(values[0, k]))
            c.add("KeyVer", _Int32(4009))
            c.add("KeyTime", ticks)
            c.add("KeyValueFloat", values[:, k].astype(np.float32))
            c.add("KeyAttrFlags", np.array([_LINEAR], dtype=np.int32))
            c.add("KeyAttrDataFloat", np.zeros(4, dtype=np.float32))
            c.add("KeyAttrRefCount", np.array([n], dtype=np.int32))
            conns.add("C", "OP", cid, cn, f"d|{a}")
            n_curves += 1

    for j in range(nj):
        name = sk.names[j]
        p = int(sk.parents[j])
        rot = euler_branch.apply(_euler_xyz(motion.rotations[:, j]), name, [], {}, fps)
        if j == 0:
            trans = motion.root_translation * CM
        elif lt is not None:
            trans = lt[:, j] * CM
        else:
            trans = np.broadcast_to(sk.offsets[j] * CM, (n, 3))
        moves = j == 0 or np.ptp(trans, axis=0).max(initial=0.0) > 0
        attr = next(ids)
        na = objects.add("NodeAttribute", attr, f"{name}\x00\x01NodeAttribute", "LimbNode")
        na.kids.append(_p70(("Size", "double", "Number", "", 10.0)))
        na.add("TypeFlags", "Skeleton")
        m = objects.add("Model", model_ids[j], f"{name}\x00\x01Model", "LimbNode")
        m.add("Version", _Int32(232))
        m.kids.append(
            _p70(
                ("RotationOrder", "enum", "", "", _Int32(0)),
                ("RotationActive", "bool", "", "", _Int32(1)),
                ("InheritType", "enum", "", "", _Int32(1)),
                ("DefaultAttributeIndex", "int", "Integer", "", _Int32(0)),
                ("Lcl Translation", "Lcl Translation", "", "A", *map(float, trans[0])),
                ("Lcl Rotation", "Lcl Rotation", "", "A", 0.0, 0.0, 0.0),
                ("Lcl Scaling", "Lcl Scaling", "", "A", 1.0, 1.0, 1.0),
            )
        )
        m.add("Shading", True)
        m.add("Culling", "CullingOff")
        conns.add("C", "OO", attr, model_ids[j])
        conns.add("C", "OO", model_ids[j], model_ids[p] if p >= 0 else 0)
        if moves:
            animate(model_ids[j], "Lcl Translation", "T", np.asarray(trans))
        animate(model_ids[j], "Lcl Rotation", "R", rot)
    counts = {
        "GlobalSettings": 1,
        "Model": nj,
        "NodeAttribute": nj,
        "AnimationStack": 1,
        "AnimationLayer": 1,
        "AnimationCurveNode": n_nodes,
        "AnimationCurve": n_curves,
    }
    defs = _N("Definitions")
    defs.add("Version", _Int32(100))
    defs.add("Count", _Int32(sum(counts.values())))
    for kind, cnt in counts.items():
        ot = defs.add("ObjectType", kind)
        ot.add("Count", _Int32(cnt))
    header = _N("FBXHeaderExtension")
    header.add("FBXHeaderVersion", _Int32(1003))
    header.add("FBXVersion", _Int32(VERSION))
    header.add("EncryptionType", _Int32(0))
    ts = header.add("CreationTimeStamp")
    for key, val in (("Version", 1000), ("Year", 2026), ("Month", 1), ("Day", 1), ("Hour", 0), ("Minute", 0)):
        ts.add(key, _Int32(val))
    ts.add("Second", _Int32(0))
    ts.add("Millisecond", _Int32(0))
    header.add("Creator", "mocapflow")
    settings = _N("GlobalSettings")
    settings.add("Version", _Int32(1000))
    settings.kids.append(
        _p70(
            ("UpAxis", "int", "Integer", "", _Int32(1)),
            ("UpAxisSign", "int", "Integer", "", _Int32(1)),
            ("FrontAxis", "int", "Integer", "", _Int32(2)),
            ("FrontAxisSign", "int", "Integer", "", _Int32(1)),
            ("CoordAxis", "int", "Integer", "", _Int32(0)),
            ("CoordAxisSign", "int", "Integer", "", _Int32(1)),
            ("OriginalUpAxis", "int", "Integer", "", _Int32(1)),
            ("OriginalUpAxisSign", "int", "Integer", "", _Int32(1)),
            ("UnitScaleFactor", "double", "Number", "", 1.0),
            ("OriginalUnitScaleFactor", "double", "Number", "", 1.0),
            ("TimeMode", "enum", "", "", _Int32(14)),
            ("TimeSpanStart", "KTime", "Time", "", 0),
            ("TimeSpanStop", "KTime", "Time", "", stop),
            ("CustomFrameRate", "double", "Number", "", fps),
        )
    )
    docs = _N("Documents")
    docs.add("Count", _Int32(1))
    doc = docs.add("Document", next(ids), "", "Scene")
    doc.add("RootNode", 0)
    takes = _N("Takes")
    takes.add("Current", "Take 001")
    take = takes.add("Take", "Take 001")
    take.add("FileName", "Take_001.tak")
    take.add("LocalTime", 0, stop)
    take.add("ReferenceTime", 0, stop)
    top = [
        header,
        _N("FileId", _Raw(_FOOT_ID[::-1])),
        _N("CreationTime", "1970-01-01 10:00:00:000"),
        _N("Creator", "mocapflow"),
        settings,
        docs,
        _N("References"),
        defs,
        objects,
        conns,
        takes,
    ]
    out = bytearray(_HEAD + struct.pack("<I", VERSION))
    for node in top:
        out += _record(node, len(out))
    out += _NULL
    out += _FOOT_ID
    out += b"\x00" * ((16 - len(out) % 16) % 16 or 16)
    out += b"\x00" * 4 + struct.pack("<I", VERSION) + b"\x00" * 120 + _FOOT_MAGIC
    return bytes(out)


def write_fbx(motion: Motion, path: str | Path) -> None:
    """Write a motion as binary FBX 7.4 (module doc)."""
    Path(path).write_bytes(fbx_bytes(motion))
