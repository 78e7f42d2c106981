"""Slow, obviously correct references for the swap and offset repairs of the calibrated
cleaner (:mod:`mocapflow.plugins.selfsim.calibrated.swaps`, :mod:`mocapflow.plugins.selfsim.calibrated.offsets`).

Scalar quaternion arithmetic written out here, one frame and joint at a time, independent
of :mod:`mocapflow.framework.quaternions`.
"""

from __future__ import annotations

import math

import numpy as np

from .cleaning_cues import _angle, _slerp_half


def _mul(a, b):
    """Hamilton product of (w, x, y, z) quaternions."""
    aw, ax, ay, az = (float(v) for v in a)
    bw, bx, by, bz = (float(v) for v in b)
    return [
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ]


def _conj(a):
    return [float(a[0]), -float(a[1]), -float(a[2]), -float(a[3])]


def _mirror(a):
    """Across the sagittal plane: (w, x, y, z) -> (w, x, -y, -z)."""
    return [float(a[0]), float(a[1]), -float(a[2]), -float(a[3])]


def naive_edge_benefit(q: np.ndarray, left: list[int], right: list[int]) -> np.ndarray:
    """B(f) of the swaps module doc, frame by frame and joint by joint (-inf where undefined)."""
    t = len(q)
    out = np.full(t, -np.inf)
    pairs = list(zip(left, right, strict=True)) + list(zip(right, left, strict=True))
    for f in range(2, t - 1):
        total = 0.0
        for j, other in pairs:
            x = [q[g, j] for g in (f - 2, f - 1, f, f + 1)]
            s = [_mirror(q[g, other]) for g in (f, f + 1)]
            take = _angle(x[1], _slerp_half(x[0], x[2])) + _angle(x[2], _slerp_half(x[1], x[3]))
            cross = _angle(x[1], _slerp_half(x[0], s[0])) + _angle(s[0], _slerp_half(x[1], s[1]))
            total += take - cross
        out[f] = total
    return out


def naive_forward_offset(track: np.ndarray, f: int) -> list[float]:
    """p^-1 q[f] with p = q[f-1] (q[f-2]^-1 q[f-1]): the jump at f against the take's own motion."""
    vel = _mul(_conj(track[f - 2]), track[f - 1])
    pred = _mul(track[f - 1], vel)
    off = _mul(_conj(pred), track[f])
    n = math.sqrt(sum(v * v for v in off))
    return [v / n for v in off]
