"""Kinematic helpers of the calibrated cleaner's detectors (:mod:`.detectors`) and repairs:
speed, acceleration (angle of a frame to its neighbours' midpoint), holds, windowed minima
and medians, and the left/right mirror of limb chains (swaps)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import numpy as np

from mocapflow.framework import quaternions as quat

from .constants import HOLD_SPEED

#: Limb chains whose left/right exchange the mirror cue looks for (canonical names).
MIRROR_CHAINS: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = (
    (("lshoulder", "lelbow", "lwrist"), ("rshoulder", "relbow", "rwrist")),
    (("lhip", "lknee", "lankle"), ("rhip", "rknee", "rankle")),
)


def mirror(q: np.ndarray) -> np.ndarray:
    """Mirror local rotations across the sagittal (y-z) plane: (w, x, y, z) -> (w, x, -y, -z)."""
    out = np.array(q, dtype=float, copy=True)
    out[..., 2:] *= -1.0
    return out


def acceleration(q: np.ndarray) -> np.ndarray:
    """Angle between each frame and the midpoint of its two neighbours, radians, (T, m); 0 at the ends."""
    out = np.zeros(q.shape[:2])
    if len(q) >= 3:
        mid = quat.slerp(q[:-2], q[2:], np.full(q[1:-1].shape[:-1], 0.5))
        out[1:-1] = quat.geodesic_angle(q[1:-1], mid)
    return out


def _window_mean(x: np.ndarray, half: int) -> np.ndarray:
    """Mean over ``[t - half, t + half]`` along time (shrunk at the ends)."""
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    t = np.arange(len(x))
    lo, hi = np.maximum(t - half, 0), np.minimum(t + half + 1, len(x))
    return cast("np.ndarray", (c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1)))


def speed(q: np.ndarray) -> np.ndarray:
    """Frame-to-frame rotation angle, radians per frame, (T, m) (the last frame repeats)."""
    if len(q) < 2:
        return np.zeros(q.shape[:2])
    v = quat.geodesic_angle(q[1:], q[:-1])
    return np.concatenate([v, v[-1:]], axis=0)


def chain_columns(joints: Sequence[str]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Texture columns (left, right) of each :data:`MIRROR_CHAINS` pair present in ``joints``."""
    out = []
    for left, right in MIRROR_CHAINS:
        if all(j in joints for j in left + right):
            out.append((np.array([joints.index(j) for j in left]), np.array([joints.index(j) for j in right])))
    return out


def mirror_gain(
    q: np.ndarray, mean_q: np.ndarray, joints: Sequence[str], joint_margin: float = np.deg2rad(5.0)
) -> np.ndarray:
    """Per frame and chain joint: summed over the chain pair, the digression minus the angle
    to the mirrored consensus of the counterpart (radians; > 0 where swapping back brings the
    limbs nearer their consensus), kept on the joints that themselves gain more than
    ``joint_margin`` (a joint that looks the same mirrored carries no evidence). 0 on joints
    outside the chains."""
    out = np.zeros(q.shape[:2])
    for lc, rc in chain_columns(list(joints)):
        cols = np.concatenate([lc, rc])
        other = np.concatenate([rc, lc])
        own = quat.geodesic_angle(q[:, cols], mean_q[:, cols])
        swapped = quat.geodesic_angle(q[:, cols], mirror(mean_q[:, other]))
        gain = own - swapped
        out[:, cols] = np.where(gain > joint_margin, gain.sum(1, keepdims=True), 0.0)
    return out


def hold_lengths(v: np.ndarray, still: float = HOLD_SPEED) -> tuple[np.ndarray, np.ndarray]:
    """Per cell of the speeds ``v`` (T, m) (:func:`speed`), the frames of the hold holding it
    (a frame is held when the step into or out of it is slower than ``still`` rad/frame; 0
    outside holds), and whether that hold touches the first or the last frame (bool)."""
    calm = v < still  # step t -> t+1 still (speed() repeats the last step into the last frame)
    held = calm.copy()
    held[1:] |= calm[:-1]
    length = np.zeros(v.shape, float)
    edge = np.zeros(v.shape, bool)
    t = len(v)
    for j in range(v.shape[1]):
        d = np.diff(np.concatenate([[0], held[:, j].astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            length[a:b, j] = b - a
            edge[a:b, j] = a == 0 or b == t
    return length, edge


def window_min(x: np.ndarray, half: int) -> np.ndarray:
    """Smallest value over ``[t - half, t + half]`` along time (shrunk at the ends)."""
    out: np.ndarray = x.copy()
    for o in range(1, half + 1):
        out[o:] = np.minimum(out[o:], x[:-o])
        out[:-o] = np.minimum(out[:-o], x[o:])
    return out


def window_median(x: np.ndarray, half: int) -> np.ndarray:
    """Median over ``[t - half, t + half]`` along time, (T, m); the ends padded by reflection."""
    if len(x) <= half:
        return cast("np.ndarray", np.median(x, axis=0, keepdims=True).repeat(len(x), 0))
    pad = np.concatenate([x[half:0:-1], x, x[-2 : -half - 2 : -1]], axis=0)
    win = np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1, axis=0)
    return cast("np.ndarray", np.median(win, axis=-1))
