"""Frozen joints repaired as gaps: the held frames filled by a Hermite curve between the two
frames that bound the hold (session 6, issue 14).

A frozen joint (a marker lost and its last value held by the capture software, the
protocol's ``freeze``) is *held*: from its first frozen frame ``a`` (still its true value)
to the last, it turns less than :data:`.cues.HOLD_SPEED` per frame, and at ``b`` it jumps
back to the motion. The KNN consensus is no good repair there: the neighbours were chosen
on the frozen take, so T̄ is nearly still too (held-out 16_06 ``relbow``: the consensus
moves 0.1-0.5 degrees per frame over an 18-frame freeze), and the bounded repair, which
only moves a cell nearer T̄, changes it by a few degrees. The hold is a gap, and a gap in
capture is filled from its two sides: here a cubic Hermite curve in the tangent space of
``q[a]``, from ``q[a]`` to ``q[b]``, with the take's own angular velocities at ``a`` (step
``a - 1 -> a``) and at ``b`` (step ``b -> b + 1``). A hold that touches the first or the
last frame has one side only and is left to the other repairs.
"""
from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat


def log_map(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, radians) of unit quaternions (..., 4)."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(s, q[..., :1])
    safe = np.where(s > 1e-12, s, 1.0)
    return np.where(s > 1e-12, q[..., 1:] / safe * ang, 2.0 * q[..., 1:])


def exp_map(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3)."""
    ang = np.linalg.norm(v, axis=-1, keepdims=True)
    safe = np.where(ang > 1e-12, ang, 1.0)
    axis = np.where(ang > 1e-12, v / safe, 0.0)
    return np.concatenate([np.cos(ang / 2.0), axis * np.sin(ang / 2.0)], axis=-1)


def hermite_fill(track: np.ndarray, a: int, b: int) -> np.ndarray:
    """Rotations of frames ``a + 1 .. b - 1`` of one joint ``track`` (T, 4), shape (b - a - 1, 4).

    Cubic Hermite in the tangent space of ``track[a]``: position 0 at ``a`` and
    ``log(track[a]^-1 track[b])`` at ``b``; end tangents the take's angular velocity per frame
    just before ``a`` and just after ``b`` (0 where the track ends), times the ``b - a`` frames.
    Needs ``0 <= a < b < T``.
    """
    n = b - a
    qa = track[a]
    inv = quat.conjugate(qa)
    p1 = log_map(quat.mul(inv, track[b]))
    m0 = log_map(quat.mul(quat.conjugate(track[a - 1]), qa)) * n if a >= 1 else np.zeros(3)
    m1 = log_map(quat.mul(quat.conjugate(track[b]), track[b + 1])) * n if b + 1 < len(track) else np.zeros(3)
    u = (np.arange(1, n) / n)[:, None]
    h10 = u ** 3 - 2 * u ** 2 + u
    h01 = -2 * u ** 3 + 3 * u ** 2
    h11 = u ** 3 - u ** 2
    v = h10 * m0 + h01 * p1 + h11 * m1
    return quat.normalize(quat.mul(np.broadcast_to(qa, v.shape[:-1] + (4,)), exp_map(v)))


def slerp_fill(track: np.ndarray, a: int, b: int) -> np.ndarray:
    """Frames ``a + 1 .. b - 1`` of ``track`` (T, 4) on the geodesic from ``track[a]`` to ``track[b]``, (b - a - 1, 4)."""
    n = b - a
    u = np.arange(1, n) / n
    return quat.slerp(np.broadcast_to(track[a], (n - 1, 4)), np.broadcast_to(track[b], (n - 1, 4)), u)


def consensus_fill(track: np.ndarray, mean: np.ndarray, a: int, b: int) -> np.ndarray:
    """Frames ``a + 1 .. b - 1``: the consensus ``mean`` (T, 4) carried by a displacement map that
    joins ``track`` at ``a`` and ``b`` (the right correction ``mean^-1 track`` slerped between
    the two ends), (b - a - 1, 4)."""
    n = b - a
    u = np.arange(1, n) / n
    d0 = quat.mul(quat.conjugate(mean[a]), track[a])
    d1 = quat.mul(quat.conjugate(mean[b]), track[b])
    delta = quat.slerp(np.broadcast_to(d0, (n - 1, 4)), np.broadcast_to(d1, (n - 1, 4)), u)
    return quat.normalize(quat.mul(mean[a + 1:b], delta))


def fill_holds(q: np.ndarray, new: np.ndarray, seeds: np.ndarray, min_frames: int, how: str = "hermite",
               mean_q: np.ndarray | None = None, guard: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``new`` (T, m, 4) with every hold of the take ``q`` that holds a ``seeds`` cell filled.

    Parameters
    ----------
    q, new : ndarray (T, m, 4)
        The take and its repair so far.
    seeds : ndarray of bool (T, m)
        Cells the freeze cue flagged.
    min_frames : int
        Shortest hold filled (frames at the analysis rate).
    how : {"hermite", "slerp", "consensus"}
        :func:`hermite_fill`, :func:`slerp_fill` or :func:`consensus_fill` (needs ``mean_q``).
    mean_q : ndarray (T, m, 4), optional
        The KNN consensus T̄.
    guard : bool
        Keep a fill only when the hold's summed squared distance to ``mean_q`` does not
        rise (the clip-level "never farther from the consensus" rule, per hold).

    Returns
    -------
    new : ndarray (T, m, 4)
    filled : ndarray of bool (T, m)
        The cells replaced (the hold's frames after its first).
    holds : ndarray of bool (T, m)
        The filled holds, first frame included (the other repairs leave them alone).
    """
    from .cues import hold_lengths, speed

    out = new.copy()
    filled = np.zeros(q.shape[:2], bool)
    holds = np.zeros(q.shape[:2], bool)
    length, edge = hold_lengths(speed(q))
    t = len(q)
    for j in np.flatnonzero((seeds & (length >= min_frames) & ~edge).any(axis=0)):
        held = (length[:, j] >= min_frames) & ~edge[:, j]
        d = np.diff(np.concatenate([[0], held.astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
            if seeds[a:b, j].any() and 0 < a and b < t and b - a >= 2:
                if how == "hermite":
                    fill = hermite_fill(q[:, j], a, b)
                elif how == "slerp":
                    fill = slerp_fill(q[:, j], a, b)
                else:
                    fill = consensus_fill(q[:, j], mean_q[:, j], a, b)
                if guard and mean_q is not None:
                    d0 = float((quat.geodesic_angle(q[a + 1:b, j], mean_q[a + 1:b, j]) ** 2).sum())
                    if float((quat.geodesic_angle(fill, mean_q[a + 1:b, j]) ** 2).sum()) > d0:
                        continue  # the hold would end farther from its consensus than it was
                out[a + 1:b, j] = fill
                filled[a + 1:b, j] = True
                holds[a:b, j] = True
    return out, filled, holds
