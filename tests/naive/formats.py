"""Slow, obviously correct twins of the format kernels (``plugins/formats/_text_kernels.py``,
``plugins/formats/_kernels.py``)."""

from __future__ import annotations

import math

import numpy as np

from mocapflow.framework import quaternions as quat


def tokenize(data: bytes, start: int = 0, first_line: int = 1):
    """Tokens of ``data[start:]`` with Python's ``split`` and ``float``.

    Returns (starts, lens, lines, values, isnum) like the fast tokenizer (without hashes
    and the binary-byte report); ``values`` is NaN where a token is not a finite number.
    """
    starts, lens, lines, values, isnum = [], [], [], [], []
    line = first_line
    i = start
    for piece in data[start:].split(b"\n"):
        pos = 0
        for tok in piece.split():
            off = piece.index(tok, pos)
            pos = off + len(tok)
            starts.append(i + off)
            lens.append(len(tok))
            lines.append(line)
            try:
                v = float(tok)
                ok = (
                    math.isfinite(v)
                    and tok.lower().lstrip(b"+-")[:1] not in (b"n", b"i")
                    and b"_" not in tok
                    and not tok.lower().startswith((b"0x", b"-0x", b"+0x"))
                )
            except ValueError:
                v, ok = math.nan, False
            values.append(v if ok else math.nan)
            isnum.append(ok)
        i += len(piece) + 1
        line += 1
    return (
        np.array(starts, np.int64),
        np.array(lens, np.int64),
        np.array(lines, np.int64),
        np.array(values, float),
        np.array(isnum, bool),
    )


def euler_table_to_quat(table, cols, axis_id, frames, scale, extrinsic):
    """Per-joint ``C M C^-1`` with ``M`` composed from elementary rotations one by one."""
    t, nj = table.shape[0], cols.shape[0]
    out = np.zeros((t, nj, 4))
    for f in range(t):
        for j in range(nj):
            m = quat.identity()
            for k in range(3):
                if cols[j, k] < 0:
                    continue
                axis = np.eye(3)[axis_id[j, k]]
                e = quat.from_axis_angle(axis, scale * table[f, cols[j, k]])
                m = quat.mul(e, m) if extrinsic else quat.mul(m, e)
            out[f, j] = quat.mul(quat.mul(frames[j], m), quat.conjugate(frames[j]))
    return out
