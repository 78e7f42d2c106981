"""Generic geometric primitives of relational features (Müller, Röder, Clausen 2005, §3).

Every function works on arrays of points broadcast over frames, ``(..., 3)`` in metres,
y up, and returns a real-valued quantity (a signed distance, a distance, an angle or a
speed); thresholding into booleans (optionally with hysteresis) is a separate step
(:func:`threshold`, :func:`hysteresis`). Nothing here knows about joints: the feature
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

import numpy as np

_EPS = 1e-12


def _normalize(v: np.ndarray) -> np.ndarray:
    n = np.sqrt(np.einsum("...i,...i->...", v, v))
    return v / np.maximum(n, _EPS)[..., None]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def plane_distance(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray, q: np.ndarray,
                   offset: float | np.ndarray = 0.0) -> np.ndarray:
    """Signed distance of ``q`` from the oriented plane through ``p1, p2, p3``, minus ``offset``.

    Parameters
    ----------
    p1, p2, p3, q : ndarray of shape (..., 3), metres
    offset : float or ndarray broadcasting to (...,), metres
        Moves the plane along its normal (the paper moves the "hand in front" plane one
        humerus length to the front), so the result is ``>= 0`` iff ``q`` lies in front of
        or on the moved plane.

    Returns
    -------
    ndarray of shape (...,), metres
        NaN where a point is NaN; degenerate planes (collinear points) give 0 - offset.
    """
    n = _normalize(np.cross(p2 - p1, p3 - p1))
    return _dot(q - p1, n) - offset


def normal_plane_distance(a: np.ndarray, b: np.ndarray, anchor: np.ndarray, q: np.ndarray,
                          offset: float | np.ndarray = 0.0) -> np.ndarray:
    """Signed distance of ``q`` from the plane with normal ``b - a`` through ``anchor``, minus ``offset``.

    ``a`` and ``b`` may be joints (shape (..., 3)) or a fixed direction can be given as
    ``a = 0, b = direction``.

    Returns
    -------
    ndarray of shape (...,), metres
        Positive on the side the normal points to.
    """
    n = _normalize(np.broadcast_to(b - a, np.broadcast_shapes(np.shape(b - a), np.shape(q))))
    return _dot(q - anchor, n) - offset


def point_segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance of point ``q`` from the segment ``[a, b]``, shape (...,), metres."""
    ab = b - a
    t = np.clip(_dot(q - a, ab) / np.maximum(_dot(ab, ab), _EPS), 0.0, 1.0)
    d = q - (a + t[..., None] * ab)
    return np.sqrt(_dot(d, d))


def segment_segment_distance(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Smallest distance between the segments ``[a0, a1]`` and ``[b0, b1]``, shape (...,), metres.

    Closed form (clamped parameters of the closest points), vectorised; exact also for
    parallel and degenerate (point) segments because the clamped candidate pairs include
    every endpoint-to-segment distance.
    """
    u, v, w = a1 - a0, b1 - b0, a0 - b0
    a, b, c, d, e = _dot(u, u), _dot(u, v), _dot(v, v), _dot(u, w), _dot(v, w)
    den = a * c - b * b
    # interior candidate: closest points of the infinite lines, clamped to the segments
    s = np.clip(np.where(den > _EPS, (b * e - c * d) / np.maximum(den, _EPS), 0.0), 0.0, 1.0)
    t = np.clip(np.where(c > _EPS, (b * s + e) / np.maximum(c, _EPS), 0.0), 0.0, 1.0)
    s = np.clip(np.where(a > _EPS, (b * t - d) / np.maximum(a, _EPS), 0.0), 0.0, 1.0)
    diff = w + s[..., None] * u - t[..., None] * v
    best = np.sqrt(_dot(diff, diff))
    # endpoint candidates make the result exact where the alternating clamp is not
    for dist in (point_segment_distance(a0, b0, b1), point_segment_distance(a1, b0, b1),
                 point_segment_distance(b0, a0, a1), point_segment_distance(b1, a0, a1)):
        best = np.fmin(best, dist)
    return best


def angle_between(a0: np.ndarray, a1: np.ndarray, b0: np.ndarray, b1: np.ndarray) -> np.ndarray:
    """Angle in degrees between the directions ``a1 - a0`` and ``b1 - b0``, shape (...,).

    The knee angle is ``angle_between(knee, hip, knee, ankle)``: 180 for a straight leg.
    """
    cos = _dot(_normalize(a1 - a0), _normalize(b1 - b0))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def clip_starts(offsets: np.ndarray, n_frames: int) -> np.ndarray:
    """Boolean mask of shape (n_frames,), True at the first frame of each non-empty clip."""
    offsets = np.asarray(offsets, dtype=np.int64)
    mask = np.zeros(n_frames, dtype=bool)
    starts = offsets[:-1][np.diff(offsets) > 0]
    mask[starts] = True
    return mask


def speed(p: np.ndarray, fps: float, offsets: np.ndarray | None = None,
          reference: np.ndarray | None = None) -> np.ndarray:
    """Speed of a point, metres per second, never differencing across clip boundaries.

    Central differences inside a clip, one-sided differences at a clip's first and last
    frame, 0 for one-frame clips.

    Parameters
    ----------
    p : ndarray of shape (T, 3), metres
        Trajectory of all frames of one or several concatenated clips.
    fps : float
    offsets : ndarray of int, shape (n_clips + 1,), optional
        Clip offsets (``MotionDatabase.offsets``); default one clip.
    reference : ndarray of shape (T, 3), optional
        Speed relative to this point (``p - reference`` is differentiated).

    Returns
    -------
    ndarray of shape (T,), m/s
    """
    x = p if reference is None else p - reference
    t = x.shape[0]
    if offsets is None:
        offsets = np.array([0, t])
    if t == 0:
        return np.zeros(0)
    starts = clip_starts(offsets, t)
    ends = np.zeros(t, dtype=bool)
    ends[:-1] = starts[1:]
    ends[-1] = True
    prev = np.empty_like(x)
    prev[1:] = x[:-1]
    prev[0] = x[0]
    prev[starts] = x[starts]
    nxt = np.empty_like(x)
    nxt[:-1] = x[1:]
    nxt[-1] = x[-1]
    nxt[ends] = x[ends]
    steps = 2.0 - starts - ends  # frames spanned by the difference (0 for 1-frame clips)
    d = np.sqrt(_dot(nxt - prev, nxt - prev))
    return np.where(steps > 0, d * fps / np.maximum(steps, 1), 0.0)


def threshold(value: np.ndarray, thresh: float | np.ndarray, below: bool = False) -> np.ndarray:
    """``value >= thresh`` (or ``value < thresh`` when ``below``); NaN gives False."""
    with np.errstate(invalid="ignore"):
        return (value < thresh) if below else (value >= thresh)


def hysteresis(on: np.ndarray, stay: np.ndarray, offsets: np.ndarray | None = None) -> np.ndarray:
    """Two-threshold (Schmitt trigger) booleans, vectorised over frames and features.

    The output switches to True where ``on`` (the stricter test) holds, to False where
    ``stay`` (the laxer test) fails, and otherwise keeps its previous value; each clip starts
    False unless ``on`` holds. ``on`` must imply ``stay``.

    Parameters
    ----------
    on, stay : ndarray of bool, shape (T,) or (T, f)
    offsets : ndarray of int, shape (n_clips + 1,), optional

    Returns
    -------
    ndarray of bool, same shape
    """
    on = np.asarray(on, dtype=bool)
    stay = np.asarray(stay, dtype=bool)
    t = on.shape[0]
    if t == 0:
        return on.copy()
    if offsets is None:
        offsets = np.array([0, t])
    starts = clip_starts(offsets, t)
    decided = on | ~stay
    decided |= starts.reshape((-1,) + (1,) * (on.ndim - 1))
    idx = np.where(decided, np.arange(t).reshape((-1,) + (1,) * (on.ndim - 1)), 0)
    np.maximum.accumulate(idx, axis=0, out=idx)
    return np.take_along_axis(on, idx, axis=0) if on.ndim > 1 else on[idx]


__all__ = ["angle_between", "clip_starts", "hysteresis", "normal_plane_distance", "plane_distance",
           "point_segment_distance", "segment_segment_distance", "speed", "threshold"]
