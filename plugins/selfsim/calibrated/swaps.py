"""Swapped limbs found by their edges (calibrated cleaner).

A left/right mislabelling of a limb (the markers of the two arms or legs exchanged, seen
as the left chain taking the *mirrored* rotations of the right one and the reverse) starts
and stops with a jump of every joint of both chains, and swapping the chains back from
that frame on removes the jump. The *edge benefit* of a frame ``f`` is how much smoother
the six chain joints become around ``f`` when the frames from ``f`` on are swapped back::

    B(f) = sum_j [acc(x[f-2], x[f-1], x[f]) + acc(x[f-1], x[f], x[f+1])]
         - sum_j [acc(x[f-2], x[f-1], s[f]) + acc(x[f-1], s[f], s[f+1])]

with ``x`` the take's chain rotations, ``s`` the mirrored counterparts
(:func:`.cues.mirror`) and ``acc(a, b, c)`` the angle between ``b`` and the midpoint of
``a`` and ``c`` (:func:`.cues.acceleration`). Swapping back is an involution, so the same
``B`` is large at the start *and* at the end of a swapped interval. ``B`` is measured in
units of the chains' typical acceleration on the take itself (the sum over the six joints
of each one's median acceleration), so it needs no context: on the tuning clips
(locomotion subjects 02, 49; salsa trials 01, 02, 04, 05) true swap edges scored 4.8-64,
every frame away from an error at most 1.8 and clean takes at most 1.8.

A swap is an interval ``[a, b)`` between two consecutive frames whose benefit exceeds
``level`` (local maxima), ``min_len <= b - a <= max_len`` apart. This finds swaps the
digression misses (a mirrored walker's limb is a plausible pose; dancers mirror each
other's moves, so the KNN consensus adapts to the swapped limb in mid-interval) and gives
their exact extent. A swap that starts before the take or lasts past its end has one edge
and is not found here (the mirror cue of :mod:`.bounded_repair` may still find it).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocapflow.framework import quaternions as quat

from .cues import acceleration, chain_columns, mirror


def _acc(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Angle between ``b`` and the midpoint of ``a`` and ``c`` (radians), elementwise."""
    return quat.geodesic_angle(b, quat.slerp(a, c, np.full(b.shape[:-1], 0.5)))


def edge_benefit(q: np.ndarray, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``B(f)`` of the module doc for one chain pair, radians, shape (T,); -inf where undefined
    (the first two frames and the last).

    Parameters
    ----------
    q : ndarray of shape (T, m, 4)
        Texture (local rotations, sign-continuous).
    left, right : ndarray of int
        Texture columns of the left chain and of its right counterpart (same order).
    """
    cols = np.concatenate([left, right])
    other = np.concatenate([right, left])
    x = q[:, cols]
    s = mirror(q[:, other])
    s = np.where(np.sum(s * x, -1, keepdims=True) < 0, -s, s)
    t = len(q)
    out = np.full(t, -np.inf)
    if t < 4:
        return out
    f = np.arange(2, t - 1)
    take = _acc(x[f - 2], x[f - 1], x[f]).sum(1) + _acc(x[f - 1], x[f], x[f + 1]).sum(1)
    cross = _acc(x[f - 2], x[f - 1], s[f]).sum(1) + _acc(x[f - 1], s[f], s[f + 1]).sum(1)
    out[f] = take - cross
    return out


def chain_unit(q: np.ndarray, cols: np.ndarray) -> float:
    """Sum over ``cols`` of each joint's median acceleration on the take, radians (floored at
    0.5 degree per joint): the unit of the edge benefit."""
    acc = np.median(acceleration(q)[1:-1, cols], axis=0) if len(q) > 2 else np.zeros(len(cols))
    return float(np.maximum(acc, np.deg2rad(0.5)).sum())


def swap_edges(
    q: np.ndarray, joints: Sequence[str], level: float = 3.0, min_len: int = 2, max_len: int = 72
) -> list[tuple[np.ndarray, np.ndarray, int, int]]:
    """(left columns, right columns, start, end) of the swapped intervals found by their edges.

    Parameters
    ----------
    q : ndarray of shape (T, m, 4)
    joints : sequence of str
        Canonical names of the texture columns.
    level : float
        Least edge benefit at both ends, in units of :func:`chain_unit`.
    min_len, max_len : int
        Interval lengths accepted, frames.
    """
    out = []
    for lc, rc in chain_columns(list(joints)):
        b = edge_benefit(q, lc, rc) / chain_unit(q, np.concatenate([lc, rc]))
        peak = np.zeros(len(b), bool)
        peak[1:-1] = (b[1:-1] > level) & (b[1:-1] >= b[:-2]) & (b[1:-1] >= b[2:])
        cand = np.flatnonzero(peak).tolist()
        i = 0
        while i + 1 < len(cand):
            a, e = cand[i], cand[i + 1]
            if min_len <= e - a <= max_len:
                out.append((lc, rc, a, e))
                i += 2
            else:
                i += 1
    return out
