"""``mode: calibrated``: cues, the self-supervised calibration on the clean context, the
decision rule and the bounded repair (swaps, offsets, holds). Its measured constants are in
:mod:`.constants`."""
