"""The fusion of the calibrated detector's cues: the per-cue weights fitted on the
calibration clips' injected errors (:func:`fit_levels`, a greedy allocation of the
false-alarm budget) and the (word, joint) pairs they are counted on. Used by
:mod:`.calibration` (module doc there, step 4).
"""

from __future__ import annotations

import numpy as np

#: Least null level per cue of :data:`.constants.CUES` (units of :func:`.cues.cue_values`).
FLOORS = np.array([1.0, 1.0, 0.2, 0.3, 0.5])
_GRID = np.array([0.8, 1.0, 1.25, 1.6, 2.0, 2.5, 3.2, 4.0, 5.0, 6.4, 8.0, 12.0, np.inf])


def word_joint(mask: np.ndarray, n: int = 15, step: int = 5) -> np.ndarray:
    """(word, joint) pairs holding a True cell: shape (S, m) over the source words."""
    from ..paper.motion_words import source_word_starts

    starts = source_word_starts(len(mask), n, step)
    if len(starts) == 0:
        return np.zeros((0, mask.shape[1]), bool)
    c = np.concatenate([np.zeros((1, mask.shape[1]), np.int64), np.cumsum(mask, axis=0)])
    return (c[starts + n] - c[starts]) > 0


def fit_levels(
    values: list[np.ndarray], levels: np.ndarray, truth: list[np.ndarray], false_alarm: float, max_steps: int = 40
) -> np.ndarray:
    """Per-cue weights ``lambda`` (K,) maximising the (word, joint) recall of the injected
    errors ``truth`` (T, m) in the cue ``values`` (T, m, K) over the null ``levels`` (m, K),
    with at most ``false_alarm`` of the clean pairs flagged. Greedy on the budget: from
    every cue off (inf), each step takes the move (one cue to a lower grid value) with the
    most newly found pairs per newly flagged clean pair within budget."""
    wj_truth = [word_joint(t) for t in truth]
    ratio = [v / levels for v in values]
    n_clean = max(sum(int((~w).sum()) for w in wj_truth), 1)
    budget = false_alarm * n_clean

    def counts(lam: np.ndarray) -> tuple[int, int]:
        tp = fp = 0
        for r, w in zip(ratio, wj_truth, strict=True):
            f = word_joint((r / lam).max(axis=-1) > 1.0)
            tp += int((f & w).sum())
            fp += int((f & ~w).sum())
        return tp, fp

    k_count = levels.shape[1]
    lam = np.full(k_count, np.inf)
    tp, fp = 0, 0
    for _ in range(max_steps):
        best = None
        for k in range(k_count):
            for g in _GRID[lam[k] > _GRID]:
                trial = lam.copy()
                trial[k] = g
                t2, f2 = counts(trial)
                if f2 > budget or t2 <= tp:
                    continue
                gain = (t2 - tp) / (max(f2 - fp, 0) + 0.5)
                if best is None or gain > best[0]:
                    best = (gain, k, g, t2, f2)
        if best is None:
            break
        _, k, g, tp, fp = best
        lam[k] = g
    return lam
