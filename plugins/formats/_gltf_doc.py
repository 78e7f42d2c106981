"""The glTF document as the reader sees it: the GLB container or JSON text checked at its
head (and its size) before the body is read, the JSON parsed with a depth bound, and the
buffers, buffer views and accessors it declares checked against each other and against the
file before any array is made (:class:`_Doc`)."""

from __future__ import annotations

import base64
import binascii
import json
import struct
from pathlib import Path
from typing import Any, cast

import numpy as np

from mocapflow.framework.bounded_json import JsonDepthError
from mocapflow.framework.bounded_json import loads as bounded_loads
from mocapflow.framework.errors import ParseError

from . import _common
from ._common import MAX_GLB_JSON, read_sidecar

_COMPONENTS: dict[int, tuple[str, float | None]] = {
    5120: ("<i1", 127.0),
    5121: ("<u1", 255.0),
    5122: ("<i2", 32767.0),
    5123: ("<u2", 65535.0),
    5125: ("<u4", None),
    5126: ("<f4", None),
}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_PATHS = {"translation": 3, "rotation": 4, "scale": 3}
_GLB_MAGIC, _JSON_CHUNK, _BIN_CHUNK = 0x46546C67, 0x4E4F534A, 0x004E4942
#: Largest |value| accepted in node transforms and accessors (metres, seconds, factors):
#: above any real scene, below the overflow of the products that follow.
_MAX_VALUE = 1.0e7
#: Deepest JSON nesting of a glTF document (the format nests < 10 levels).
MAX_JSON_DEPTH = 64
#: Most nodes in a document, and the deepest node hierarchy (a skeleton is < 100 deep).
MAX_NODES = 1_000_000
MAX_NODE_DEPTH = 1_000
#: Elements of an accessor without a bufferView (all zeros by the specification).
MAX_ZERO_ELEMENTS = 1 << 20


def _check_head(path: Path, head: bytes, size: int) -> None:
    """glTF/GLB header check on the file's first bytes (``size``: the file's size): a GLB
    container's magic, version, total length and first chunk, or the start of a JSON object
    (no control bytes in the head): anything else is refused before the body is read."""
    if head[:4] == b"glTF":
        if len(head) < 20:
            raise ParseError(path, None, f"expected a 12-byte GLB header and a JSON chunk, found {len(head)} bytes")
        _magic, version, length = struct.unpack_from("<III", head)
        if version != 2:
            raise ParseError(path, None, f"expected GLB version 2, found {version}")
        if length != size:
            raise ParseError(path, None, f"expected {length:,} bytes (GLB header), the file holds {size:,}")
        n, kind = struct.unpack_from("<II", head, 12)
        if kind != _JSON_CHUNK:
            raise ParseError(path, None, "expected a JSON chunk first in the GLB container")
        if 20 + n > size:
            raise ParseError(path, None, f"the JSON chunk claims {n:,} bytes, past the end of the file")
        if n > MAX_GLB_JSON:
            raise ParseError(
                path,
                None,
                f"the JSON chunk claims {n:,} bytes; expected at most {MAX_GLB_JSON >> 20} MiB (data: BIN chunk)",
            )
        _json_start(path, head[20 : 20 + n], "the GLB JSON chunk")
        return
    _json_start(path, head[3:] if head.startswith(b"\xef\xbb\xbf") else head, "a glTF JSON document or a GLB file")
    if size > MAX_GLB_JSON:
        raise ParseError(
            path,
            None,
            f"a glTF JSON document of {size / 2**20:,.1f} MiB; expected at most {MAX_GLB_JSON >> 20} MiB "
            "(a large take's data belong in a .glb, or in a .bin buffer beside the .gltf)",
        )


def _json_start(path: Path, head: bytes, what: str) -> None:
    body = head.lstrip(b" \t\r\n")
    if not body[:1] == b"{":
        raise ParseError(path, 1, f"expected {what} starting with '{{', found {body[:16]!r}")
    bad = head.translate(None, bytes(range(32, 256)) + b"\t\r\n")
    if bad:
        off = head.find(bad[:1])
        raise ParseError(path, head.count(b"\n", 0, off) + 1, f"expected JSON text, found control byte 0x{bad[0]:02x}")


class _Doc:
    """A parsed glTF document: its JSON and buffers, with checked accessors."""

    def __init__(self, path: Path, data: bytes) -> None:
        self.path = path
        glb_bin: memoryview | None = None
        if data[:4] == b"glTF":
            chunk, glb_bin = self._glb(data)
            text = bytes(chunk)  # the JSON chunk (small); the BIN chunk stays a view
        else:
            text = data[3:] if data.startswith(b"\xef\xbb\xbf") else data
        try:
            doc = bounded_loads(text, MAX_JSON_DEPTH)
        except UnicodeDecodeError as exc:
            raise self.error(f"expected UTF-8 JSON (or a GLB container), found byte 0x{text[exc.start]:02x}") from None
        except json.JSONDecodeError as exc:
            raise ParseError(path, None if glb_bin is not None else exc.lineno, f"expected JSON: {exc.msg}") from None
        except JsonDepthError as exc:
            raise self.error(f"expected a glTF document, found {exc}") from None
        except ValueError as exc:  # e.g. an integer of more than 4,300 digits
            raise self.error(f"expected JSON: {str(exc)[:120]}") from None
        if not isinstance(doc, dict):
            raise self.error("expected a JSON object at the top level")
        version = str(self.get(doc, "asset", dict, "asset").get("version", ""))
        if not version.startswith("2."):
            raise self.error(f"expected glTF version 2.x, found {version!r}")
        self.doc = doc
        self.glb_bin = glb_bin
        self._budget = _common.MAX_FILE_BYTES - len(data)  # bytes left for buffers beside the file
        self._buffers: dict[int, bytes | memoryview] = {}
        self._accessors: dict[tuple[Any, ...], np.ndarray] = {}

    def error(self, msg: str) -> ParseError:
        return ParseError(self.path, None, msg)

    def _glb(self, data: bytes) -> tuple[memoryview, memoryview | None]:
        if len(data) < 20:
            raise self.error(f"expected a 12-byte GLB header and a JSON chunk, found {len(data)} bytes")
        magic, version, length = struct.unpack_from("<III", data)
        if version != 2:
            raise self.error(f"expected GLB version 2, found {version}")
        if length != len(data):
            raise self.error(f"expected {length} bytes (GLB header), found {len(data)}")
        view = memoryview(data)  # chunks are views: no copy of the file's body
        chunks: list[tuple[int, memoryview]] = []
        pos = 12
        while pos < len(data):
            if pos + 8 > len(data):
                raise self.error(f"expected a chunk header at byte {pos}, the file ends")
            n, kind = struct.unpack_from("<II", data, pos)
            if pos + 8 + n > len(data):
                raise self.error(f"chunk at byte {pos} claims {n} bytes, past the end of the file")
            chunks.append((kind, view[pos + 8 : pos + 8 + n]))
            pos += 8 + n
        if not chunks or chunks[0][0] != _JSON_CHUNK:
            raise self.error("expected a JSON chunk first in the GLB container")
        binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _BIN_CHUNK else None
        return chunks[0][1], binary

    def get(self, obj: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str, default: Any = ...) -> Any:
        """``obj[key]`` checked to be of ``kind`` (error names the JSON location)."""
        if key not in obj:
            if default is ...:
                raise self.error(f"{where}: expected a {key!r} entry")
            return default
        v = obj[key]
        if not isinstance(v, kind) or (kind is int and isinstance(v, bool)):
            raise self.error(f"{where}: expected {key!r} to be {_kind_name(kind)}, found {json.dumps(v)[:60]}")
        return v

    def item(self, key: str, i: Any, where: str) -> dict[str, Any]:
        arr = self.doc.get(key, [])
        if not isinstance(arr, list):
            raise self.error(f"{where}: expected {key!r} to be an array, found {json.dumps(arr)[:40]}")
        if isinstance(i, bool) or not isinstance(i, int) or not 0 <= i < len(arr):
            raise self.error(f"{where}: expected an index into {key} (0..{len(arr) - 1}), found {json.dumps(i)[:40]}")
        if not isinstance(arr[i], dict):
            raise self.error(f"{key}[{i}]: expected a JSON object")
        return cast("dict[str, Any]", arr[i])

    def buffer(self, i: int) -> bytes | memoryview:
        """Buffer ``i``: the GLB binary chunk, a data URI (its base64 length checked against
        ``byteLength`` before decoding) or a file beside the document, confined to its
        folder (:func:`._common.read_sidecar`), its bytes counted in the per-file cap."""
        if i in self._buffers:
            return self._buffers[i]
        w = f"buffers[{i}]"
        b = self.item("buffers", i, w)
        uri = self.get(b, "uri", str, w, None)
        n = self.get(b, "byteLength", int, w)
        if not 0 < n <= _common.MAX_FILE_BYTES:
            raise self.error(f"{w}: expected a byteLength in [1, {_common.MAX_FILE_BYTES:,}], found {n:,}")
        raw: bytes | memoryview
        if uri is None:
            if i != 0 or self.glb_bin is None:
                raise self.error(f"{w}: expected a 'uri' (or the GLB binary chunk for buffer 0)")
            raw = self.glb_bin
        elif uri.startswith("data:"):
            head, _, payload = uri.partition(",")
            if not head.endswith(";base64"):
                raise self.error(f"{w}: expected a base64 data URI")
            if len(payload) > 4 * (n // 3 + 1) + 4:  # more than byteLength needs: refused before decoding
                raise self.error(
                    f"{w}: a data URI of {len(payload):,} base64 characters for a byteLength of {n:,}; expected at "
                    f"most {4 * (n // 3 + 1):,}"
                )
            try:
                raw = base64.b64decode(payload, validate=True)
            except (ValueError, binascii.Error):
                raise self.error(f"{w}: expected valid base64 in the data URI") from None
        else:
            from urllib.parse import unquote

            raw = read_sidecar(self.path, unquote(uri), n, self._budget, w)
            self._budget -= len(raw)
        if len(raw) < n:
            raise self.error(f"{w}: expected {n:,} bytes, found {len(raw):,}")
        self._buffers[i] = raw
        return raw

    def nonneg(self, obj: dict[str, Any], key: str, where: str, default: Any = ...) -> int:
        """An integer entry that must be >= 0 (offsets, lengths, strides)."""
        v = self.get(obj, key, int, where, default)
        if v < 0:
            raise self.error(f"{where}: expected {key!r} >= 0, found {v}")
        return int(v)

    def accessor(self, i: Any, where: str, widths: tuple[int, ...]) -> np.ndarray:
        """Accessor ``i`` as float64 ``(count, width)`` (normalized integers scaled; read once)."""
        key = (i if isinstance(i, int) and not isinstance(i, bool) else repr(i), widths)
        if key not in self._accessors:
            self._accessors[key] = self._accessor(i, where, widths)
        return self._accessors[key]

    def _accessor(self, i: Any, where: str, widths: tuple[int, ...]) -> np.ndarray:
        a = self.item("accessors", i, where)
        w = f"accessors[{i}]"
        if "sparse" in a:
            raise self.error(f"{w}: sparse accessors are not supported")
        ctype = self.get(a, "componentType", int, w)
        if ctype not in _COMPONENTS:
            raise self.error(f"{w}: expected a componentType among {sorted(_COMPONENTS)}, found {ctype}")
        dtype, norm = _COMPONENTS[ctype]
        normalized = self.get(a, "normalized", bool, w, False)
        width = _WIDTH.get(self.get(a, "type", str, w), 0)
        if width not in widths:
            raise self.error(f"{w} ({where}): expected type {'/'.join(_type_names(widths))}, found {a.get('type')!r}")
        count = self.get(a, "count", int, w)
        if count < 1:
            raise self.error(f"{w}: expected count >= 1, found {count}")
        item_size = np.dtype(dtype).itemsize * width
        if "bufferView" not in a:
            if count * width > MAX_ZERO_ELEMENTS:
                raise self.error(
                    f"{w}: {count:,} items without a bufferView (all zeros); expected at most "
                    f"{MAX_ZERO_ELEMENTS // width:,}"
                )
            out = np.zeros((count, width))
        else:
            bv = self.item("bufferViews", a["bufferView"], w)
            bw = f"bufferViews[{a['bufferView']}]"
            # declared sizes first: the view inside its buffer's byteLength, the accessor inside its view
            bi = self.get(bv, "buffer", int, bw)
            declared = self.get(self.item("buffers", bi, f"{bw}.buffer"), "byteLength", int, f"buffers[{bi}]")
            view_start = self.nonneg(bv, "byteOffset", bw, 0)
            length = self.nonneg(bv, "byteLength", bw)
            acc_offset = self.nonneg(a, "byteOffset", w, 0)
            stride = self.nonneg(bv, "byteStride", bw, 0) or item_size
            if stride < item_size or stride > 252 + item_size:
                raise self.error(f"{bw}: expected a byteStride in [{item_size}, 252] for {w}, found {stride}")
            if view_start + length > declared:
                raise self.error(
                    f"{bw}: bytes {view_start:,}..{view_start + length:,} lie past its buffer's byteLength {declared:,}"
                )
            start = view_start + acc_offset
            end = start + stride * (count - 1) + item_size
            limit = view_start + length
            if end > limit:
                raise self.error(f"{w}: {count:,} items need bytes up to {end:,}, the buffer view ends at {limit:,}")
            buf = self.buffer(bi)
            if end > len(buf):
                raise self.error(f"{w}: {count:,} items need bytes up to {end:,}, the buffer holds {len(buf):,}")
            raw = np.ndarray(
                (count, width), dtype=dtype, buffer=buf, offset=start, strides=(stride, np.dtype(dtype).itemsize)
            )
            out = raw.astype(np.float64)
            if normalized and norm is not None:
                out = np.maximum(out / norm, -1.0)
        if not np.all(np.abs(out) <= _MAX_VALUE):
            raise self.error(f"{w} ({where}): expected finite numbers within {_MAX_VALUE:g}")
        return out


def _kind_name(kind: Any) -> str:
    names = {dict: "an object", list: "an array", str: "a string", int: "an integer", bool: "true/false"}
    if isinstance(kind, tuple):
        return " or ".join(names.get(k, k.__name__) for k in kind)
    return cast("str", names.get(kind, kind.__name__))


def _type_names(widths: tuple[int, ...]) -> list[str]:
    return [k for k, v in _WIDTH.items() if v in widths and not k.startswith("MAT")]
