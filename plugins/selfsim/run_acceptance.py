"""Per-run checks of the calibrated repair: edits bounded by the evidence, runs accepted on a gain.

:func:`.bounded_repair.bounded_repair` moves every flagged cell nearer its KNN consensus T̄
(cell by cell), which is no test at all for a clean cell: a clean fast joint sits some way
from T̄ everywhere, so moving it towards T̄ is always "nearer" and always damage. Two rules
of issue 14 ("never edit a cell by more than the evidence supports; never make a clip
farther from its KNN consensus than it was"), both per *run* (consecutive edited cells of
one joint; swapped-back chains are whole intervals of their own and are left alone):

* :func:`shrink_weak_runs` (``shrink_full``): a run whose strongest fused evidence ``E`` is
  below ``full`` has its edit scaled, along the geodesic, by ``(E - 1) / (full - 1)``: a run
  that barely passes its level (a clean knee's kink at heel strike, evidence 1-1.5) is
  moved a little, an error many levels above it (a 30-90 degree spike) fully.
* :func:`accept_runs` (``accept_margin``): a run is kept only when the squared distance to
  T̄ it removes, summed over every cell it changes, exceeds ``margin`` times the summed
  squared *typical clean* digression of those cells (the joint's median distance to T̄ on
  clean motion, :mod:`.calibration`): clean cells sit that far from T̄ anyway, so a gain
  below it is no evidence of an error, and every changed cell raises the bar.

Both only undo or shorten edits: no cell ends farther from T̄ than the bounded repair left
it, and none is edited that the bounded repair did not edit.
"""
from __future__ import annotations

import numpy as np

from mocapflow.framework import quaternions as quat


def edit_runs(edited: np.ndarray, exclude: np.ndarray) -> list[tuple[int, int, int]]:
    """(joint, start, end) of the half-open runs of ``edited & ~exclude`` (T, m), per joint."""
    from .bounded_repair import _runs

    mask = edited & ~exclude
    return [(int(j), a, b) for j in np.flatnonzero(mask.any(axis=0)) for a, b in _runs(mask[:, j])]


def shrink_weak_runs(q: np.ndarray, new: np.ndarray, edited: np.ndarray, exclude: np.ndarray,
                     evidence: np.ndarray, eligible: np.ndarray, full: float) -> np.ndarray:
    """``new`` (T, m, 4) with the edit of each weak run scaled by its evidence.

    Parameters
    ----------
    q, new : ndarray (T, m, 4)
        The take and its repair.
    edited, exclude : ndarray of bool (T, m)
        Cells the repair changed; cells never touched here (swapped-back chains, offsets).
    evidence : ndarray (T, m)
        Fused evidence (> 1 flags, :meth:`.calibration.Calibration.detect`).
    eligible : ndarray of bool (T, m)
        Flagged cells whose deciding cue may be shrunk; a run is shrunk when its strongest
        flagged cell is one.
    full : float
        Evidence from which a run is edited in full (> 1).
    """
    out = new.copy()
    for j, a, b in edit_runs(edited, exclude):
        ev = evidence[a:b, j]
        k = int(np.argmax(ev))
        if not eligible[a + k, j]:
            continue
        s = float(np.clip((ev[k] - 1.0) / (full - 1.0), 0.0, 1.0))
        if s < 1.0:
            out[a:b, j] = q[a:b, j] if s == 0.0 else quat.slerp(q[a:b, j], new[a:b, j], np.full(b - a, s))
    return out


def accept_runs(q: np.ndarray, new: np.ndarray, mean_q: np.ndarray, edited: np.ndarray, exclude: np.ndarray,
                typical: np.ndarray, margin: float) -> tuple[np.ndarray, int]:
    """``new`` with the runs whose consensus gain is below ``margin`` times their clean scatter undone.

    Parameters
    ----------
    q, new, mean_q : ndarray (T, m, 4)
        The take, its repair and the KNN consensus T̄.
    edited, exclude : ndarray of bool (T, m)
    typical : ndarray (m,)
        Each joint's typical clean digression, radians.
    margin : float

    Returns
    -------
    new : ndarray (T, m, 4)
    undone : int
        Runs undone.
    """
    out = new.copy()
    d0 = quat.geodesic_angle(q, mean_q) ** 2
    d1 = quat.geodesic_angle(new, mean_q) ** 2
    undone = 0
    for j, a, b in edit_runs(edited, exclude):
        gain = float((d0[a:b, j] - d1[a:b, j]).sum())
        if gain <= margin * (b - a) * float(typical[j]) ** 2:
            out[a:b, j] = q[a:b, j]
            undone += 1
    return out, undone
