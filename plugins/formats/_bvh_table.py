"""The BVH MOTION table once parsed (frames x channels, float64): its frame-count and
value checks, and its conversion to joint rotations in blocks of rows, the table shrunk in
place behind each block so that the table and the rotations are never both whole in memory."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import ParseError

from ._common import MAX_DEGREES, MAX_METRES


def _check_motion(path: Path, state: np.ndarray, frames: int, n_ch: int, first_line: int) -> None:
    """Every data line held ``n_ch`` finite numbers and there were ``frames`` lines (the
    ``state`` :func:`._text_kernels.fill_table` left)."""
    if state[5] >= 0:  # pragma: no cover - the block check refuses binary bytes first
        raise ParseError(path, int(state[6]), "expected text, found a binary control byte")
    if state[1] >= 0:
        raise ParseError(path, int(state[1]), f"expected {n_ch} finite numbers per frame, found a non-number")
    if state[0] == 0:
        raise ParseError(path, first_line - 1, f"expected {frames} frame lines (Frames:) after this line, found none")
    if state[2] >= 0:
        raise ParseError(path, int(state[2]), f"expected {n_ch} values on this frame line, found {int(state[3])}")
    if state[0] != frames:
        raise ParseError(path, int(state[4]), f"expected {frames} frame lines (Frames:), found {int(state[0])}")


#: Rows of the MOTION table converted (and checked) at a time: the temporaries of a block stay
#: small beside the table (8 MB of values).
TABLE_BLOCK_VALUES = 1 << 20


def _rotations(
    held: list[np.ndarray], cols: np.ndarray, axis_id: np.ndarray, nj: int, shrink: bool = True
) -> np.ndarray:
    """The local rotations (frames, joints, 4) of the MOTION table, converted in blocks of rows
    from the end, the table shrunk in place behind each block: the table and the rotations do
    not both stay whole in memory (their pages are released as the table shrinks and the
    rotations are written). A table that cannot be resized (another reference) is converted
    the same way without shrinking. ``held``: a list holding the table, emptied (the caller
    keeps no other name of it); ``shrink=False`` leaves the table whole (a subset of joints)."""
    table = held.pop()
    frames, n_ch = table.shape
    rot = np.empty((frames, nj, 4))
    step = max(1, TABLE_BLOCK_VALUES // max(n_ch, 1))
    end = frames
    while end > 0:
        a = max(0, end - step)
        rot[a:end] = euler_rows_to_quat(table[a:end], cols, axis_id)
        if shrink:
            try:
                table.resize((a, n_ch), refcheck=True)
            except (ValueError, SystemError):  # a view or another name holds it: keep it whole
                shrink = False
        end = a
    return rot


def euler_rows_to_quat(table: np.ndarray, cols: np.ndarray, axis_id: np.ndarray) -> np.ndarray:
    """Joint rotations (T, J, 4) (w, x, y, z) of BVH Euler channels in degrees: ``table``
    (T, W); ``cols`` (J, 3) the column of joint j's k-th listed rotation channel (-1: none);
    ``axis_id`` (J, 3) its axis (0=x, 1=y, 2=z). Intrinsic, in listed order:
    ``M = R1 R2 R3``. NumPy over the rows (no compiled kernel, module doc of ``_bvh_rows``);
    the slow twin is ``tests/naive/formats.py``."""
    t, nj = table.shape[0], cols.shape[0]
    out = np.zeros((t, nj, 4))
    out[:, :, 0] = 1.0
    half = 0.5 * (np.pi / 180.0)
    for j in range(nj):
        q = out[:, j]
        for k in range(3):
            c = cols[j, k]
            if c < 0:
                continue
            h = half * table[:, c]
            ew, s = np.cos(h), np.sin(h)
            e = np.zeros((t, 4))
            e[:, 0] = ew
            e[:, 1 + axis_id[j, k]] = s
            q[:] = quat.mul(q, e)
    return out


def _check_bounds(
    path: Path, joints: list[Any], offsets: np.ndarray, table: np.ndarray, frame_lines: np.ndarray, scl: float
) -> None:
    """OFFSETs and position channels within MAX_METRES, rotations within MAX_DEGREES
    (the value policy of ``_common``)."""
    far = np.abs(offsets).max(axis=1) * scl > MAX_METRES
    if far.any():
        j = joints[int(np.argmax(far))]
        raise ParseError(
            path,
            j.offset_line,
            f"expected OFFSET values within {MAX_METRES:g} m (scale {scl:g} m per "
            f"file unit), found {' '.join(f'{v:g}' for v in j.offset)}",
        )
    limit = np.array(
        [MAX_DEGREES if ch[1:].lower() == "rotation" else MAX_METRES / scl for jt in joints for ch in jt.channels]
    )
    step = max(1, TABLE_BLOCK_VALUES // max(table.shape[1], 1))
    for a in range(0, len(table), step):  # in blocks of rows: |table| is never whole in memory
        block = table[a : a + step]
        over = np.abs(block) > limit
        if over.any():
            f, c = np.argwhere(over)[0]
            ch = [(jt.name, ch) for jt in joints for ch in jt.channels][c]
            what = f"within {MAX_DEGREES:g} degrees" if ch[1][1:].lower() == "rotation" else f"within {MAX_METRES:g} m"
            raise ParseError(path, int(frame_lines[a + f]), f"expected {ch[0]} {ch[1]} {what}, found {block[f, c]:g}")
