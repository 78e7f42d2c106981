"""The binary FBX container: a tree of node records with typed properties.

Layout (FBX 7.x; 64-bit record headers from version 7500): a 27-byte header
(``Kaydara FBX Binary  \\0``, ``\\x1a\\0``, uint32 version), then node records
``end_offset, n_props, props_bytes, name_len, name, props..., children..., null record``;
property codes ``Y`` int16, ``C`` bool, ``I`` int32, ``F`` float32, ``D`` float64,
``L`` int64, ``S`` string, ``R`` raw bytes, and arrays ``f d l i b`` (uint32 length,
encoding 0 raw / 1 zlib, byte count). Every read is bounds-checked: a malformed file is a
ParseError naming the byte offset and what was expected, never an exception of another kind.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework.errors import ParseError

MAGIC = b"Kaydara FBX Binary  \x00"
_SCALARS = {b"Y": "<h", b"C": "<?", b"I": "<i", b"F": "<f", b"D": "<d", b"L": "<q"}
_ARRAYS = {b"f": "<f4", b"d": "<f8", b"l": "<i8", b"i": "<i4", b"b": "<u1"}
#: Largest decompressed array accepted (elements): 2^28, far above any animation curve.
MAX_ARRAY = 1 << 28
MAX_DEPTH = 64
#: Bytes all of a file's zlib arrays may inflate to together: this floor plus
#: :data:`INFLATE_RATIO` times the file's size (real FBX arrays deflate 2-10x; one 2 MB
#: array asking for 2 GiB is a bomb). Each array inflates at most to its declared length.
INFLATE_FLOOR = 32 << 20
#: Most node records parsed per file (a Python object each, ~250 bytes): real animation
#: files hold tens of thousands (``walk_120.fbx``: 23,000) of the kinds the reader parses.
MAX_RECORDS = 500_000
INFLATE_RATIO = 8


def check_head(path: Path, head: bytes, size: int) -> None:
    """Header check on the file's first bytes (``size``: the whole file's): ASCII FBX
    refused, the binary magic, a version in 7000-9999, and the first node record's end
    offset within the file; anything else is refused before the body is read."""
    if head[:5] == b"; FBX" or head.lstrip()[:12] == b"FBXHeaderExt":
        raise ParseError(path, 1, "ASCII FBX is not supported; expected a binary FBX file (export as binary)")
    if len(head) < 27 or head[:21] != MAGIC:
        raise ParseError(path, None, "expected a binary FBX file (header 'Kaydara FBX Binary')")
    (version,) = struct.unpack_from("<I", head, 23)
    if not 7000 <= version < 10000:
        raise ParseError(path, None, f"expected FBX version 7000-9999, found {version}")
    fmt = "<QQQB" if version >= 7500 else "<IIIB"
    if len(head) >= 27 + struct.calcsize(fmt):
        end, n_props, props_len, name_len = struct.unpack_from(fmt, head, 27)
        if end == n_props == props_len == name_len == 0:
            raise ParseError(path, None, "at byte 27: expected a node record, found the end of the node list")
        if not 27 < end <= size or props_len > size:
            raise ParseError(
                path,
                None,
                f"at byte 27: node record claims to end at byte {end:,}; expected an offset in (27, {size:,}]",
            )


class Node:
    """One FBX node record: ``name``, ``props`` (Python values, numpy arrays), ``children``."""

    __slots__ = ("name", "props", "children", "offset")

    def __init__(self, name: str, props: list[Any], children: list[Node], offset: int) -> None:
        self.name, self.props, self.children, self.offset = name, props, children, offset

    def find(self, name: str) -> Node | None:
        for c in self.children:
            if c.name == name:
                return c
        return None

    def find_all(self, name: str) -> list[Node]:
        return [c for c in self.children if c.name == name]


def parse_fbx(path: Path, data: bytes, objects: frozenset[str] | None = None) -> tuple[int, Node]:
    """``(version, root)`` of a binary FBX file; ``root.children`` are the top-level nodes.
    ``objects``: the kinds of ``Objects`` children to parse (``None``: all); the others stay
    bare nodes (name and offset: no properties, no children), their content neither parsed
    nor inflated (meshes, textures, embedded media). At most :data:`MAX_RECORDS` records
    are parsed."""
    check_head(path, data[:65536], len(data))
    (version,) = struct.unpack_from("<I", data, 23)
    return version, _Reader(path, data, version, objects).top()


class _Reader:
    def __init__(self, path: Path, data: bytes, version: int, objects: frozenset[str] | None = None) -> None:
        self.path, self.data, self.wide = path, data, version >= 7500
        self.head = struct.Struct("<QQQB" if self.wide else "<IIIB")
        self.inflate_left = INFLATE_FLOOR + INFLATE_RATIO * len(data)
        self.objects, self.records_left = objects, MAX_RECORDS

    def error(self, offset: int, what: str) -> ParseError:
        return ParseError(self.path, None, f"at byte {offset}: {what}")

    def top(self) -> Node:
        nodes: list[Node] = []
        pos = 27
        while True:
            if pos + self.head.size > len(self.data):
                if nodes:  # files that end without the final null record (some writers)
                    break
                raise self.error(pos, "expected a node record, the file ends")
            node, pos = self.node(pos, 0)
            if node is None:
                break
            nodes.append(node)
        return Node("", [], nodes, 0)

    def node(self, pos: int, depth: int, parent: str = "") -> tuple[Node | None, int]:
        data = self.data
        if depth > MAX_DEPTH:
            raise self.error(pos, f"expected nodes nested at most {MAX_DEPTH} deep")
        if pos + self.head.size > len(data):
            raise self.error(pos, "expected a node record header, the file ends")
        end, n_props, props_len, name_len = self.head.unpack_from(data, pos)
        if end == 0 and n_props == 0 and props_len == 0 and name_len == 0:
            return None, pos + self.head.size
        if end > len(data) or end <= pos:
            raise self.error(
                pos, f"node record claims to end at byte {end}; expected an offset in ({pos}, {len(data)}]"
            )
        p = pos + self.head.size
        name = data[p : p + name_len].decode("latin-1")
        if self.objects is not None and depth == 1 and parent == "Objects" and name not in self.objects:
            return Node(name, [], [], pos), end  # an object kind the caller does not read: skipped whole
        self.records_left -= 1
        if self.records_left < 0:
            raise self.error(pos, f"expected at most {MAX_RECORDS:,} node records (of the object kinds read)")
        p += name_len
        props_end = p + props_len
        if props_end > end:
            raise self.error(pos, f"node {name!r}: its {props_len} property bytes run past the record's end")
        props = []
        for _ in range(n_props):
            v, p = self.prop(p, props_end, name)
            props.append(v)
        if p != props_end:
            raise self.error(
                p, f"node {name!r}: expected {props_len} property bytes, read {p - (props_end - props_len)}"
            )
        children: list[Node] = []
        while p < end:
            child, p = self.node(p, depth + 1, name)
            if child is None:
                break
            children.append(child)
        if p != end:
            raise self.error(p, f"node {name!r}: expected its children to end at byte {end}, found {p}")
        return Node(name, props, children, pos), end

    def prop(self, p: int, limit: int, owner: str) -> tuple[Any, int]:
        data = self.data
        if p >= limit:
            raise self.error(p, f"node {owner!r}: expected a property, its property bytes end")
        code = data[p : p + 1]
        p += 1
        if code in _SCALARS:
            fmt = _SCALARS[code]
            size = struct.calcsize(fmt)
            if p + size > limit:
                raise self.error(p, f"node {owner!r}: property {code.decode()} runs past its record")
            return struct.unpack_from(fmt, data, p)[0], p + size
        if code in (b"S", b"R"):
            if p + 4 > limit:
                raise self.error(p, f"node {owner!r}: expected a string length")
            (n,) = struct.unpack_from("<I", data, p)
            if p + 4 + n > limit:
                raise self.error(p, f"node {owner!r}: a {n}-byte string runs past its record")
            raw = data[p + 4 : p + 4 + n]
            return (raw.decode("utf-8", "replace") if code == b"S" else raw), p + 4 + n
        if code in _ARRAYS:
            return self.array(code, p, limit, owner)
        raise self.error(p - 1, f"node {owner!r}: expected a property type code among YCIFDLSRfdlib, found {code!r}")

    def array(self, code: bytes, p: int, limit: int, owner: str) -> tuple[np.ndarray, int]:
        """An array property (header at ``p``): raw or zlib, inflated at most to its declared
        length and within the file's inflation budget."""
        data = self.data
        if p + 12 > limit:
            raise self.error(p, f"node {owner!r}: expected an array header")
        count, enc, n = struct.unpack_from("<III", data, p)
        if p + 12 + n > limit:
            raise self.error(p, f"node {owner!r}: a {n}-byte array runs past its record")
        if count > MAX_ARRAY:
            raise self.error(p, f"node {owner!r}: an array of {count} elements; expected at most {MAX_ARRAY}")
        raw = data[p + 12 : p + 12 + n]
        dtype = np.dtype(_ARRAYS[code])
        if enc == 1:
            want = count * dtype.itemsize
            if want > self.inflate_left:
                raise self.error(
                    p,
                    f"node {owner!r}: a compressed array of {n:,} bytes declares {want:,} bytes; the file's arrays "
                    f"may inflate to {INFLATE_FLOOR >> 20} MiB + {INFLATE_RATIO}x the file's size in all "
                    f"({self.inflate_left:,} bytes left)",
                )
            try:
                d = zlib.decompressobj()
                raw = d.decompress(raw, want + 1)  # never more than the declared length (+1 tells a longer one)
            except zlib.error as exc:
                raise self.error(p, f"node {owner!r}: expected a zlib-compressed array ({exc})") from None
            self.inflate_left -= len(raw)
        elif enc != 0:
            raise self.error(p, f"node {owner!r}: expected array encoding 0 or 1, found {enc}")
        if len(raw) != count * dtype.itemsize:
            raise self.error(
                p,
                f"node {owner!r}: expected {count} array elements ({count * dtype.itemsize} bytes), found {len(raw)} bytes",
            )
        return np.frombuffer(raw, dtype=dtype).copy(), p + 12 + n
