"""Short excursions found by their two jumps, whatever the per-cell cues say (session 6, issue 14).

A spike (1-3 frames) is a short offset: the joint jumps away and back. The acceleration cue
sees each jump as a frame or two above the joint's typical acceleration and must keep a
level that the fastest clean joints' kinks stay below; on a fast joint a 30-40 degree spike
can stay under it (tuning clip 02_02, seed 1: a 3-frame ankle spike of 36 degrees with
accelerations of 18-22 degrees against a level of ~36). Its *two* jumps are another matter:
continuing the take's motion forward from the clean side predicts the added rotation at the
first corrupted frame, and continuing it backward predicts it at the last (:mod:`.offsets`);
for an excursion the two predictions agree, for a clean kink (one sharp turn) there is one
jump and nothing to agree with. :func:`spike_runs` returns the intervals of at most
``max_len`` frames whose two end jumps both exceed ``level`` typical accelerations of the
joint (and ``min_deg``) and agree within ``agree`` of the smaller; the cleaner flags them
and repairs them as offsets (:func:`.bounded_repair._offset_run`, kept only where the
repair lowers the interval's mean digression).
"""
from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat


def repair_spikes(q: np.ndarray, mean_q: np.ndarray, new: np.ndarray, runs: np.ndarray,
                  keep: float | None = None, least: float = np.deg2rad(8.0)) -> np.ndarray:
    """``new`` (T, m, 4) with each run of ``runs`` (T, m) repaired as an offset over exactly that
    run (:func:`.offsets.remove_offset` with its two end estimates), where that lowers the
    run's mean digression; returns the cells repaired (T, m) bool. The interval is not grown:
    a spike is the excursion its two jumps bound.

    With ``keep`` (session 6 round 2) the excursion must also *be* a departure from the
    consensus: its mean digression at least ``least`` radians and the repair leaving at most
    ``keep`` of it. A clean knee turn at heel strike has two agreeing jumps too, but its KNN
    words turn with it: little digression, and removing the "offset" hardly lowers it."""
    from .bounded_repair import _runs
    from .offsets import _backward_offsets, _forward_offsets, remove_offset

    done = np.zeros(runs.shape, bool)
    for j in np.flatnonzero(runs.any(axis=0)):
        fwd, bwd = _forward_offsets(q[:, j]), _backward_offsets(q[:, j])
        for a, b in _runs(runs[:, j]):
            rep = remove_offset(q[:, j], a, b, fwd[a], bwd[b - 1])
            before = quat.geodesic_angle(q[a:b, j], mean_q[a:b, j]).mean()
            after = quat.geodesic_angle(rep, mean_q[a:b, j]).mean()
            if keep is not None and (before < least or after > keep * before):
                continue
            if after < before:
                new[a:b, j] = rep
                done[a:b, j] = True
    return done


def spike_runs(q: np.ndarray, level: float, max_len: int = 3, agree: float = 0.35, min_deg: float = 8.0
               ) -> np.ndarray:
    """Cells of the excursions of at most ``max_len`` frames found by their two jumps, (T, m) bool.

    Parameters
    ----------
    q : ndarray (T, m, 4)
        The take's texture (sign-continuous).
    level : float
        Least jump at both ends, in units of twice the joint's median acceleration
        (the scale :func:`.bounded_repair._offset_run` uses).
    max_len : int
        Longest excursion, frames.
    agree : float
        The two end offsets may differ by at most this share of the smaller.
    min_deg : float
        Least jump, degrees, whatever the joint's typical acceleration.
    """
    from .cues import acceleration
    from .offsets import _angle, _backward_offsets, _forward_offsets

    t, m = q.shape[:2]
    out = np.zeros((t, m), bool)
    if t < 6:
        return out
    acc = np.median(acceleration(q)[1:-1], axis=0)
    for j in range(m):
        track = q[:, j]
        lev = max(level * 2.0 * float(acc[j]), np.deg2rad(min_deg))
        fwd, bwd = _forward_offsets(track), _backward_offsets(track)
        fa, fb = _angle(fwd), _angle(bwd)
        found = []
        for a in np.flatnonzero(fa[2:t - 2] > lev) + 2:
            for b in range(a + 1, min(a + max_len, t - 3) + 1):
                if fb[b - 1] <= lev:
                    continue
                d = float(quat.geodesic_angle(fwd[a], bwd[b - 1]))
                small = float(min(fa[a], fb[b - 1]))
                if d <= agree * small:
                    found.append((small - 2.0 * d, int(a), b))
        for _, a, b in sorted(found, reverse=True):
            if not out[max(0, a - 1):b + 1, j].any():
                out[a:b, j] = True
    return out
