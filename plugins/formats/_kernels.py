"""Numba kernels of the format readers (no validation; the readers validate).

The slow, obviously correct twins are in ``tests/naive/formats.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (no copy): numba compiles one variant per writeable flag, so
    the arguments a kernel only reads are always passed read-only (Arrow columns are)."""
    v: np.ndarray = a.view()
    v.flags.writeable = False
    return v


@njit(cache=True)
def _qmul(
    aw: float, ax: float, ay: float, az: float, bw: float, bx: float, by: float, bz: float
) -> tuple[float, float, float, float]:
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True)
def euler_table_to_quat(
    table: np.ndarray, cols: np.ndarray, axis_id: np.ndarray, frames: np.ndarray, scale: float, extrinsic: bool
) -> np.ndarray:
    """Joint rotations (T, J, 4) from a table (T, W) of Euler angles as read from the file.

    ``cols`` (J, 3) int64: column of joint j's k-th listed rotation channel, -1 if it has
    fewer (zero angle); ``axis_id`` (J, 3): its axis (0=x, 1=y, 2=z); ``frames`` (J, 4):
    per-joint frame rotation ``C`` (w, x, y, z), the result is ``C M C^-1``; ``scale``:
    radians per table unit; ``extrinsic``: rotations about fixed axes in listed order
    (``M = R3 R2 R1``, Acclaim), else intrinsic (``M = R1 R2 R3``, BVH).
    """
    t = table.shape[0]
    nj = cols.shape[0]
    out = np.empty((t, nj, 4))
    for j in range(nj):
        cw, cx, cy, cz = frames[j, 0], frames[j, 1], frames[j, 2], frames[j, 3]
        for f in range(t):
            mw, mx, my, mz = 1.0, 0.0, 0.0, 0.0
            for k in range(3):
                c = cols[j, k]
                if c < 0:
                    continue
                h = 0.5 * scale * table[f, c]
                ew = np.cos(h)
                s = np.sin(h)
                ex = s if axis_id[j, k] == 0 else 0.0
                ey = s if axis_id[j, k] == 1 else 0.0
                ez = s if axis_id[j, k] == 2 else 0.0
                if extrinsic:
                    mw, mx, my, mz = _qmul(ew, ex, ey, ez, mw, mx, my, mz)
                else:
                    mw, mx, my, mz = _qmul(mw, mx, my, mz, ew, ex, ey, ez)
            # C M C^-1
            aw, ax, ay, az = _qmul(cw, cx, cy, cz, mw, mx, my, mz)
            rw, rx, ry, rz = _qmul(aw, ax, ay, az, cw, -cx, -cy, -cz)
            out[f, j, 0] = rw
            out[f, j, 1] = rx
            out[f, j, 2] = ry
            out[f, j, 3] = rz
    return out
