"""The BVH MOTION table parsed with NumPy and Arrow, one block of complete lines at a time.

No compiled kernel: reading a BVH file never loads numba (its import and kernels cost
~130 MB of memory and, on a first run, seconds of compilation), so a 300 MB take peaks at
its float64 table plus the imports. Blocks are split and their values parsed by Arrow's
compute kernels (``ascii_split_whitespace``, a cast to float64: correctly rounded, ~200 MB/s);
every whitespace-separated token must be one finite decimal number
(``nan``, ``inf``, hexadecimal, ``1_0`` and overflowing values are non-numbers), as the
tokenizer of the other text readers and its slow twin (``tests/naive/formats.py``) define it.
"""

from __future__ import annotations

import math

import numpy as np

#: Binary bytes: < 32 but tab, LF, VT, FF, CR (whitespace, as Arrow's ``ascii_split_whitespace``), and 127.
_BINARY = np.zeros(256, bool)
_BINARY[[c for c in range(32) if c not in (9, 10, 11, 12, 13)] + [127]] = True


def table_state() -> np.ndarray:
    """A fresh ``state`` for :func:`parse_rows`: rows seen (0), first line holding a
    non-number (1), first line whose count of values is wrong (2) and that count (3), last
    non-blank line (4), offset (5) and line (6) of a binary byte (-1: none)."""
    return np.array([0, -1, -1, 0, -1, -1, -1], dtype=np.int64)


def is_number(token: bytes) -> bool:
    """Whether ``token`` is one finite decimal number (the tokenizer's definition)."""
    t = token.lower().lstrip(b"+-")
    if not t or t[:1] in (b"n", b"i") or b"_" in t or t.startswith(b"0x"):
        return False
    try:
        return math.isfinite(float(token))
    except ValueError:
        return False


def parse_rows(block: bytes, line: int, out: np.ndarray, frame_lines: np.ndarray, state: np.ndarray) -> int:
    """Parse one block of complete lines of numbers into ``out`` (rows x columns, preallocated).

    ``block``: whole lines (LF ends; CR is whitespace; a last line without LF ends with the
    block); ``line``: the 1-based line of ``block[0]``. The i-th non-blank line of the
    table fills row i while rows last, with its values when it holds exactly ``out.shape[1]``
    finite numbers; ``frame_lines[i]`` is its line. ``state`` (:func:`table_state`) carries
    the counts and the first errors from block to block. Once a non-number was seen no
    further block is parsed (that error is the one reported). Returns the line after the
    block.
    """
    if state[1] >= 0 or state[5] >= 0:
        return line + block.count(b"\n")
    a = np.frombuffer(block, dtype=np.uint8)
    binary = np.flatnonzero(_BINARY[a])
    if len(binary):  # the block reader refuses binary files first; kept for direct callers
        state[5], state[6] = int(binary[0]), line + block.count(b"\n", 0, int(binary[0]))
        return line + block.count(b"\n")
    rows, cols = out.shape
    per_line, values = _tokens_in_pieces(block)
    filled = np.flatnonzero(per_line)  # non-blank lines, as offsets from `line`
    n_lines = len(per_line) - 1  # LFs in the block
    if not len(filled):
        return line + n_lines
    r0 = int(state[0])
    keep = max(0, min(len(filled), rows - r0))
    frame_lines[r0 : r0 + keep] = line + filled[:keep]
    state[0] = r0 + len(filled)
    state[4] = line + int(filled[-1])
    wrong = filled[per_line[filled] != cols]
    if len(wrong) and state[2] < 0:
        state[2], state[3] = line + int(wrong[0]), int(per_line[wrong[0]])
    if values is None or not np.isfinite(values).all():
        bad = _first_non_number(block)
        if bad is not None:
            state[1] = line + bad
            return line + n_lines
    if not len(wrong) and values is not None and keep:
        out[r0 : r0 + keep] = values[: keep * cols].reshape(keep, cols)
    return line + n_lines


#: Bytes split and parsed at a time: Arrow's temporaries of a piece stay small and are reused.
PIECE_BYTES = 1 << 20


def _tokens_in_pieces(block: bytes) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`_tokens` of ``block`` cut into pieces of about :data:`PIECE_BYTES` at line ends."""
    if len(block) <= PIECE_BYTES:
        return _tokens(block)
    counts, values, pos = [], [], 0
    while pos < len(block):
        cut = block.find(b"\n", pos + PIECE_BYTES) if pos + PIECE_BYTES < len(block) else -1
        end = len(block) if cut < 0 else cut + 1
        per_line, vals = _tokens(block[pos:end])
        # a piece ending at an LF has an empty last line: the next piece continues the count
        counts.append(per_line[:-1] if end < len(block) else per_line)
        values.append(vals)
        pos = end
    if any(v is None for v in values):
        return np.concatenate(counts), None
    return np.concatenate(counts), np.concatenate(values)  # type: ignore[arg-type]


def _tokens(block: bytes) -> tuple[np.ndarray, np.ndarray | None]:
    """Tokens per line (one more than the block's LFs) and every token's value in order,
    or None where a token is not one number (Arrow's parser refuses it: '1-2', '0x1A').

    Arrow's compute kernels split and parse without copying the block; they allocate from
    the system allocator, which returns large blocks at once (Arrow's default pool keeps
    ~90 MB of a 300 MB file's blocks cached)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    pool = pa.system_memory_pool()
    a = np.frombuffer(block, dtype=np.uint8)
    bounds = np.concatenate(([0], np.flatnonzero(a == 10) + 1, [len(a)])).astype(np.int64)
    lines = pa.LargeStringArray.from_buffers(len(bounds) - 1, pa.py_buffer(bounds), pa.py_buffer(block))
    split = pc.ascii_split_whitespace(lines, memory_pool=pool)
    flat = pc.list_flatten(split, memory_pool=pool)
    real = pc.greater(pc.binary_length(flat, memory_pool=pool), 0, memory_pool=pool)  # leading blanks give ''
    parent = pc.list_parent_indices(split, memory_pool=pool).to_numpy()
    keep = real.to_numpy(zero_copy_only=False)
    per_line = np.bincount(parent[keep], minlength=len(bounds) - 1)
    try:
        values = pc.cast(pc.filter(flat, real, memory_pool=pool), pa.float64(), memory_pool=pool)
    except pa.ArrowInvalid:
        return per_line, None
    return per_line, values.to_numpy(zero_copy_only=False)


def _first_non_number(block: bytes) -> int | None:
    """Offset (in lines) of the first line of ``block`` holding a token that is not a
    finite number; None if every token is one."""
    for i, text in enumerate(block.split(b"\n")):
        if any(not is_number(tok) for tok in text.split()):
            return i
    return None
