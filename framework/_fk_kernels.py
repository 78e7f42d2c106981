"""Compiled forward-kinematics kernel (numba). No validation here: see motion.forward_kinematics."""

from __future__ import annotations

import numpy as np
from numba import njit


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (no copy): numba compiles one variant per writeable flag, so
    the arguments a kernel only reads are always passed read-only (Arrow columns are)."""
    v: np.ndarray = a.view()
    v.flags.writeable = False
    return v


@njit(cache=True, fastmath=False)
def fk_kernel(  # pragma: no cover - compiled
    parents: np.ndarray,
    offsets: np.ndarray,
    per_frame_offsets: np.ndarray,
    root_translation: np.ndarray,
    rotations: np.ndarray,
    pos: np.ndarray,
    glob: np.ndarray,
) -> None:
    """Fill ``pos (T,J,3)`` and ``glob (T,J,4)``.

    ``per_frame_offsets`` is ``(T,J,3)`` or ``(0,0,3)`` to use the static ``offsets (J,3)``.
    """
    t_count, j_count = rotations.shape[0], rotations.shape[1]
    use_frame = per_frame_offsets.shape[0] > 0
    for t in range(t_count):
        pos[t, 0, 0] = root_translation[t, 0]
        pos[t, 0, 1] = root_translation[t, 1]
        pos[t, 0, 2] = root_translation[t, 2]
        for c in range(4):
            glob[t, 0, c] = rotations[t, 0, c]
        for j in range(1, j_count):
            p = parents[j]
            w, x, y, z = glob[t, p, 0], glob[t, p, 1], glob[t, p, 2], glob[t, p, 3]
            if use_frame:
                ox, oy, oz = per_frame_offsets[t, j, 0], per_frame_offsets[t, j, 1], per_frame_offsets[t, j, 2]
            else:
                ox, oy, oz = offsets[j, 0], offsets[j, 1], offsets[j, 2]
            # v' = v + w t + u x t, with t = 2 u x v
            tx = 2.0 * (y * oz - z * oy)
            ty = 2.0 * (z * ox - x * oz)
            tz = 2.0 * (x * oy - y * ox)
            pos[t, j, 0] = pos[t, p, 0] + ox + w * tx + (y * tz - z * ty)
            pos[t, j, 1] = pos[t, p, 1] + oy + w * ty + (z * tx - x * tz)
            pos[t, j, 2] = pos[t, p, 2] + oz + w * tz + (x * ty - y * tx)
            bw, bx, by, bz = rotations[t, j, 0], rotations[t, j, 1], rotations[t, j, 2], rotations[t, j, 3]
            glob[t, j, 0] = w * bw - x * bx - y * by - z * bz
            glob[t, j, 1] = w * bx + x * bw + y * bz - z * by
            glob[t, j, 2] = w * by - x * bz + y * bw + z * bx
            glob[t, j, 3] = w * bz + x * by - y * bx + z * bw


def fk(
    parents: np.ndarray,
    offsets: np.ndarray,
    root_translation: np.ndarray,
    rotations: np.ndarray,
    local_translations: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray]:
    t, j = rotations.shape[:2]
    pos = np.empty((t, j, 3))
    glob = np.empty((t, j, 4))
    per_frame = (
        np.zeros((0, 0, 3))
        if local_translations is None
        else np.ascontiguousarray(local_translations, dtype=np.float64)
    )
    fk_kernel(
        readonly(np.ascontiguousarray(parents, dtype=np.int64)),
        readonly(np.ascontiguousarray(offsets, dtype=np.float64)),
        readonly(per_frame),
        readonly(np.ascontiguousarray(root_translation, dtype=np.float64)),
        readonly(np.ascontiguousarray(rotations, dtype=np.float64)),
        pos,
        glob,
    )
    return pos, glob
