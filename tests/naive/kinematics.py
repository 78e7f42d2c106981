"""Per-frame, per-joint forward kinematics with rotation matrices (scipy), the reference
for the vectorised quaternion FK."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapflow.framework import quaternions as quat


def fk_loop(parents, offsets, root_translation, rotations):
    """positions (T, J, 3) by an explicit loop over frames and joints."""
    t_count, j_count = rotations.shape[:2]
    out = np.zeros((t_count, j_count, 3))
    for t in range(t_count):
        world = [None] * j_count
        for j in range(j_count):
            # scipy uses (x, y, z, w)
            r = Rotation.from_quat(np.roll(rotations[t, j], -1)).as_matrix()
            if parents[j] < 0:
                world[j] = r
                out[t, j] = root_translation[t]
            else:
                p = parents[j]
                out[t, j] = out[t, p] + world[p] @ offsets[j]
                world[j] = world[p] @ r
    return out


def euler_matrix(angles_deg, order):
    """R = R_order[0] @ R_order[1] @ ... from degrees, built with explicit matrices."""
    m = np.eye(3)
    for a, axis in zip(np.deg2rad(angles_deg), order.lower(), strict=True):
        c, s = np.cos(a), np.sin(a)
        if axis == "x":
            r = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        elif axis == "y":
            r = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        else:
            r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        m = m @ r
    return m


def forward_kinematics_numpy(
    skeleton,
    root_translation,
    rotations,
    local_translations=None,
):
    """positions and world rotations with one batched quaternion operation per joint."""
    t, j = rotations.shape[:2]
    pos = np.empty((t, j, 3))
    glob = np.empty((t, j, 4))
    pos[:, 0] = root_translation
    glob[:, 0] = rotations[:, 0]
    for k in range(1, j):
        p = skeleton.parents[k]
        off = skeleton.offsets[k] if local_translations is None else local_translations[:, k]
        pos[:, k] = pos[:, p] + quat.rotate(glob[:, p], np.broadcast_to(off, (t, 3)))
        glob[:, k] = quat.mul(glob[:, p], rotations[:, k])
    return pos, glob
