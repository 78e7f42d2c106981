"""Reading a text motion file in blocks of whole lines: the readers of large text formats
(BVH's MOTION section) parse each block straight into preallocated arrays, so an accepted
file costs its decoded arrays and one block, not the file's bytes plus a token per value.

:func:`text_blocks` checks the file as :func:`._common.read_bytes` does (a regular file
within :data:`._common.MAX_FILE_BYTES`, the header check on the first
:data:`._common.HEAD_BYTES`), then yields the text as :func:`._common.text_body` makes it
(no BOM, a lone CR turned into LF) in blocks that end at a line end, each checked for binary
bytes (:func:`._common.check_text`, the error at the file's line), while the SHA-1 of the
raw bytes accumulates for :func:`checksum_metadata`.
"""

from __future__ import annotations

import hashlib
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, cast

import numpy as np

from mocapflow.framework.errors import ParseError

from . import _common
from ._common import _BOM, HEAD_BYTES, check_text

#: Bytes read at a time (a block is these plus the rest of its last line).
BLOCK_BYTES = 8 << 20


def _lone_cr_to_lf(block: bytes, final: bool) -> bytes:
    """``block`` with every CR not followed by LF turned into LF (``final``: a CR that ends
    it ends the file, so it is lone too), as :func:`._common.text_body` does."""
    if b"\r" not in block:
        return block
    buf = np.frombuffer(block, dtype=np.uint8)
    cr = np.flatnonzero(buf == 13)
    nxt = np.minimum(cr + 1, buf.size - 1)
    lone = (buf[nxt] != 10) | ((cr + 1 >= buf.size) if final else False)
    if not lone.any():
        return block
    out = buf.copy()
    out[cr[lone]] = 10
    return cast("bytes", out.tobytes())


class TextBlocks:
    """The blocks of one file; ``sha1`` holds the raw bytes' digest once all were read,
    ``any_text`` whether a non-whitespace byte was seen."""

    def __init__(self, path: str | Path, check_head: Callable[[bytes], None] | None = None) -> None:
        self.path = Path(path)
        self.sha1 = hashlib.sha1()
        self.any_text = False
        self.check_head = check_head

    def __iter__(self) -> Iterator[tuple[bytes, int]]:
        """``(block, line of its first byte)``; every block but the last ends with LF."""
        p = self.path
        try:
            st = p.stat()
            if stat.S_ISDIR(st.st_mode):
                raise ParseError(p, None, "expected a file, found a directory")
            if not stat.S_ISREG(st.st_mode):
                raise ParseError(p, None, "expected a regular file (found a device, a pipe or a socket)")
            if st.st_size > _common.MAX_FILE_BYTES:  # read at call time (tests lower it)
                raise ParseError(
                    p,
                    None,
                    f"the file holds {st.st_size / 2**20:,.0f} MiB; a reader accepts at most "
                    f"{_common.MAX_FILE_BYTES / 2**20:,.0f} MiB per file (split the take)",
                )
            f = open(p, "rb")  # noqa: SIM115 - closed below, also when the consumer stops early
        except FileNotFoundError:
            raise ParseError(p, None, "file not found") from None
        except OSError as exc:
            raise ParseError(p, None, f"cannot read the file ({exc.strerror or exc})") from None
        try:
            yield from self._blocks(f)
        finally:
            f.close()

    def _blocks(self, f: BinaryIO) -> Iterator[tuple[bytes, int]]:
        p, total, line, rest, first = self.path, 0, 1, b"", True
        while True:
            try:
                raw = f.read(HEAD_BYTES if first else BLOCK_BYTES)  # the head is checked before any more is read
            except OSError as exc:
                raise ParseError(p, None, f"cannot read the file ({exc.strerror or exc})") from None
            total += len(raw)
            if total > _common.MAX_FILE_BYTES:
                raise ParseError(
                    p, None, f"the file grew beyond {_common.MAX_FILE_BYTES / 2**20:,.0f} MiB while being read"
                )
            self.sha1.update(raw)
            if first:
                first = False
                head = raw[:HEAD_BYTES]
                if self.check_head is not None and head.strip():
                    self.check_head(head)
                if raw.startswith(_BOM):
                    raw = raw[3:]
            final = not raw
            data = rest + raw
            cut = len(data) if final else data.rfind(b"\n") + 1
            if cut == 0 and not final:  # no line end yet: read on
                rest = data
                continue
            block, rest = _lone_cr_to_lf(data[:cut], final), data[cut:]
            if block:
                if not self.any_text and block.strip():
                    self.any_text = True
                try:
                    check_text(p, block)
                except ParseError as exc:  # the line within the block -> the file's line
                    raise ParseError(p, (exc.line or 1) + line - 1, exc.message) from None
                yield block, line
                line += block.count(b"\n")
            if final:
                if not self.any_text:
                    raise ParseError(p, 1, "the file is empty")
                return

    def metadata(self, fmt: str) -> dict[str, Any]:
        """What :func:`._common.file_metadata` records, from the bytes read."""
        return {"path": str(self.path), "format": fmt, "checksum": self.sha1.hexdigest()}
