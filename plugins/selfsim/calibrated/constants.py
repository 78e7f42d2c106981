"""The measured constants of the calibrated cleaner (``mode: calibrated``), each chosen as
docs/cleaning.md ("How the default was chosen") says; a user chooses only
:class:`~mocapflow.plugins.selfsim.cleaner.CalibratedParams` (the false-alarm rate). Angles
in degrees unless the name says otherwise; frames at the 24 fps analysis rate.
"""

from __future__ import annotations

import numpy as np

#: The default false-alarm rate: the share of (frame, joint) cells of a clean take flagged.
DEFAULT_RATE = 2e-3

#: Under this share of the take's KNN words in the context, the context is unlike the take and
#: the shipped null decides.
MIN_SIMILAR = 0.2

#: A context null of fewer frames like the take than this is too small: the shipped null decides.
NULL_MIN_FRAMES = 120

#: Frames around the KNN-covered context frames taken into a calibration span.
SPAN_PAD = 8

#: A joint turning less than this per frame (radians) is still: holds are runs of still frames.
HOLD_SPEED = float(np.deg2rad(0.05))

#: Least summed chain mirror gain (radians over the chain pair) to swap limbs back.
SWAP_GAIN = 0.1

#: Least edge benefit (units of the chains' typical acceleration) at both ends of a swap
#: found by its edges, and the longest such swap (frames); only a swap holding a flagged
#: chain cell is repaired.
SWAP_LEVEL = 3.0
SWAP_MAX = 72

#: A flagged run whose ends are two consistent jumps of at least this many typical
#: accelerations of the joint (and 8 degrees) is repaired by taking the offset out.
OFFSET_LEVEL = 6.0

#: Flagged runs of one joint at most this many frames apart are repaired as one.
MERGE_GAP = 3

#: An edit larger than this (degrees) is named in the report as a capture glitch.
GLITCH_DEG = 15.0
