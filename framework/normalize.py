"""Motion geometry several built-in packages share: facing direction, root frame, facing
alignment and resampling (arrays, broadcast over frames)."""

from __future__ import annotations

import numpy as np

from . import quaternions as quat
from .errors import DataError
from .joints import CANONICAL_JOINTS
from .motion import Motion

UP = np.array([0.0, 1.0, 0.0])


def facing_angles(positions: np.ndarray, joints: tuple[str, ...] | list[str] = CANONICAL_JOINTS) -> np.ndarray:
    """Heading (T,) radians about +y (rotating by ``-a`` faces +z) of canonical positions
    (T, K, 3) named by ``joints``: the direction ``(lhip - rhip) x up``."""
    j = list(joints)
    across = positions[:, j.index("lhip")] - positions[:, j.index("rhip")]
    fwd = np.cross(across, UP)
    return np.arctan2(fwd[:, 0], fwd[:, 2])


def rotate_about_y(v: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (T, ..., 3)`` by ``angle (T,)`` radians about +y."""
    c = np.cos(angle).reshape((-1,) + (1,) * (v.ndim - 2))
    s = np.sin(angle).reshape((-1,) + (1,) * (v.ndim - 2))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([c * x + s * z, y, -s * x + c * z], axis=-1)


def to_root_frame(
    positions: np.ndarray, joints: tuple[str, ...] | list[str] = CANONICAL_JOINTS, root: str = "root"
) -> np.ndarray:
    """Positions (T, K, 3) metres with the root at the origin and facing +z (heights kept,
    as in Krüger et al. 2010 §3)."""
    j = list(joints)
    r = positions[:, j.index(root)]
    centred = positions - r[:, None, :]
    return rotate_about_y(centred, -facing_angles(positions, joints))


def align_facing(motion: Motion) -> Motion:
    """Motion rotated about +y per frame so that it always faces +z, root over the origin."""
    pos = motion.canonical_positions()
    angle = facing_angles(pos)
    turn = quat.from_axis_angle(np.broadcast_to(UP, (len(angle), 3)), -angle)
    rot = motion.rotations.copy()
    rot[:, 0] = quat.mul(turn, rot[:, 0])
    root = np.zeros_like(motion.root_translation)
    root[:, 1] = motion.root_translation[:, 1]
    return motion.with_arrays(rotations=rot, root_translation=root)


def resample(motion: Motion, fps: float) -> Motion:
    """Resample to ``fps`` (slerp rotations, lerp translations) at ``k / fps`` seconds up to
    the last frame's time (the clip never grows past it)."""
    if fps <= 0:
        raise DataError(f"target fps must be positive, got {fps}")
    if abs(fps - motion.fps) < 1e-9 or motion.n_frames < 2:
        return motion.with_arrays(fps=fps)
    span = (motion.n_frames - 1) / motion.fps
    n = int(np.floor(span * fps + 1e-9)) + 1
    src = np.arange(n) * (motion.fps / fps)
    i0 = np.minimum(np.floor(src).astype(np.int64), motion.n_frames - 1)
    i1 = np.minimum(i0 + 1, motion.n_frames - 1)
    w = src - i0
    rot = quat.slerp(motion.rotations[i0], motion.rotations[i1], np.broadcast_to(w[:, None], (n, motion.n_joints)))
    root = (1 - w)[:, None] * motion.root_translation[i0] + w[:, None] * motion.root_translation[i1]
    lt = None
    if motion.local_translations is not None:
        lt = (1 - w)[:, None, None] * motion.local_translations[i0] + w[:, None, None] * motion.local_translations[i1]
    meta = dict(motion.metadata)
    meta.setdefault("source_fps", motion.fps)
    meta.setdefault("source_frames", motion.n_frames)
    return motion.with_arrays(rotations=rot, root_translation=root, local_translations=lt, fps=fps, metadata=meta)
