"""glTF 2.0 / GLB writer (see :mod:`mocapflow.plugins.formats.gltf` for the conventions)."""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.motion import Motion


class _Buffer:
    """One binary buffer with its views and accessors."""

    def __init__(self) -> None:
        self.parts: list[bytes] = []
        self.size = 0
        self.views: list[dict[str, Any]] = []
        self.accessors: list[dict[str, Any]] = []

    def add(self, arr: np.ndarray, kind: str, minmax: bool = False) -> int:
        a = np.ascontiguousarray(arr, dtype="<f4")
        raw = a.tobytes()
        self.views.append({"buffer": 0, "byteOffset": self.size, "byteLength": len(raw)})
        self.parts.append(raw)
        self.size += len(raw)  # float32 data: every view stays 4-byte aligned
        acc = {"bufferView": len(self.views) - 1, "componentType": 5126, "count": int(a.shape[0]), "type": kind}
        if minmax:
            flat = a.reshape(a.shape[0], -1)
            acc["min"] = flat.min(axis=0).tolist()
            acc["max"] = flat.max(axis=0).tolist()
        self.accessors.append(acc)
        return len(self.accessors) - 1


def _xyzw(q: np.ndarray) -> np.ndarray:
    return q[..., [1, 2, 3, 0]]


def write_gltf(motion: Motion, path: str | Path, binary: bool | None = None) -> None:
    """Write a motion as glTF 2.0 (``binary``: GLB container; default from the suffix,
    ``.glb``). Nodes: one per joint, rest rotations from ``Skeleton.meta["rest_rotations"]``
    when the skeleton came from glTF/FBX (identity otherwise); one skin over them; one
    ``LINEAR`` animation sampled at ``motion.fps`` with ``extras.fps``."""
    path = Path(path)
    binary = path.suffix.lower() == ".glb" if binary is None else binary
    sk = motion.skeleton
    nj, n = sk.n_joints, motion.n_frames
    rest = sk.meta.get("rest_rotations")
    wrest = (
        quat.normalize(np.asarray(rest, dtype=float)) if rest is not None and len(rest) == nj else quat.identity((nj,))
    )
    par = sk.parents
    wpar = np.array([wrest[p] if p >= 0 else quat.identity() for p in par])
    # file-local values: r = Wrest_p^-1 r' Wrest_j, t = Wrest_p^-1 offset (module doc of _nodes)
    rot = quat.mul(quat.mul(quat.conjugate(wpar)[None], motion.rotations), wrest[None])
    rot = quat.make_continuous(rot)
    trans = quat.rotate(quat.conjugate(wpar), sk.offsets)
    rest_local = quat.mul(quat.conjugate(wpar), wrest)
    rest_world = np.zeros((nj, 3))
    for j in range(1, nj):
        rest_world[j] = rest_world[par[j]] + sk.offsets[j]
    rest_world += motion.root_translation[0]
    buf = _Buffer()
    times = np.arange(n, dtype=np.float64) / motion.fps
    t_acc = buf.add(times[:, None], "SCALAR", minmax=True)
    samplers: list[dict[str, Any]] = []
    channels: list[dict[str, Any]] = []

    def channel(node: int, what: str, values: np.ndarray, kind: str) -> None:
        samplers.append({"input": t_acc, "output": buf.add(values, kind), "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": what}})

    channel(0, "translation", motion.root_translation, "VEC3")
    lt = motion.local_translations
    for j in range(nj):
        channel(j, "rotation", _xyzw(rot[:, j]), "VEC4")
        if j > 0 and lt is not None and np.abs(lt[:, j] - sk.offsets[j]).max() > 0:
            channel(j, "translation", quat.rotate(quat.conjugate(wpar[j]), lt[:, j]), "VEC3")
    ibm = np.zeros((nj, 4, 4))
    m = np.zeros((nj, 4, 4))
    m[:, :3, :3] = quat.to_matrix(wrest)
    m[:, :3, 3] = rest_world
    m[:, 3, 3] = 1.0
    ibm[:] = np.linalg.inv(m)
    ibm_acc = buf.add(ibm.transpose(0, 2, 1).reshape(nj, 16), "MAT4")  # column-major
    nodes = []
    for j in range(nj):
        node: dict[str, Any] = {"name": sk.names[j]}
        kids = sk.children(j)
        if kids:
            node["children"] = kids
        node["translation"] = (motion.root_translation[0] if j == 0 else trans[j]).tolist()
        node["rotation"] = _xyzw(rest_local[j]).tolist()
        nodes.append(node)
    doc: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "mocapflow"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "skins": [{"joints": list(range(nj)), "skeleton": 0, "inverseBindMatrices": ibm_acc}],
        "animations": [
            {"name": motion.name or "motion", "channels": channels, "samplers": samplers, "extras": {"fps": motion.fps}}
        ],
        "accessors": buf.accessors,
        "bufferViews": buf.views,
        "buffers": [{"byteLength": buf.size}],
    }
    blob = b"".join(buf.parts)
    if not binary:
        from mocapflow.framework.errors import DataError

        from ._common import MAX_GLB_JSON

        if 4 * len(blob) // 3 + 4096 + 64 * len(nodes) > MAX_GLB_JSON:  # before anything is written
            raise DataError(
                f"{motion.name or 'the motion'}: {len(blob) / 2**20:,.1f} MiB of animation data is too much to embed "
                f"in a .gltf (readers take at most {MAX_GLB_JSON >> 20} MiB of JSON): write a .glb"
            )
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
        path.write_text(json.dumps(doc, separators=(",", ":")), encoding="utf-8")
        return
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    with path.open("wb") as fh:
        fh.write(struct.pack("<III", 0x46546C67, 2, total))
        fh.write(struct.pack("<II", len(text), 0x4E4F534A) + text)
        fh.write(struct.pack("<II", len(blob), 0x004E4942) + blob)
