"""Constant-offset repair of a flagged run (calibrated cleaner).

A spike or an offset burst right-multiplies one rotation ``off`` onto a joint over
``[a, b)``. Continuing the take's own motion one frame forward from ``a - 2, a - 1``
predicts ``p`` with ``p^-1 q[a] ~ off``, and backward from ``b + 1, b`` the same at the last
corrupted frame; when the two agree, taking out ``off`` slerped between them restores the
clean track and keeps the take's own motion (a KNN word is another performance). The ends
are searched around the run, so a partly flagged offset is repaired whole.
"""

from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat


def _forward_offsets(track: np.ndarray) -> np.ndarray:
    """(T, 4): at frame t, ``p^-1 q[t]`` with ``p`` predicted from frames t-2, t-1 (identity for t < 2)."""
    t = len(track)
    out = np.tile(quat.identity(()), (t, 1))
    if t >= 3:
        vel = quat.mul(quat.conjugate(track[:-2]), track[1:-1])  # q[t-2]^-1 q[t-1]
        pred = quat.mul(track[1:-1], vel)
        out[2:] = quat.normalize(quat.mul(quat.conjugate(pred), track[2:]))
    return out


def _backward_offsets(track: np.ndarray) -> np.ndarray:
    """(T, 4): at frame t, ``p^-1 q[t]`` with ``p`` predicted backwards from frames t+2, t+1."""
    return _forward_offsets(track[::-1])[::-1]


def _angle(q: np.ndarray) -> np.ndarray:
    return quat.geodesic_angle(q, np.broadcast_to(quat.identity(()), q.shape))


def offset_interval(
    track: np.ndarray, a0: int, b0: int, level: float, window: int = 18, agree: float = 0.35
) -> tuple[int, int, np.ndarray, np.ndarray] | None:
    """The offset interval ``[a, b)`` holding the flagged run ``[a0, b0)`` of one joint's
    ``track`` (T, 4) and its end offsets, or None: both ends jump at least ``level`` radians,
    searched ``window`` frames around the run (inside it too), and their offsets differ by
    at most ``agree`` times the smaller."""
    t = len(track)
    fwd = _forward_offsets(track)
    bwd = _backward_offsets(track)
    fa, fb = _angle(fwd), _angle(bwd)
    # the run may hold an end (an acceleration-flagged jump is one frame of the offset)
    starts = np.arange(max(2, a0 - window), min(b0 - 1, t - 3) + 1)
    ends = np.arange(max(a0 + 1, 1), min(b0 + window, t - 2) + 1)  # b: first clean frame after
    starts = starts[fa[starts] > level] if len(starts) else starts
    ends = ends[fb[ends - 1] > level] if len(ends) else ends
    best = None
    for a in starts[starts <= a0 + 1].tolist():
        for b in ends[(ends > a) & (ends >= b0 - 1)].tolist():  # the interval covers the run (up to its edge frames)
            d = float(quat.geodesic_angle(fwd[a], bwd[b - 1]))
            small = min(fa[a], fb[b - 1])
            if d > agree * small:
                continue
            score = small - 2.0 * d
            if best is None or score > best[0]:
                best = (score, a, b)
    if best is None:
        return None
    _, a, b = best
    return a, b, fwd[a], bwd[b - 1]


def remove_offset(track: np.ndarray, a: int, b: int, off_a: np.ndarray, off_b: np.ndarray) -> np.ndarray:
    """``track[a:b]`` with the offset slerped from ``off_a`` to ``off_b`` taken out, (b - a, 4)."""
    u = np.linspace(0.0, 1.0, b - a) if b - a > 1 else np.zeros(1)
    d1 = np.where(np.sum(off_a * off_b) < 0, -off_b, off_b)
    off = quat.slerp(np.broadcast_to(off_a, (b - a, 4)), np.broadcast_to(d1, (b - a, 4)), u)
    out = quat.normalize(quat.mul(track[a:b], quat.conjugate(off)))
    return np.where(np.sum(out * track[a:b], -1, keepdims=True) < 0, -out, out)
