"""Frozen joints repaired as gaps: the held frames filled from the KNN consensus joined to
the two frames that bound the hold (a run the ``hold`` detector flagged,
:func:`.bounded_repair.repair_flagged`).

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
