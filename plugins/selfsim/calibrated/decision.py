"""The decision of ``mode: calibrated``: one test per (frame, joint) at a stated false-alarm
rate, and repairs only where it fired.

The detectors' evidence (:mod:`.detectors`) is fused into one statistic per cell and
compared with the take's null (:mod:`.null`, :mod:`.calibration`): a cell is flagged when
its conformal p-value is at most ``false_alarm_rate``. Each flagged run (runs of one joint
at most :data:`.constants.MERGE_GAP` frames apart merged) is repaired by the detector that
decided its strongest cell (:func:`.bounded_repair.repair_flagged`): swapped limbs swapped
back, holds filled from the consensus, runs bounded by two agreeing jumps taken out as an
offset, the rest the median KNN word joined to the take at both ends; a repair moves a cell
only nearer the consensus and never beyond its digression plus the KNN spread.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .detectors import DETECTORS


def calibrated_decision(res: Any, null: Any, rate: float) -> tuple[np.ndarray, ...]:
    """Decide and repair one analysed take against its ``null`` at ``rate``: flags (T, m),
    map value (``0.5 S / threshold``, > 0.5 = flagged, in [0, 1]), deciding detector name per
    flagged cell, repaired texture (T, m, 4), the changed cells, the p-values and the fused
    statistic (T, m)."""
    from .bounded_repair import repair_flagged
    from .detectors import evidence

    q, mean_q = res.texture.q, res.mean_texture
    ev = evidence(q, mean_q, res.spread, res.joints)
    s, det = null.statistic(ev)
    tau = max(null.take_threshold(rate, s), 1e-9)
    flags = s > tau
    new24, edited = repair_flagged(res, flags, det, s)
    cue = np.full(flags.shape, None, dtype=object)
    cue[flags] = np.array(DETECTORS, dtype=object)[det[flags]]
    value = np.clip(0.5 * s / tau, 0.0, 1.0)
    value = np.where(flags, np.maximum(value, 0.5 + 1e-6), np.minimum(value, 0.5))
    return flags, value, cue, new24, edited, null.p_values(s), s
