"""Compact binary data files for the report's player, loadable from ``file://``.

Browsers refuse ``fetch``/XHR of local files for a page opened from ``file://``, but they run
``<script src>`` files. Each data file is therefore a one-line script that hands a
base64-encoded binary blob to the page::

    MocapReport.blob("m/motions/3", {"parts": [...], ...}, "AAAA...");

The blob is a concatenation of little-endian arrays (``parts``: name, dtype, shape, byte
offset; each part starts on a 4-byte boundary so the page views it without copying).
Joint positions are stored as the root's world position (float32, metres) plus each joint's
offset from the root quantised to int16 with one scale per clip (``scale`` metres per unit;
resolution better than 0.1 mm for a body 3 m across), NaN (a joint the skeleton lacks) as
-32768: a 10-minute take at 30 fps (18 000 frames x 25 joints) is 2.9 MB, 3.8 MB as base64.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

#: int16 value standing for NaN (a joint the source skeleton lacks).
NAN_CODE = -32768
_DTYPES = {"float32": "<f4", "int16": "<i2", "uint8": "u1", "int32": "<i4", "uint16": "<u2"}


def encode_positions(positions: np.ndarray) -> tuple[dict[str, np.ndarray], float]:
    """Split canonical positions (T, J, 3) in metres (joint 0 the root, NaN where absent) into
    ``parts`` ``root`` float32 (T, 3) and ``rel`` int16 (T, J, 3) offsets, and ``scale``, the
    metres per int16 unit of ``rel``."""
    pos = np.asarray(positions, np.float64)
    root = np.nan_to_num(pos[:, 0, :]).astype(np.float32)
    rel = pos - root[:, None, :].astype(np.float64)
    finite = np.isfinite(rel)
    extent = float(np.abs(rel[finite]).max()) if finite.any() else 1.0
    scale = max(extent, 1e-6) / 32767.0
    q = np.full(rel.shape, NAN_CODE, np.int16)
    q[finite] = np.clip(np.rint(rel[finite] / scale), -32767, 32767).astype(np.int16)
    # a joint is absent as a whole: any NaN coordinate marks all three
    q[(~finite).any(axis=-1)] = NAN_CODE
    return {"root": root, "rel": q}, scale


def decode_positions(root: np.ndarray, rel: np.ndarray, scale: float) -> np.ndarray:
    """Inverse of :func:`encode_positions` (what the page computes), shape (T, J, 3)."""
    out = root[:, None, :].astype(np.float64) + rel.astype(np.float64) * scale
    out[(rel == NAN_CODE).any(axis=-1)] = np.nan
    return out


def pack(parts: Mapping[str, np.ndarray]) -> tuple[bytes, list[dict[str, Any]]]:
    """Concatenate arrays on 4-byte boundaries; returns the bytes and the part table."""
    chunks, table, offset = [], [], 0
    for name, arr in parts.items():
        arr = np.asarray(arr)
        dtype = next((k for k, v in _DTYPES.items() if np.dtype(v) == arr.dtype.newbyteorder("<")), None)
        if dtype is None:
            raise TypeError(f"part {name!r}: unsupported dtype {arr.dtype}")
        data = np.ascontiguousarray(arr, dtype=_DTYPES[dtype]).tobytes()
        table.append({"name": name, "dtype": dtype, "shape": list(arr.shape), "offset": offset})
        pad = (-len(data)) % 4
        chunks.append(data + b"\0" * pad)
        offset += len(data) + pad
    return b"".join(chunks), table


def unpack(blob: bytes, table: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack`."""
    out = {}
    for p in table:
        dt = np.dtype(_DTYPES[p["dtype"]])
        n = int(np.prod(p["shape"], dtype=np.int64))
        out[p["name"]] = np.frombuffer(blob, dt, count=n, offset=p["offset"]).reshape(p["shape"])
    return out


def write_blob(path: Path, key: str, meta: Mapping[str, Any], parts: Mapping[str, np.ndarray]) -> int:
    """Write one data script (see the module docstring); returns its size in bytes."""
    blob, table = pack(parts)
    head = json.dumps({**meta, "parts": table}, separators=(",", ":"), allow_nan=False)
    text = f'MocapReport.blob({json.dumps(key)},{head},"{base64.b64encode(blob).decode("ascii")}");\n'
    path.write_text(text, encoding="ascii")
    return len(text)


def read_blob(path: Path) -> tuple[str, dict[str, Any], dict[str, np.ndarray]]:
    """Parse a data script written by :func:`write_blob` (tests, tools): key, meta, parts."""
    text = Path(path).read_text(encoding="ascii").strip()
    prefix = "MocapReport.blob("
    if not (text.startswith(prefix) and text.endswith(");")):
        raise ValueError(f"{path}: not a report data script")
    key, meta, b64 = json.loads("[" + text[len(prefix) : -2] + "]")
    return key, meta, unpack(base64.b64decode(b64), meta["parts"])
