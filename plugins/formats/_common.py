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
import re
from pathlib import Path

import numpy as np

from mocapflow.framework.errors import ParseError


def read_bytes(path: str | Path) -> bytes:
    """The file's bytes; a ParseError (line ``None``) for a missing file, a directory,
    an unreadable or an empty file."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except IsADirectoryError:
        raise ParseError(p, None, "expected a file, found a directory") from None
    except FileNotFoundError:
        raise ParseError(p, None, "file not found") from None
    except OSError as exc:
        raise ParseError(p, None, f"cannot read the file ({exc.strerror or exc})") from None
    if not data.strip():
        raise ParseError(p, 1, "the file is empty")
    return data


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


def file_metadata(path: str | Path, data: bytes, fmt: str) -> dict:
    """Metadata every reader records: path, format and the sha1 of the file bytes."""
    return {"path": str(path), "format": fmt, "checksum": hashlib.sha1(data).hexdigest()}
