"""Slow, obviously correct reference for the per-run acceptance test of the calibrated repair
(:func:`mocapflow.plugins.selfsim.run_acceptance.accept_runs`): one joint, one frame at a time."""
from __future__ import annotations

import numpy as np

from .cleaning_cues import _angle


def naive_accept_runs(q: np.ndarray, new: np.ndarray, mean_q: np.ndarray, edited: np.ndarray,
                      exclude: np.ndarray, typical: np.ndarray, margin: float) -> np.ndarray:
    """``new`` with every run (consecutive ``edited & ~exclude`` frames of a joint) undone whose
    summed drop of the squared angle to ``mean_q`` is at most ``margin`` x frames x typical^2."""
    out = np.array(new, dtype=float, copy=True)
    t_count, m = edited.shape
    for j in range(m):
        f = 0
        while f < t_count:
            if not (edited[f, j] and not exclude[f, j]):
                f += 1
                continue
            a = f
            while f < t_count and edited[f, j] and not exclude[f, j]:
                f += 1
            gain = 0.0
            for g in range(a, f):
                gain += _angle(q[g, j], mean_q[g, j]) ** 2 - _angle(new[g, j], mean_q[g, j]) ** 2
            if gain <= margin * (f - a) * float(typical[j]) ** 2:
                out[a:f, j] = q[a:f, j]
    return out
