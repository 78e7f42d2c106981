"""The structural detectors of the calibrated cleaner: per (frame, joint) evidence of one kind
of capture error, each measured against what the KNN consensus ``T̄`` of similar words
(:mod:`..paper.mdm`) does at that joint, never against an absolute level. (T, m) arrays at
the analysis rate, >= 0; :mod:`.null` standardises them per joint on clean similar motion
and fuses them into one statistic.

* ``step``: the take's acceleration (angle of a frame to the midpoint of its neighbours)
  beyond the consensus' at the same cell: offsets' edges, spikes, flips;
* ``digression``: the angle to ``T̄`` over the KNN spread there (the least over 3 frames: an
  error lasts), so a joint whose similar words disagree (a toe, a wrist) needs more;
* ``hold``: on a still run of >= 3 frames, the log of the consensus' speed over the take's
  (a frozen joint is still while its like moves; a straight knee at its limit is still in its
  neighbours too);
* ``swap``: the mirror gain of a left/right chain pair (swapping back brings both nearer ``T̄``);
* ``jitter``: the 9-frame median of ``step`` (noise lasts, a kink does not).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mocapflow.framework import quaternions as quat

from .cues import _window_mean, acceleration, hold_lengths, mirror_gain, speed, window_median, window_min

#: The detectors, in the order of the last axis of :func:`evidence`.
DETECTORS: tuple[str, ...] = ("step", "digression", "hold", "swap", "jitter")

#: Least robust scale of each detector's evidence per joint (its units: radians, a ratio,
#: a log ratio, radians, radians): a joint whose null evidence is nearly constant (a still
#: toe) is measured in these.
SCALE_FLOOR = np.array([np.deg2rad(0.5), 0.1, 0.1, np.deg2rad(1.0), np.deg2rad(0.25)])

#: Least KNN spread (radians) the digression is divided by.
SPREAD_FLOOR = float(np.deg2rad(2.0))

#: Least still run (frames) the hold detector looks at.
HOLD_MIN = 3


def evidence(q: np.ndarray, mean_q: np.ndarray, spread: np.ndarray | None, joints: Sequence[str]) -> np.ndarray:
    """Every detector of the module doc for a texture ``q`` (T, m, 4), its consensus ``mean_q``
    and KNN spread (T, m) of the texture joints ``joints``: (T, m, len(DETECTORS))."""
    t, m = q.shape[:2]
    step = np.maximum(acceleration(q) - acceleration(mean_q), 0.0)
    sp = np.zeros((t, m)) if spread is None else spread
    dig = window_min(quat.geodesic_angle(q, mean_q) / (sp + SPREAD_FLOOR), 1)
    floor = np.deg2rad(0.2)
    v = speed(q)
    length, edge = hold_lengths(v)
    held = np.log((_window_mean(speed(mean_q), 4) + floor) / (v + floor))
    hold = np.where((length >= HOLD_MIN) & ~edge, np.maximum(held, 0.0), 0.0)
    swap = mirror_gain(q, mean_q, joints)
    jit = window_median(step, 4)
    return np.stack([step, dig, hold, swap, jit], axis=-1)
