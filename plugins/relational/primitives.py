"""Generic geometric primitives of relational features (Müller, Röder, Clausen 2005, §3).

Every function works on arrays of points broadcast over frames, ``(..., 3)`` in metres,
y up, and returns a real-valued quantity (a signed distance, a distance, an angle or a
speed); thresholding into booleans is a separate step (:func:`threshold`). Nothing here knows about joints: the feature
table in :mod:`.relational` picks the joints.

Conventions
-----------
plane through three points
    ``<p1, p2, p3>`` is oriented by point order: its normal is
    ``(p2 - p1) x (p3 - p1)`` (right-handed); a point lies *in front* when its signed
    distance is positive. Eq. (1) of the paper is ``plane_distance(...) >= 0``.
plane given by a normal
    The normal runs from joint ``a`` to joint ``b`` (or is a fixed direction) and the
    plane passes through an anchor point; the signed distance is positive on the side the
    normal points to.
"""

from __future__ import annotations

from types import ModuleType
from typing import cast

import numpy as np

from mocapflow.framework.errors import DataError


def _points(*arrays: np.ndarray) -> tuple[tuple[np.ndarray, ...], tuple[int, ...]]:
    """Broadcast point arrays ``(..., 3)`` to a common shape and flatten to ``(N, 3)`` float32."""
    arrs = [np.asarray(a, dtype=np.float32) for a in arrays]
    for a in arrs:
        if a.ndim == 0 or a.shape[-1] != 3:
            raise DataError(f"points must have shape (..., 3), got {a.shape}")
    shape = np.broadcast_shapes(*(a.shape for a in arrs))
    return tuple(np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1, 3) for a in arrs), shape[:-1]


def _scalars(x: float | np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    return np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=np.float32), shape)).reshape(-1)


def _k() -> ModuleType:
    # numba is imported lazily, on the first feature computation, never at start-up
    from . import _feature_kernels as _relational_kernels

    return _relational_kernels


def plane_distance(
    p1: np.ndarray, p2: np.ndarray, p3: np.ndarray, q: np.ndarray, offset: float | np.ndarray = 0.0
) -> np.ndarray:
    """Signed distance (..., float32, metres) of ``q`` from the oriented plane through
    ``p1, p2, p3`` (all (..., 3), metres), minus ``offset`` (metres, broadcasting): the plane
    moved along its normal (the paper moves "hand in front" one humerus length forward), so
    the result is ``>= 0`` iff ``q`` lies in front of or on it. NaN where a point is NaN;
    collinear points give ``-offset``."""
    (a, b, c, d), shape = _points(p1, p2, p3, q)
    out = np.empty(len(a), np.float32)
    _k().plane_distance(a, b, c, d, _scalars(offset, shape), out)
    return out.reshape(shape)


def normal_plane_distance(
    a: np.ndarray, b: np.ndarray, anchor: np.ndarray, q: np.ndarray, offset: float | np.ndarray = 0.0
) -> np.ndarray:
    """Signed distance of ``q`` from the plane with normal ``b - a`` through ``anchor``, minus ``offset``.

    ``a`` and ``b`` may be joints (..., 3) or a fixed direction ``a = (0, 0, 0), b = direction``.
    Returns float32 (...,) metres, positive on the side the normal points to.
    """
    (x, y, z, w), shape = _points(a, b, anchor, q)
    out = np.empty(len(x), np.float32)
    _k().normal_plane_distance(x, y, z, w, _scalars(offset, shape), out)
    return out.reshape(shape)


def point_segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance of point ``q`` from the segment ``[a, b]``, float32 (...,), metres."""
    (x, y, z), shape = _points(q, a, b)
    out = np.empty(len(x), np.float32)
    _k().point_segment_distance(x, y, z, out)
    return out.reshape(shape)


def segment_segment_distance(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Smallest distance between the segments ``[a0, a1]`` and ``[b0, b1]``, float32 (...,), metres.

    Closed form (clamped parameters of the closest points of the two lines) completed by
    the four endpoint-to-segment distances, which makes it exact also for parallel and
    degenerate (point) segments.
    """
    (w, x, y, z), shape = _points(a0, a1, b0, b1)
    out = np.empty(len(w), np.float32)
    _k().segment_segment_distance(w, x, y, z, out)
    return out.reshape(shape)


def cos_between(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Cosine of the angle between the directions ``a1 - a0`` and ``b1 - b0``, float32 (...,).

    Thresholding the cosine (``angle < theta`` iff ``cos > cos(theta)``) is what the
    features do; :func:`angle_between` gives degrees.
    """
    (w, x, y, z), shape = _points(a0, a1, b0, b1)
    out = np.empty(len(w), np.float32)
    _k().cos_between(w, x, y, z, out)
    return out.reshape(shape)


def angle_between(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Angle in degrees between the directions ``a1 - a0`` and ``b1 - b0``, float32 (...,).

    The knee angle is ``angle_between(knee, hip, knee, ankle)``: 180 for a straight leg.
    """
    return cast("np.ndarray", np.degrees(np.arccos(cos_between(a0, a1, b0, b1))))


def min_height(positions: np.ndarray) -> np.ndarray:
    """Lowest y (T,) float32 over the joints of each frame of ``positions`` (T, J, 3), metres,
    ignoring NaN joints (NaN where every joint is NaN)."""
    p = np.asarray(positions)
    if p.ndim != 3 or p.shape[2] != 3:
        raise DataError(f"positions must be (T, J, 3), got {p.shape}")
    out = np.empty(p.shape[0], np.float32)
    _k().min_height(p, out)
    return out


def clip_starts(offsets: np.ndarray, n_frames: int) -> np.ndarray:
    """Boolean mask of shape (n_frames,), True at the first frame of each non-empty clip."""
    offsets = np.asarray(offsets, dtype=np.int64)
    if len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != n_frames or np.any(np.diff(offsets) < 0):
        raise DataError(f"clip offsets must rise from 0 to {n_frames}")
    mask = np.zeros(n_frames, dtype=bool)
    starts = offsets[:-1][np.diff(offsets) > 0]
    mask[starts] = True
    return mask


def speed(
    p: np.ndarray, fps: float, offsets: np.ndarray | None = None, reference: np.ndarray | None = None
) -> np.ndarray:
    """Speed of a point, metres per second, never differencing across clip boundaries.

    Central differences inside a clip, one-sided differences at a clip's first and last
    frame, 0 for one-frame clips.

    ``p`` (T, 3), metres: the trajectory of one or several concatenated clips, split at
    ``offsets`` (n_clips + 1,) (default one clip); with ``reference`` (T, 3) the speed of
    ``p - reference``. Returns (T,) float32, m/s.
    """
    x = np.asarray(p, dtype=np.float32)
    if reference is not None:
        x = x - np.asarray(reference, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != 3:
        raise DataError(f"trajectory must be (T, 3), got {x.shape}")
    t = x.shape[0]
    starts = clip_starts(np.array([0, t]) if offsets is None else offsets, t)
    out = np.empty(t, np.float32)
    _k().speed(np.ascontiguousarray(x), starts, float(fps), out)
    return out


def threshold(value: np.ndarray, thresh: float | np.ndarray, below: bool = False) -> np.ndarray:
    """``value >= thresh`` (or ``value < thresh`` when ``below``); NaN gives False."""
    with np.errstate(invalid="ignore"):
        return (value < thresh) if below else (value >= thresh)
