"""Frozen joints repaired as gaps: the held frames filled from the KNN consensus joined to
the two frames that bound the hold.

A frozen joint is still from its first frozen frame ``a`` (its true value) to the last and
jumps back at ``b``. The bounded repair cannot fix it (the neighbours were chosen on the
frozen take, so T̄ is nearly still too); the consensus keeps the motion's shape and a
displacement map joins it to the take at ``a`` and ``b``. A hold touching an end of the take
has one side only and is left to the other repairs.
"""

from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat


def consensus_fill(track: np.ndarray, mean: np.ndarray, a: int, b: int) -> np.ndarray:
    """Frames ``a + 1 .. b - 1``: the consensus ``mean`` (T, 4) carried by a displacement map that
    joins ``track`` at ``a`` and ``b`` (the right correction ``mean^-1 track`` slerped between
    the two ends), (b - a - 1, 4)."""
    n = b - a
    u = np.arange(1, n) / n
    d0 = quat.mul(quat.conjugate(mean[a]), track[a])
    d1 = quat.mul(quat.conjugate(mean[b]), track[b])
    delta = quat.slerp(np.broadcast_to(d0, (n - 1, 4)), np.broadcast_to(d1, (n - 1, 4)), u)
    return quat.normalize(quat.mul(mean[a + 1 : b], delta))


def frozen_holds(v: np.ndarray, length: np.ndarray, edge: np.ndarray, mean_v: np.ndarray) -> np.ndarray:
    """Holds of any length found without a flag (T, m): a joint still for at least
    :data:`.constants.FREEZE_SCAN` frames, inside the take, on a joint that moves on most
    frames, while the KNN consensus turns at least :data:`.constants.FREEZE_SCAN_DEG` over
    the hold and the joint jumps as much out of it in one frame (a clean joint is never
    exactly still while its like moves that much, nor leaves a hold with such a step)."""
    from .constants import FREEZE_SCAN, FREEZE_SCAN_DEG, HOLD_SPEED

    out = np.zeros(v.shape, bool)
    cand = (length >= FREEZE_SCAN) & ~edge
    for j in np.flatnonzero(cand.any(axis=0)):
        if np.median(v[:, j]) < 2.0 * HOLD_SPEED:
            continue  # a joint still on most of the take (a toe the capture does not track)
        d = np.diff(np.concatenate([[0], cand[:, j].astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            # the consensus turns over the hold, and the joint jumps out of it (a joint held at
            # its limit, a straight knee, leaves it as smoothly as the consensus)
            if mean_v[a : b - 1, j].sum() >= np.deg2rad(FREEZE_SCAN_DEG) and v[b - 1, j] >= np.deg2rad(FREEZE_SCAN_DEG):
                out[a:b, j] = True
    return out


def fill_holds(
    q: np.ndarray, seeds: np.ndarray, min_frames: int, mean_q: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The take ``q`` (T, m, 4) with every hold of at least ``min_frames`` frames holding a
    ``seeds`` cell (freeze flags), and every hold :func:`frozen_holds` finds, filled by
    :func:`consensus_fill` from ``mean_q``; returns it, the cells replaced (the hold's frames after its first) and the filled holds (first frame
    included; the other repairs leave them alone), (T, m) bool."""
    from .cues import hold_lengths, speed

    out = q.copy()
    filled = np.zeros(q.shape[:2], bool)
    holds = np.zeros(q.shape[:2], bool)
    v = speed(q)
    length, edge = hold_lengths(v)
    t = len(q)
    scanned = frozen_holds(v, length, edge, speed(mean_q))
    seeds = seeds | scanned
    for j in np.flatnonzero((seeds & ((length >= min_frames) | scanned) & ~edge).any(axis=0)):
        held = ((length[:, j] >= min_frames) | scanned[:, j]) & ~edge[:, j]
        d = np.diff(np.concatenate([[0], held.astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True):
            if seeds[a:b, j].any() and a > 0 and b < t and b - a >= 2:
                out[a + 1 : b, j] = consensus_fill(q[:, j], mean_q[:, j], a, b)
                filled[a + 1 : b, j] = True
                holds[a:b, j] = True
    return out, filled, holds
