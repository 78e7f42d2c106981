"""Pose distance measures compared by Krüger et al. 2010 §3.1 (Fig. 2).

Each measure compares one frame ``i`` of a :class:`PoseMeasures` database with many frames
``js`` at once (arrays, no per-frame objects):

``D_quat``
    Joint angles as quaternions [CH05]: ``sqrt(sum_j angle(q_i,j, q_js,j)^2)`` over every
    non-root joint with rotation channels, ``angle`` the geodesic angle (radians, sign
    invariant). The root is left out: its heading is what every feature normalises away.
``D_euler``
    The same joints as Euler angles "in the standard asf/amc representation": the AMC dof
    values (radians; for BVH skeletons the file's channel order), Euclidean distance
    without wrapping (the representation is the point: it suffers from gimbal effects).
``D_pc<n>``
    Kovar–Gleicher point-cloud distance over a window of ``n`` frames centred on the
    frame (``n // 2`` before and after, clamped at clip edges): the world positions of the
    joints in the window, optimally aligned by a rotation about the vertical axis and a
    ground-plane translation (closed form), then the root of the summed squared distances
    (metres). ``D_pc1`` and ``D_pc11`` are the paper's.
``D_wb``
    Wang–Bodenheimer weighted joint-angle and joint-velocity distance [WB03, LCR*02]:
    ``sqrt(sum_j w_j angle_j^2 + velocity_weight * sum_j w_j |omega_i,j - omega_js,j|^2)``
    over hips, knees, shoulders and elbows (the joints with non-zero optimised weights,
    as the paper states; the optimised values are not given there, so ``w_j = 1``);
    ``omega`` the local angular velocity (rad/s, forward difference, last frame repeats).
"""

from __future__ import annotations

import re
from typing import cast

import numpy as np

from mocapflow.framework import MotionDatabase
from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion

from .pca import PCA_JOINTS

WB_JOINTS = ("lhip", "rhip", "lknee", "rknee", "lshoulder", "rshoulder", "lelbow", "relbow")
PC_JOINTS = ("root", *PCA_JOINTS)
DISTANCE_MEASURES = ("D_quat", "D_euler", "D_pc1", "D_pc11", "D_wb")


def angle_joints(motion: Motion) -> np.ndarray:
    """Indices of the non-root joints that have rotation channels (all non-root joints if none listed)."""
    sk = motion.skeleton
    if not sk.channels:
        return np.arange(1, sk.n_joints)
    return np.array([j for j in range(1, sk.n_joints) if any(c[0].upper() == "R" for c in sk.channels[j])], np.int64)


def euler_dofs(motion: Motion) -> np.ndarray:
    """The motion's joint angles as in its file (AMC dofs / BVH channels), radians, shape (T, n_dofs)."""
    from mocapflow.framework.quaternions import euler_extrinsic_inverse

    sk = motion.skeleton
    cols = []
    for j in angle_joints(motion):
        q = motion.rotations[:, j]
        if sk.axes is not None and sk.channels:  # ASF: dofs act in the bone's axis frame C
            c = sk.axes[j]
            order = "".join(ch[1].lower() for ch in sk.channels[j] if ch[0].lower() == "r")
            cols.append(euler_extrinsic_inverse(quat.mul(quat.mul(quat.conjugate(c), q), c), order, degrees=False))
        else:
            cols.append(quat.to_euler(q, sk.rotation_orders[j] or "zxy", degrees=False))
    return np.concatenate(cols, axis=1) if cols else np.zeros((motion.n_frames, 0))


def angular_velocity(motion: Motion, joints: np.ndarray) -> np.ndarray:
    """Local angular velocity (rad/s) of ``joints``, shape (T, len(joints), 3); forward difference."""
    q = motion.rotations[:, joints]
    if motion.n_frames < 2:
        return np.zeros(q.shape[:2] + (3,))
    rel = quat.mul(quat.conjugate(q[:-1]), q[1:])
    rel = np.where(rel[..., :1] < 0, -rel, rel)
    angle = 2.0 * np.arccos(np.clip(rel[..., 0], -1.0, 1.0))
    s = np.linalg.norm(rel[..., 1:], axis=-1, keepdims=True)
    axis = np.where(s > 1e-12, rel[..., 1:] / np.where(s > 1e-12, s, 1.0), 0.0)
    w = axis * angle[..., None] * motion.fps
    return np.concatenate([w, w[-1:]], axis=0)


class PoseMeasures:
    """Per-frame representations of a database for the distance measures (see module doc).

    Parameters
    ----------
    db : MotionDatabase
        All clips must share joint names (angles are compared joint by joint).
    velocity_weight : float
        Weight of the joint-velocity term of ``D_wb`` (s^2).
    """

    def __init__(self, db: MotionDatabase, velocity_weight: float = 0.01) -> None:
        if db.n_clips == 0:
            raise DataError("distance measures need at least one clip")
        names = {m.skeleton.names for m in db.motions}
        if len(names) != 1:
            raise DataError(
                f"joint-angle distances need clips with the same joint names; got {len(names)} skeleton layouts"
            )
        self.db = db
        self.velocity_weight = velocity_weight
        m0 = db.motions[0]
        aj = angle_joints(m0)
        wb = m0.skeleton.canonical_indices(WB_JOINTS)
        if np.any(wb < 0):
            raise DataError(f"D_wb needs canonical joints {WB_JOINTS}")
        self.quats = np.concatenate([m.rotations[:, aj] for m in db.motions])
        self.euler = np.concatenate([euler_dofs(m) for m in db.motions])
        self.wb_quats = np.concatenate([m.rotations[:, wb] for m in db.motions])
        self.wb_vel = np.concatenate([angular_velocity(m, wb) for m in db.motions])
        self.points = np.concatenate([m.canonical_positions(PC_JOINTS) for m in db.motions]).astype(np.float32)
        if not np.isfinite(self.points).all():
            raise DataError(f"D_pc needs canonical joints {PC_JOINTS}")
        pos = db.frame_clip_index
        self._first = db.offsets[pos]
        self._last = db.offsets[pos + 1] - 1

    def window_rows(self, rows: np.ndarray, n: int) -> np.ndarray:
        """Global frame ids of the ``n``-frame windows centred on ``rows``, clamped to their clips, (m, n)."""
        rows = np.asarray(rows, np.int64)
        off = np.arange(n) - n // 2
        return np.clip(rows[:, None] + off[None, :], self._first[rows][:, None], self._last[rows][:, None])

    def distance(self, measure: str, i: int, js: np.ndarray) -> np.ndarray:
        """Distances of frame ``i`` to frames ``js``, shape (len(js),), float64."""
        js = np.asarray(js, np.int64)
        if measure == "D_quat":
            return cast("np.ndarray", np.sqrt((quat.geodesic_angle(self.quats[i][None], self.quats[js]) ** 2).sum(1)))
        if measure == "D_euler":
            return cast("np.ndarray", np.linalg.norm(self.euler[js] - self.euler[i][None], axis=1))
        if measure == "D_wb":
            ang = (quat.geodesic_angle(self.wb_quats[i][None], self.wb_quats[js]) ** 2).sum(1)
            vel = ((self.wb_vel[js] - self.wb_vel[i][None]) ** 2).sum((1, 2))
            return cast("np.ndarray", np.sqrt(ang + self.velocity_weight * vel))
        m = re.fullmatch(r"D_pc(\d+)", measure)
        if m:
            n = int(m.group(1))
            a = self.points[self.window_rows(np.array([i]), n)].reshape(1, -1, 3)
            b = self.points[self.window_rows(js, n)].reshape(len(js), -1, 3)
            return point_cloud_distance(a, b)
        raise DataError(f"unknown distance measure {measure!r} (known: {', '.join(DISTANCE_MEASURES)}, D_pc<n>)")


def point_cloud_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Kovar–Gleicher distance between point clouds after the best rigid 2D alignment about +y.

    Parameters
    ----------
    a, b : ndarray of shape (m, P, 3), metres (broadcasting over m)

    Returns
    -------
    ndarray of shape (m,)
        ``min over theta, (x0, z0) of sqrt(sum_p |a_p - (R_y(theta) b_p + (x0, 0, z0))|^2)``.
    """
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    # ground-plane coordinates as complex numbers: a rotation about y multiplies by e^{i phi}
    ca = a[..., 0] + 1j * a[..., 2]
    cb = b[..., 0] + 1j * b[..., 2]
    ca = ca - ca.mean(-1, keepdims=True)  # the optimal translation matches the centroids
    cb = cb - cb.mean(-1, keepdims=True)
    s = (ca * np.conj(cb)).sum(-1)
    # min_phi sum |ca - e^{i phi} cb|^2 = sum |ca|^2 + sum |cb|^2 - 2 |sum ca conj(cb)|
    plane = (np.abs(ca) ** 2).sum(-1) + (np.abs(cb) ** 2).sum(-1) - 2.0 * np.abs(s)
    height = ((a[..., 1] - b[..., 1]) ** 2).sum(-1)
    return cast("np.ndarray", np.sqrt(np.maximum(plane + height, 0.0)))
