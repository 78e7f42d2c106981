"""Numba kernels of the format readers (no validation; the readers validate).

The slow, obviously correct twins are in ``tests/naive/formats.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _qmul(aw, ax, ay, az, bw, bx, by, bz):
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


@njit(cache=True)
def euler_table_to_quat(table, cols, axis_id, frames, scale, extrinsic):
    """Joint rotations from a table of Euler angles.

    Parameters
    ----------
    table : ndarray of shape (T, W)
        Values as read from the file, one row per frame.
    cols : ndarray of int64, shape (J, 3)
        Column of the k-th listed rotation channel of joint j, ``-1`` if the joint has
        fewer (zero angle).
    axis_id : ndarray of int64, shape (J, 3)
        Axis (0=x, 1=y, 2=z) of each listed channel.
    frames : ndarray of shape (J, 4)
        Per-joint frame rotation ``C`` (w, x, y, z); the result is ``C M C^-1``.
    scale : float
        Radians per table unit (pi/180 for degrees).
    extrinsic : bool
        True: channels are rotations about fixed axes in listed order (``M = R3 R2 R1``,
        Acclaim); False: intrinsic in listed order (``M = R1 R2 R3``, BVH).

    Returns
    -------
    ndarray of shape (T, J, 4)
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
