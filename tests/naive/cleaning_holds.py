"""Slow, obviously correct references for the hold cue and the hold fill of the calibrated
cleaner (:mod:`mocapflow.plugins.selfsim.calibrated.holds`, ``cues.hold_lengths``).

Scalar loops and quaternion arithmetic written out here, independent of
:mod:`mocapflow.framework.quaternions`.
"""

from __future__ import annotations

import math

import numpy as np


def naive_hold_lengths(v: np.ndarray, still: float) -> tuple[np.ndarray, np.ndarray]:
    """Per cell: the length of the run of *held* frames it lies in (a frame is held when the
    step into it, ``v[t-1]``, or out of it, ``v[t]``, is below ``still``), and whether that run
    includes the first or last frame."""
    t, m = v.shape
    length = np.zeros((t, m))
    edge = np.zeros((t, m), bool)
    for j in range(m):
        held = [v[f, j] < still or (f > 0 and v[f - 1, j] < still) for f in range(t)]
        f = 0
        while f < t:
            if not held[f]:
                f += 1
                continue
            g = f
            while g < t and held[g]:
                g += 1
            for k in range(f, g):
                length[k, j] = g - f
                edge[k, j] = f == 0 or g == t
            f = g
    return length, edge


def _mul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return [
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ]


def _conj(a):
    return [a[0], -a[1], -a[2], -a[3]]


def _slerp(a, b, u):
    d = sum(x * y for x, y in zip(a, b, strict=True))
    if d < 0:
        b, d = [-x for x in b], -d
    d = min(1.0, d)
    th = math.acos(d)
    if th < 1e-9:
        return list(a)
    s0, s1 = math.sin((1 - u) * th) / math.sin(th), math.sin(u * th) / math.sin(th)
    return [s0 * x + s1 * y for x, y in zip(a, b, strict=True)]


def naive_consensus_fill(track: np.ndarray, mean: np.ndarray, a: int, b: int) -> np.ndarray:
    """Frames a+1..b-1: ``mean[t] * slerp(mean[a]^-1 track[a], mean[b]^-1 track[b], (t - a) / (b - a))``."""
    d0 = _mul(_conj([float(x) for x in mean[a]]), [float(x) for x in track[a]])
    d1 = _mul(_conj([float(x) for x in mean[b]]), [float(x) for x in track[b]])
    out = []
    for t in range(a + 1, b):
        r = _mul([float(x) for x in mean[t]], _slerp(d0, d1, (t - a) / (b - a)))
        n = math.sqrt(sum(x * x for x in r))
        out.append([x / n for x in r])
    return np.array(out)
