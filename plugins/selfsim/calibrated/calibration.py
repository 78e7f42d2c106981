"""Self-supervised calibration of the cleaner on the user's own clean context.

A fixed level on the digression either edits clean fast joints or misses errors
(docs/cleaning.md), so the detector is fitted per take on the clean context:

1. calibration clips: the longest other context clips (``frames`` in all), else the take;
2. each gets seeded synthetic errors (:data:`.constants.CALIBRATION_RANGES`) and is analysed
   leave-one-clip-out, exactly as the take is;
3. on the cells with nothing injected, each joint's typical digression and acceleration set
   the units of its cues and each cue's :data:`.constants.NULL_QUANTILE` its null level;
4. a cell's evidence of cue k is its value over ``lambda_k`` times the null level, flagged
   above 1; the weights are fitted on the injected errors (:func:`.fusion.fit_levels`)
   under at most ``false_alarm`` clean (word, joint) pairs flagged;
5. the take's own typical values replace the context's where larger (a faster take is not
   an error everywhere).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .constants import CALIBRATION_DENSITY, CALIBRATION_KINDS, CALIBRATION_RANGES, CUES, NULL_QUANTILE
from .cues import cue_values, raw_cues, typical
from .fusion import FLOORS, fit_levels, word_joint


@dataclass
class Calibration:
    """A fitted detector: ``scales`` (per-joint typical digression and acceleration, radians,
    (m,)), ``levels`` (m, K) null level per cue of :data:`.constants.CUES`, ``weights`` (K,)
    ``lambda_k`` (inf = unused), the calibration's cells, error cells, (word, joint) recall
    and false alarm, ``source`` (``context`` or ``self``) and clip names.
    """

    scales: dict[str, np.ndarray]
    levels: np.ndarray
    weights: np.ndarray
    n_cells: int
    n_error_cells: int
    recall: float
    false_alarm: float
    source: str
    clips: list[str] = field(default_factory=list)
    fallback: str = ""  # why the take calibrated itself although a context was given

    def evidence(self, q: np.ndarray, mean_q: np.ndarray, joints: Sequence[str]) -> np.ndarray:
        """Evidence of every cue (T, m, K): value over weight times null level (> 1 flags)."""
        cue = raw_cues(q, mean_q, joints)
        own = typical(cue)
        scale = {k: np.maximum(v, own[k]) for k, v in self.scales.items()}
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.nan_to_num(cue_values(cue, scale) / (self.levels * self.weights), nan=0.0, posinf=0.0)

    @staticmethod
    def decide(ev: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flags (T, m) bool, fused evidence (T, m) and the index of the deciding cue (T, m)
        from the evidence (T, m, K) of :meth:`evidence`."""
        best = ev.max(axis=-1)
        return best > 1.0, best, np.argmax(ev, axis=-1)

    def summary(self) -> dict:
        """JSON-friendly description (weight per cue, calibration figures, clips)."""
        return {
            "source": self.source,
            "fallback": self.fallback or None,
            "clips": list(self.clips),
            "cells": self.n_cells,
            "error_cells": self.n_error_cells,
            "recall": round(self.recall, 4),
            "false_alarm": round(self.false_alarm, 5),
            "weights": {
                name: (None if not np.isfinite(w) else float(w)) for name, w in zip(CUES, self.weights, strict=True)
            },
        }


def context_support(res, others: Sequence, fps: float) -> str:
    """Why the context cannot support a decision on the analysed take ``res`` ("" when it can):
    fewer analysis frames than the take and :data:`.constants.CONTEXT_MIN_FRAMES`."""
    from .constants import CONTEXT_MIN_FRAMES

    if not others:
        return ""
    frames = sum(c.n_frames * fps / c.fps for c in others)
    if frames < min(CONTEXT_MIN_FRAMES, res.texture.n_frames):
        return f"context too small ({frames / fps:.1f} s, less than the take and {CONTEXT_MIN_FRAMES / fps:.0f} s)"
    return ""


def calibration_clips(take, others: Sequence, frames: int, fps: float) -> tuple[list, str]:
    """The longest other context clips up to ``frames`` analysis frames (lengths counted at
    ``fps``, so any input rate calibrates on as many seconds), or the take itself alone."""
    if not others:
        return [take], "self"
    chosen, total = [], 0.0
    for c in sorted(others, key=lambda c: -c.n_frames / c.fps):
        if total >= frames:
            break
        chosen.append(c)
        total += c.n_frames * fps / c.fps
    return chosen, "context"


def calibration_material(
    take,
    others: Sequence,
    analyse: Callable,
    joints: Sequence[str],
    fps: float,
    *,
    frames: int = 600,
    seed: int = 0,
) -> tuple[list[dict[str, np.ndarray]], list[np.ndarray], list[str], str]:
    """Raw cues and injected-error masks (T, m) per calibration clip, their names and the
    source (steps 1-2); ``analyse(motion, others)`` is the cleaner's analysis with the clip
    itself included."""
    from ..evaluation.error_injection import inject_at_density
    from ..paper.motion_words import motion_texture

    clips, source = calibration_clips(take, others, frames, fps)
    cue_list, truth_list = [], []
    for i, clip in enumerate(clips):
        tex = motion_texture(clip, joints, fps)
        rest = [c for c in others if c is not clip]
        bad, mask, _ = inject_at_density(
            tex.motion, CALIBRATION_DENSITY, CALIBRATION_KINDS, seed=seed + i, ranges=CALIBRATION_RANGES
        )
        res = analyse(bad, rest)
        cue_list.append(raw_cues(res.texture.q, res.mean_texture, joints))
        truth_list.append(mask[:, tex.joint_index])
    return cue_list, truth_list, [c.name for c in clips], source


def calibrate(
    take,
    others: Sequence,
    analyse: Callable,
    joints: Sequence[str],
    fps: float,
    *,
    false_alarm: float = 0.004,
    frames: int = 600,
    seed: int = 0,
) -> Calibration:
    """:func:`calibration_material`, then the null scales, levels and cue weights (steps 3-4)."""
    cue_list, truth_list, names, source = calibration_material(
        take, others, analyse, joints, fps, frames=frames, seed=seed
    )
    clean = [~t for t in truth_list]
    scales = {
        k: np.median(np.stack([typical(c, ok)[k] for c, ok in zip(cue_list, clean, strict=True)]), axis=0)
        for k in ("digression", "acceleration")
    }
    # fitted without the acceleration cap: with it, the greedy allocation re-spends the freed budget
    values = [cue_values(c, {k: np.maximum(v, typical(c)[k]) for k, v in scales.items()}, None) for c in cue_list]
    stacked = np.concatenate([np.where(ok[..., None], v, np.nan) for v, ok in zip(values, clean, strict=True)], 0)
    levels = np.maximum(np.nan_to_num(np.nanquantile(stacked, NULL_QUANTILE, axis=0), nan=0.0), FLOORS)
    lam = fit_levels(values, levels, truth_list, false_alarm)
    wj_t = [word_joint(t) for t in truth_list]
    wj_f = [word_joint((v / (levels * lam)).max(-1) > 1.0) for v in values]
    rec = sum(int((f & t).sum()) for f, t in zip(wj_f, wj_t, strict=True)) / max(sum(int(t.sum()) for t in wj_t), 1)
    fa = sum(int((f & ~t).sum()) for f, t in zip(wj_f, wj_t, strict=True)) / max(sum(int((~t).sum()) for t in wj_t), 1)
    return Calibration(
        scales,
        levels,
        lam,
        int(sum(t.size for t in truth_list)),
        int(sum(t.sum() for t in truth_list)),
        rec,
        fa,
        source,
        names,
    )
