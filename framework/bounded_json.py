"""JSON parsing with a nesting limit that holds before the parser runs.

``json.loads`` recurses once per nested array or object: 100,000 nested ``[`` raise
``RecursionError`` (or worse, exhaust the C stack), which no caller expects. :func:`loads`
first measures the deepest nesting of the text in C-speed byte operations (strings
removed: split on quotes, or with a regular expression when a quote follows a backslash;
everything but brackets deleted; a running sum of +1/-1 with numpy) and refuses a text nested deeper than ``max_depth`` with
:class:`JsonDepthError`; only a text within the limit reaches ``json.loads``. Every other
failure is a :class:`ValueError` (``json.JSONDecodeError`` for syntax, with its line), so a
caller catches ``ValueError`` and nothing else.
"""

from __future__ import annotations

import json
import re
from typing import Any

import numpy as np

#: Deepest nesting of arrays and objects accepted by default (a glTF document nests < 10
#: levels, a search request 2).
MAX_DEPTH = 64

_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")


class JsonDepthError(ValueError):
    """The text nests arrays/objects deeper than the limit (``depth`` is the first level
    found beyond it, ``limit`` the limit)."""

    def __init__(self, depth: int, limit: int) -> None:
        self.depth, self.limit = depth, limit
        super().__init__(f"arrays/objects nested more than {limit} deep (found at least {depth})")


def nesting_depth(text: bytes | str, limit: int | None = None) -> int:
    """Deepest nesting of ``[``/``{`` outside strings (exact for valid JSON; for a text with
    an unterminated string, an upper or lower bound: it is invalid anyway). ``limit``:
    a text with at most ``limit`` brackets in all returns that count at once."""
    data = text.encode("utf-8", "surrogatepass") if isinstance(text, str) else bytes(text)
    if data.count(b"[") + data.count(b"{") <= (limit if limit is not None else -1):
        return data.count(b"[") + data.count(b"{")  # cannot nest deeper than it has brackets
    # strings removed: when no quote follows a backslash every quote opens or closes one (a
    # split on quotes, fast); otherwise the exact string pattern (4x slower)
    data = b"".join(data.split(b'"')[0::2]) if b'\\"' not in data else _STRING.sub(b"", data)
    brackets = data.translate(None, _NOT_BRACKETS)
    if not brackets:
        return 0
    b = np.frombuffer(brackets, dtype=np.uint8)
    step = np.where((b == ord("[")) | (b == ord("{")), 1, -1).astype(np.int32)
    return int(np.cumsum(step, dtype=np.int64).max(initial=0))


def loads(text: bytes | str, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads(text)`` for a text nested at most ``max_depth`` deep; JsonDepthError
    (a ValueError) beyond, ValueError for anything else that is not JSON (bytes that are
    not UTF-8 included)."""
    depth = nesting_depth(text, max_depth)
    if depth > max_depth:
        raise JsonDepthError(depth, max_depth)
    if isinstance(text, (bytes, bytearray, memoryview)):
        text = bytes(text).decode("utf-8")  # UnicodeDecodeError is a ValueError
    try:
        return json.loads(text)
    except RecursionError:  # pragma: no cover - the depth check above keeps it away
        raise JsonDepthError(max_depth + 1, max_depth) from None
