"""Helpers shared by the format readers: reading a file's bytes with clear errors, the
text normalisation every text reader applies, the bounds on values, metadata common to
every clip, and the Euler conventions of the formats.

Value policy (every reader)
---------------------------
A reader never turns a value it cannot trust into something else silently:

* non-finite numbers (``nan``, ``inf``, numbers that overflow a double such as ``1e309``)
  are a ParseError, except where the format defines them as a gap (``NaN`` or an empty
  field in TRC, an invalid C3D sample, which becomes NaN);
* positions and lengths beyond :data:`MAX_METRES` (10 km) after conversion to metres
  are a ParseError: no capture volume is that large, and beyond it a position stored as
  float32 (the marker datasets) no longer resolves a millimetre (float32 spacing at
  10^4 m is 1 mm), so such a value is corruption, never data;
* Euler angles beyond :data:`MAX_DEGREES` (10^6 degrees, 2,778 turns; the same bound in
  radians for ``:RADIANS`` files) are a ParseError: real files keep angles within a few
  turns, even unwrapped ones;
* frame rates must lie in (0, :data:`MAX_FPS`] (100 kHz, above every capture system).

Text files may start with a UTF-8 byte-order mark and end lines with LF, CRLF or a lone
CR, mixed in one file (:func:`text_body`); every other control byte except tab,
vertical tab and form feed (whitespace) is binary garbage.
"""

from __future__ import annotations

import hashlib
import math
import os
import re
import stat
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework.errors import ParseError

#: Largest file a reader accepts, bytes (1 GiB: an hour of 120 Hz BVH with 60 joints is
#: ~0.6 GB); a larger file is a ParseError before any of it is read.
MAX_FILE_BYTES = 1 << 30

#: Largest JSON chunk of a GLB (its data live in the BIN chunk: real ones hold kilobytes),
#: and largest ``.gltf`` JSON document (buffers embedded as base64 included): the whole text
#: is parsed at once, so a bigger one (or an endless string behind a valid head) is refused
#: from its size, before its body is read. Larger takes travel as ``.glb`` or with a ``.bin``.
MAX_GLB_JSON = 64 << 20
#: Bytes a reader's header check sees before the rest of the file is read.
HEAD_BYTES = 1 << 16


def read_bytes(path: str | Path, check_head: Callable[[bytes], None] | None = None) -> bytes:
    """The file's bytes; a ParseError (line ``None``) for a missing file, a directory or
    anything but a regular file, an unreadable or an empty file, and a file larger than
    :data:`MAX_FILE_BYTES`. ``check_head(head)`` sees the first :data:`HEAD_BYTES` and
    raises the reader's ParseError before the rest is read: a file that is not of the
    format costs one small read, whatever its size."""
    p = Path(path)
    try:
        st = p.stat()
        if stat.S_ISDIR(st.st_mode):
            raise ParseError(p, None, "expected a file, found a directory")
        if not stat.S_ISREG(st.st_mode):
            raise ParseError(p, None, "expected a regular file (found a device, a pipe or a socket)")
        if st.st_size > MAX_FILE_BYTES:
            raise ParseError(
                p,
                None,
                f"the file holds {st.st_size / 2**20:,.0f} MiB; a reader accepts at most "
                f"{MAX_FILE_BYTES / 2**20:,.0f} MiB per file (split the take)",
            )
        with open(p, "rb") as f:
            if check_head is not None:
                head = f.read(HEAD_BYTES)
                if head.strip():
                    check_head(head)
                f.seek(0)
            # the size stat gave (+1: a file that grew since is seen), never a buffer of the
            # whole limit up front (read(n) allocates n), and still bounded if it grew
            data = f.read(min(st.st_size, MAX_FILE_BYTES) + 1)
            if len(data) > st.st_size:
                data += f.read(MAX_FILE_BYTES + 1 - len(data))
    except FileNotFoundError:
        raise ParseError(p, None, "file not found") from None
    except OSError as exc:
        raise ParseError(p, None, f"cannot read the file ({exc.strerror or exc})") from None
    if len(data) > MAX_FILE_BYTES:
        raise ParseError(p, None, f"the file grew beyond {MAX_FILE_BYTES / 2**20:,.0f} MiB while being read")
    if not data.strip():
        raise ParseError(p, 1, "the file is empty")
    return data


def read_sidecar(owner: Path, name: str, n_bytes: int, budget: int, what: str) -> bytes:
    """The first ``n_bytes`` of a file a document names beside itself (a glTF buffer
    ``uri``), confined to the document's own folder: ``name`` is a relative path (already
    percent-decoded) without ``..``, a drive or a scheme; the file it resolves to, symbolic
    links followed, lies inside ``owner``'s folder (resolved), is a regular file (a FIFO or
    a device is refused without blocking: the file is opened non-blocking and checked
    after opening) and holds at least ``n_bytes``, which must fit in ``budget`` (the bytes
    the reader may still read for this document). ParseError naming ``owner`` and ``what``
    otherwise; no other file is opened."""

    def refuse(msg: str) -> ParseError:
        return ParseError(owner, None, f"{what}: {msg}")

    parts = name.replace("\\", "/").split("/")
    if (
        not name
        or "\x00" in name
        or name.startswith(("/", "\\"))
        or (len(name) > 1 and name[1] == ":")
        or ".." in parts
        or re.match(r"[A-Za-z][A-Za-z0-9+.-]*:", name)
    ):
        raise refuse(f"expected a relative path inside the file's folder, found {name!r:.80}")
    if n_bytes > budget:
        raise refuse(
            f"declares {n_bytes:,} bytes; with the file itself a reader accepts at most "
            f"{MAX_FILE_BYTES / 2**20:,.0f} MiB per file"
        )
    folder = owner.parent.resolve()
    try:
        target = (folder / "/".join(p for p in parts if p not in ("", "."))).resolve(strict=True)
    except FileNotFoundError:
        raise refuse(f"cannot read {name!r:.80} beside the file (file not found)") from None
    except (OSError, RuntimeError) as exc:  # RuntimeError: a symlink loop (Python < 3.13)
        raise refuse(f"cannot read {name!r:.80} beside the file ({getattr(exc, 'strerror', None) or exc})") from None
    if target == folder or not target.is_relative_to(folder):
        raise refuse(f"{name!r:.80} resolves outside the file's folder; expected a file beside it")
    try:
        fd = os.open(target, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise refuse(f"cannot read {name!r:.80} beside the file ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise refuse(f"{name!r:.80} is not a regular file (a device, a pipe or a folder)")
        if st.st_size < n_bytes:
            raise refuse(f"expected {n_bytes:,} bytes in {name!r:.80}, found {st.st_size:,}")
        with os.fdopen(os.dup(fd), "rb") as f:
            data = f.read(n_bytes)
    except OSError as exc:
        raise refuse(f"cannot read {name!r:.80} beside the file ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if len(data) < n_bytes:
        raise refuse(f"expected {n_bytes:,} bytes in {name!r:.80}, found {len(data):,}")
    return data


#: Frames a scene reader (glTF, FBX) samples beyond its keys: at most this many per distinct
#: key time plus :data:`TIMELINE_FRAMES_FLOOR`; one far key cannot turn a short take into
#: millions of frames.
TIMELINE_FRAMES_PER_KEY = 100
TIMELINE_FRAMES_FLOOR = 10_000
#: Node-frames (sampled frames x nodes of the skeleton and its ancestors) a scene reader
#: builds: at most :data:`NODE_FRAMES_FLOOR` plus one per byte of the file (a take keyed on
#: every frame stores >= 16 bytes per node-frame), ~250 bytes of memory each.
NODE_FRAMES_FLOOR = 1 << 20
#: Most nodes in a scene reader's skeleton (its joints and their ancestors): each costs
#: Python work downstream (~1 ms); real rigs, face rigs included, have fewer than 1,000.
MAX_SKELETON_NODES = 4096


def check_timeline(
    path: Path, *, n_frames: int, n_nodes: int, key_times: list[np.ndarray], t0: float, t1: float, fps: float, size: int
) -> None:
    """Refuse a timeline the file's own data do not support (module constants): more frames
    than its distinct key times justify (one far key), more node-frames than its size, or
    more than :data:`MAX_SKELETON_NODES` nodes."""
    if n_nodes > MAX_SKELETON_NODES:
        raise ParseError(
            path,
            None,
            f"a skeleton of {n_nodes:,} nodes; expected at most {MAX_SKELETON_NODES:,} (joints and ancestors)",
        )
    keys: Any = (
        np.unique(np.concatenate([np.asarray(k, dtype=np.float64).ravel() for k in key_times])) if key_times else []
    )
    allowed = TIMELINE_FRAMES_PER_KEY * len(keys) + TIMELINE_FRAMES_FLOOR
    if n_frames > allowed:
        gaps = np.diff(keys) if len(keys) > 1 else np.zeros(1)
        g = int(np.argmax(gaps))
        far = (
            f"; the largest gap between keys is {gaps[g]:g} s (from {keys[g]:g} to {keys[g + 1]:g} s)"
            if len(keys) > 1
            else ""
        )
        raise ParseError(
            path,
            None,
            f"keys from {t0:g} to {t1:g} s at {fps:g} fps make {n_frames:,} frames from {len(keys):,} distinct key "
            f"times{far}; expected at most {TIMELINE_FRAMES_PER_KEY} frames per key time + {TIMELINE_FRAMES_FLOOR:,} "
            "(a far or corrupt key time?)",
        )
    if n_frames * n_nodes > NODE_FRAMES_FLOOR + size:
        raise ParseError(
            path,
            None,
            f"{n_frames:,} frames x {n_nodes:,} nodes = {n_frames * n_nodes:,} node-frames from a file of {size:,} bytes; "
            f"expected at most {NODE_FRAMES_FLOOR:,} + one per byte of the file",
        )


def text_head(path: Path, head: bytes, starts: tuple[bytes, ...], what: str) -> None:
    """Header check of a text format: ``head`` (the file's first bytes) is text up to its
    last complete line and, after a BOM and whitespace, starts with one of ``starts``
    (case-insensitive; empty: any text)."""
    cut = head.rfind(b"\n") + 1 if len(head) >= HEAD_BYTES else len(head)
    check_text(path, head, cut or len(head))
    if starts:
        text = head[3:] if head.startswith(_BOM) else head
        first = text.lstrip()[: max(len(s) for s in starts)].upper()
        if not any(first.startswith(s.upper()) for s in starts):
            line = line_of(text, len(text) - len(text.lstrip()))
            found = text.lstrip().split(b"\n", 1)[0][:40].decode("latin-1")
            raise ParseError(path, line, f"expected {what}, found {found!r}")


#: Largest accepted |position| or length after conversion to metres (module doc).
MAX_METRES = 1.0e4
#: Largest accepted |Euler angle| in degrees (module doc).
MAX_DEGREES = 1.0e6
#: Largest accepted frame rate in Hz (module doc).
MAX_FPS = 1.0e5

_BOM = b"\xef\xbb\xbf"


_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_INT = re.compile(r"[0-9]+")


def strict_float(text: str | bytes) -> float:
    """A finite decimal number written exactly as the tokenizer reads one (no ``inf``,
    ``nan``, ``1_0``, surrounding or non-ASCII whitespace); ValueError otherwise."""
    t = text.decode("latin-1") if isinstance(text, bytes) else text
    if not _FLOAT.fullmatch(t):
        raise ValueError(t)
    v = float(t)
    if not math.isfinite(v):
        raise ValueError(t)
    return v


def strict_int(text: str | bytes) -> int:
    """A non-negative integer written with ASCII digits only; ValueError otherwise."""
    t = text.decode("latin-1") if isinstance(text, bytes) else text
    if not _INT.fullmatch(t):
        raise ValueError(t)
    return int(t)


def split_ascii(text: str) -> list[str]:
    """Words of a latin-1 line split on ASCII whitespace only (as the tokenizer splits;
    ``str.split`` would also split on NBSP and NEL)."""
    return [w.decode("latin-1") for w in text.encode("latin-1").split()]


def text_body(data: bytes) -> bytes:
    """The text a reader parses: ``data`` without a leading UTF-8 BOM, with every lone CR
    (old Mac line ends) turned into LF. CRLF stays (CR is whitespace to the tokenizer),
    so byte offsets after the BOM and line numbers are those an editor shows."""
    if data.startswith(_BOM):
        data = data[3:]
    if b"\r" in data:  # one vectorised pass (bytes.count(b"\r\n") costs three times as much)
        buf = np.frombuffer(data, dtype=np.uint8)
        cr = np.flatnonzero(buf == 13)
        lone = buf[np.minimum(cr + 1, buf.size - 1)] != 10  # a CR that ends the file is lone too
        if lone.any():
            out = buf.copy()
            out[cr[lone]] = 10
            data = out.tobytes()
    return data


def line_of(data: bytes, offset: int) -> int:
    """1-based line number of a byte offset (LF ends a line)."""
    return data.count(b"\n", 0, offset) + 1


_TEXT_BYTES = b"\t\n\r\x0b\x0c" + bytes(range(32, 127)) + bytes(range(128, 256))


def check_text(path: str | Path, data: bytes, upto: int | None = None) -> None:
    """Reject binary garbage: control bytes (0x00-0x1f, 0x7f) other than whitespace in
    ``data[:upto]``."""
    head = data if upto is None else data[:upto]
    bad = head.translate(None, _TEXT_BYTES)
    if bad:
        off = head.find(bad[:1])
        raise ParseError(path, line_of(data, off), f"expected text, found binary byte 0x{bad[0]:02x}")


def file_metadata(path: str | Path, data: bytes, fmt: str) -> dict[str, Any]:
    """Metadata every reader records: path, format and the sha1 of the file bytes."""
    return {"path": str(path), "format": fmt, "checksum": hashlib.sha1(data).hexdigest()}
