"""Slow, obviously correct references for the calibrated cleaner's cues (:mod:`mocapflow.plugins.selfsim.calibrated.cues`).

Each loops over frames and joints with scalar quaternion arithmetic written out here,
independent of :mod:`mocapflow.framework.quaternions`.
"""

from __future__ import annotations

import math

import numpy as np


def _angle(a, b) -> float:
    """Rotation angle (radians) between two unit quaternions, sign-invariant."""
    d = abs(sum(float(x) * float(y) for x, y in zip(a, b, strict=True)))
    return 2.0 * math.acos(min(1.0, d))


def _slerp_half(a, b):
    """The rotation halfway between unit quaternions a and b (shorter arc)."""
    a = [float(x) for x in a]
    b = [float(x) for x in b]
    if sum(x * y for x, y in zip(a, b, strict=True)) < 0:
        b = [-x for x in b]
    s = [x + y for x, y in zip(a, b, strict=True)]  # the chordal midpoint is the slerp midpoint once normalised
    n = math.sqrt(sum(x * x for x in s))
    return [x / n for x in s]


def naive_acceleration(q: np.ndarray) -> np.ndarray:
    t, m = q.shape[:2]
    out = np.zeros((t, m))
    for f in range(1, t - 1):
        for j in range(m):
            out[f, j] = _angle(q[f, j], _slerp_half(q[f - 1, j], q[f + 1, j]))
    return out


def naive_window_min(x: np.ndarray, half: int) -> np.ndarray:
    out = np.zeros_like(x)
    for f in range(len(x)):
        lo, hi = max(0, f - half), min(len(x), f + half + 1)
        for j in range(x.shape[1]):
            out[f, j] = min(x[g, j] for g in range(lo, hi))
    return out


def naive_mirror_gain(q: np.ndarray, mean_q: np.ndarray, joints, chains, margin: float) -> np.ndarray:
    """For each chain pair and frame: the summed (own digression - angle to the mirrored
    counterpart's consensus) over the six joints, on the joints whose own gain > margin."""

    def mirrored(v):
        return [v[0], v[1], -v[2], -v[3]]

    out = np.zeros(q.shape[:2])
    for left, right in chains:
        if not all(j in joints for j in left + right):
            continue
        cols = [joints.index(j) for j in left + right]
        other = [joints.index(j) for j in right + left]
        for f in range(len(q)):
            gains = [
                _angle(q[f, c], mean_q[f, c]) - _angle(q[f, c], mirrored(mean_q[f, o]))
                for c, o in zip(cols, other, strict=True)
            ]
            total = sum(gains)
            for c, g in zip(cols, gains, strict=True):
                out[f, c] = total if g > margin else 0.0
    return out


def naive_window_median(x: np.ndarray, half: int) -> np.ndarray:
    """Median over ``[t - half, t + half]``, indices beyond the ends reflected (-1 -> 1, T -> T - 2)."""
    n = x.shape[0]
    out = np.zeros_like(x)
    for t in range(n):
        idx = []
        for i in range(t - half, t + half + 1):
            if i < 0:
                i = -i
            elif i >= n:
                i = 2 * (n - 1) - i
            idx.append(i)
        for j in range(x.shape[1]):
            vals = sorted(float(x[i, j]) for i in idx)
            out[t, j] = vals[half]
    return out
