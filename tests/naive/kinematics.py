"""Per-frame, per-joint forward kinematics with rotation matrices (scipy), the reference
for the vectorised quaternion FK."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


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
