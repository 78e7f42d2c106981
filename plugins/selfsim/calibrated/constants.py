"""The measured constants of the calibrated cleaner (``mode: calibrated``), each chosen on the
tuning clips and checked on held-out ones (docs/cleaning.md, "How the default was chosen");
a user chooses only :class:`~mocapflow.plugins.selfsim.cleaner.CalibratedParams`. Angles in
degrees unless the name says otherwise; frames at the 24 fps analysis rate.
"""

from __future__ import annotations

import numpy as np

#: Cues of the detector (:func:`.cues.cue_values`), each with its own null and weight.
CUES: tuple[str, ...] = ("digression", "acceleration", "mirror", "freeze", "jitter")

#: Quantile of a cue over a joint's clean calibration cells taken as its null level.
NULL_QUANTILE = 0.99

#: A context of fewer analysis frames than this and than the take cannot support a decision:
#: the take calibrates itself.
CONTEXT_MIN_FRAMES = 240

#: Share of the calibration words given a synthetic error.
CALIBRATION_DENSITY = 0.2

#: Error kinds and ranges (frames, degrees) of the self-supervised injection: wider than the
#: evaluation protocol's, with a drift kind it lacks, so the fusion is not fitted to the test
#: distribution.
CALIBRATION_RANGES: dict[str, tuple[tuple[int, int], tuple[float, float]]] = {
    "spike": ((1, 3), (20.0, 100.0)),
    "offset": ((3, 24), (15.0, 60.0)),
    "drift": ((16, 36), (25.0, 60.0)),
    "freeze": ((8, 30), (0.0, 0.0)),
    "noise": ((6, 20), (8.0, 20.0)),
    "swap": ((8, 30), (0.0, 0.0)),
}
CALIBRATION_KINDS: tuple[str, ...] = tuple(CALIBRATION_RANGES)

#: The acceleration cue of a cell is capped at this many times the larger of its two
#: neighbours' on the take (isolated kinks of clean fast joints drop; spikes, steps and
#: jitter keep it); the weights are fitted without the cap.
ACC_PERSIST = 1.5

#: The jitter cue is the median of the acceleration cue over ``2 JITTER_HALF + 1`` frames.
JITTER_HALF = 4

#: At frames where at least this many joints are flagged by the acceleration cue (a jolt of
#: the whole body), those flags are dropped.
ACC_BODY = 3

#: A joint turning less than this per frame (radians) is still: holds are runs of still
#: frames, and freeze flags grow over the still interval.
HOLD_SPEED = float(np.deg2rad(0.05))

#: The freeze cue counts only on holds of at least this many frames.
FREEZE_HOLD = 8

#: Holds of at least ``FREEZE_SCAN`` frames are filled without a freeze flag when the KNN
#: consensus turns at least ``FREEZE_SCAN_DEG`` degrees over them (:func:`.holds.frozen_holds`).
FREEZE_SCAN = 3
FREEZE_SCAN_DEG = 10.0

#: Freeze flags grow only over frames where the KNN consensus moves at least this much per
#: frame (mean over +-2 frames), radians.
FREEZE_MOVING = float(np.deg2rad(0.1))

#: Runs flagged by the digression alone are kept only where the acceleration, freeze or
#: jitter evidence exceeds this somewhere in the run (+-1 frame).
AGREE = 0.3

#: Least summed chain mirror gain (radians over the chain pair) to swap limbs back.
SWAP_GAIN = 0.1

#: Least edge benefit (units of the chains' typical acceleration) at both ends of a swap
#: found by its edges, and the longest such swap (frames).
SWAP_LEVEL = 3.0
SWAP_MAX = 72

#: Flagged runs whose ends are two consistent jumps of at least this many typical
#: accelerations of the joint (and 8 degrees) are repaired by taking the offset out.
OFFSET_LEVEL = 6.0

#: Every joint is searched for offsets (two such agreeing steps, the removal nearer the
#: consensus) of at most this many frames, flagged or not: spikes and flips are short offsets;
#: those steps are at least ``OFFSET_SCAN_DEG`` (clean toes and wrists step 8-12 degrees).
OFFSET_MAX = 48
OFFSET_SCAN_DEG = 15.0

#: Flagged runs of one joint at most this many frames apart are repaired as one.
MERGE_GAP = 3

#: A repaired run decided by one of :data:`SHRINK_CUES` whose strongest evidence E is below
#: this has its edit scaled by ``(E - 1) / (SHRINK_FULL - 1)``.
SHRINK_FULL = 1.5
SHRINK_CUES: tuple[str, ...] = ("acceleration", "jitter")

#: Cells the repair changes by less than this are edited but not reported flagged.
FLAG_MIN_DEG = 10.0
