"""Swapped limbs found by their edges (calibrated cleaner).

A left/right mislabelling of a limb (each chain taking the *mirrored* rotations of the
other) starts and stops with a jump of every joint of both chains that swapping back
removes. The edge benefit of frame ``f``, how much smoother the six chain joints get when
the frames from ``f`` on are swapped back::

    B(f) = sum_j [acc(x[f-2], x[f-1], x[f]) + acc(x[f-1], x[f], x[f+1])]
         - sum_j [acc(x[f-2], x[f-1], s[f]) + acc(x[f-1], s[f], s[f+1])]

(``x`` the chain rotations, ``s`` the mirrored counterparts, ``acc`` the angle to the
neighbours' midpoint) is large at both ends of a swap (an involution). In units of the
chains' typical acceleration on the take (no context needed), tuning-clip swap edges scored
4.8-64 and every other frame at most 1.8. A swap is ``[a, b)`` between consecutive peaks
above ``level``; it finds swaps the digression misses (the consensus adapts to a mirrored
limb) with their exact extent, but not a swap with one edge in the take.
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
    """``B(f)`` of the module doc for the chain columns ``left``/``right`` of the texture
    ``q`` (T, m, 4), radians, (T,); -inf where undefined (the first two frames, the last)."""
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
    """(left columns, right columns, start, end) of the swapped intervals found by their
    edges: benefit at least ``level`` :func:`chain_unit` at both ends, ``min_len`` to
    ``max_len`` frames apart."""
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
