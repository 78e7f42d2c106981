"""Slow, obviously correct glTF evaluation: the twin of ``plugins/formats/gltf.py``.

Values are unpacked one by one with ``struct``, each channel is evaluated at each time by
scanning its keys, and every node's world matrix is the product of 4x4 ``T @ R @ S``
matrices from the scene root down (the glTF specification's own definitions).
"""

from __future__ import annotations

import base64
import json
import math
import struct
from pathlib import Path

import numpy as np

_FMT = {
    5120: ("b", 127.0),
    5121: ("B", 255.0),
    5122: ("h", 32767.0),
    5123: ("H", 65535.0),
    5125: ("I", None),
    5126: ("f", None),
}
_N = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def _load(path: Path) -> tuple[dict, list[bytes]]:
    data = path.read_bytes()
    binchunk = b""
    if data[:4] == b"glTF":
        n = struct.unpack_from("<I", data, 12)[0]
        doc = json.loads(data[20 : 20 + n])
        pos = 20 + n
        if pos < len(data):
            m = struct.unpack_from("<I", data, pos)[0]
            binchunk = data[pos + 8 : pos + 8 + m]
    else:
        doc = json.loads(data)
    bufs = []
    for b in doc.get("buffers", []):
        uri = b.get("uri")
        if uri is None:
            bufs.append(binchunk)
        elif uri.startswith("data:"):
            bufs.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            bufs.append((path.parent / uri).read_bytes())
    return doc, bufs


def _accessor(doc: dict, bufs: list[bytes], i: int) -> list[list[float]]:
    a = doc["accessors"][i]
    code, norm = _FMT[a["componentType"]]
    n = _N[a["type"]]
    size = struct.calcsize("<" + code)
    if "bufferView" not in a:
        return [[0.0] * n for _ in range(a["count"])]
    bv = doc["bufferViews"][a["bufferView"]]
    buf = bufs[bv["buffer"]]
    stride = bv.get("byteStride") or size * n
    out = []
    for k in range(a["count"]):
        base = bv.get("byteOffset", 0) + a.get("byteOffset", 0) + k * stride
        row = [struct.unpack_from("<" + code, buf, base + c * size)[0] for c in range(n)]
        if a.get("normalized") and norm:
            row = [max(v / norm, -1.0) for v in row]
        out.append([float(v) for v in row])
    return out


def _slerp(a: list[float], b: list[float], u: float) -> list[float]:
    d = sum(x * y for x, y in zip(a, b, strict=True))
    if d < 0:
        b, d = [-x for x in b], -d
    if d > 1 - 1e-12:
        q = [x + u * (y - x) for x, y in zip(a, b, strict=True)]
    else:
        th = math.acos(min(d, 1.0))
        wa, wb = math.sin((1 - u) * th) / math.sin(th), math.sin(u * th) / math.sin(th)
        q = [wa * x + wb * y for x, y in zip(a, b, strict=True)]
    n = math.sqrt(sum(x * x for x in q))
    return [x / n for x in q]


def _evaluate(times: list[float], vals: list[list[float]], interp: str, t: float, rotation: bool) -> list[float]:
    k = len(times)
    cubic = interp == "CUBICSPLINE"
    v = (lambda i: vals[3 * i + 1]) if cubic else (lambda i: vals[i])
    if t <= times[0] or k == 1:
        return list(v(0)) if not rotation else _norm(v(0))
    if t >= times[-1]:
        return list(v(k - 1)) if not rotation else _norm(v(k - 1))
    i = 0
    while times[i + 1] <= t:
        i += 1
    dt = times[i + 1] - times[i]
    u = (t - times[i]) / dt
    if interp == "STEP":
        return list(v(i))
    if cubic:
        b0, a1 = vals[3 * i + 2], vals[3 * (i + 1)]
        h = (2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2)
        out = [
            h[0] * p0 + h[1] * dt * m0 + h[2] * p1 + h[3] * dt * m1
            for p0, m0, p1, m1 in zip(v(i), b0, v(i + 1), a1, strict=True)
        ]
        return _norm(out) if rotation else out
    if rotation:
        return _slerp(v(i), v(i + 1), u)
    return [x + u * (y - x) for x, y in zip(v(i), v(i + 1), strict=True)]


def _norm(q: list[float]) -> list[float]:
    n = math.sqrt(sum(x * x for x in q))
    return [x / n for x in q]


def _matrix(t: list[float], q: list[float], s: list[float]) -> np.ndarray:
    x, y, z, w = q
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = r @ np.diag(s)
    m[:3, 3] = t
    return m


def naive_gltf_positions(path: Path, times: np.ndarray, animation: int = 0) -> dict[str, np.ndarray]:
    """World position (len(times), 3) of every named node at each time (seconds)."""
    doc, bufs = _load(Path(path))
    nodes = doc["nodes"]
    anim = doc["animations"][animation]
    chans = []
    for ch in anim["channels"]:
        tgt = ch["target"]
        if tgt.get("path") not in ("translation", "rotation", "scale") or "node" not in tgt:
            continue
        smp = anim["samplers"][ch["sampler"]]
        ts = [r[0] for r in _accessor(doc, bufs, smp["input"])]
        vs = _accessor(doc, bufs, smp["output"])
        chans.append((tgt["node"], tgt["path"], smp.get("interpolation", "LINEAR"), ts, vs))
    parent = {c: i for i, nd in enumerate(nodes) for c in nd.get("children", [])}
    out = {nd.get("name", f"node{i}"): np.zeros((len(times), 3)) for i, nd in enumerate(nodes)}
    for f, t in enumerate(times):
        local = []
        for i, nd in enumerate(nodes):
            if "matrix" in nd:
                local.append(np.array(nd["matrix"], dtype=float).reshape(4, 4).T)
                continue
            trs = {
                "translation": nd.get("translation", [0, 0, 0]),
                "rotation": nd.get("rotation", [0, 0, 0, 1]),
                "scale": nd.get("scale", [1, 1, 1]),
            }
            for node, what, interp, ts, vs in chans:
                if node == i:
                    trs[what] = _evaluate(ts, vs, interp, float(t), what == "rotation")
            local.append(_matrix(trs["translation"], trs["rotation"], trs["scale"]))
        for i, nd in enumerate(nodes):
            m, k = local[i], i
            while k in parent:
                k = parent[k]
                m = local[k] @ m
            out[nd.get("name", f"node{i}")][f] = m[:3, 3]
    return out
