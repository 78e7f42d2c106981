"""Self-supervised calibration of the cleaner on the user's own clean context.

The paper flags a cell when its row-normalised digression exceeds a fixed level (§3.4, §4).
On real takes the clean digression of the fastest joints overlaps the errors
(docs/cleaning.md), so a fixed level either edits clean motion or misses errors. Here the
detector is fitted, for each take, on material the user already trusts: the clean context.

1. *Calibration clips*: the context clips other than the take (up to ``frames`` frames at
   the analysis rate, longest first); with no other clip, the take itself.
2. *Self-supervision*: each calibration clip gets seeded synthetic errors
   (:func:`~mocapflow.plugins.selfsim.evaluation.error_injection.inject_at_density`, ranges
   of :data:`.constants.CALIBRATION_RANGES`, wider than the evaluation's) and is analysed
   against the context without it plus itself (leave-one-clip-out, exactly as the take is).
3. *Null*: on the cells with nothing injected, each joint's typical digression and
   acceleration (medians) set the units of its cues (:func:`.cues.cue_values`), and each
   cue's :data:`.constants.NULL_QUANTILE` per joint is that joint's null level.
4. *Fusion*: a cell's evidence of cue ``k`` is its value over ``lambda_k`` times the
   joint's null level; the cell is flagged when its largest evidence exceeds 1, and that
   cue is reported. The weights ``lambda_k`` are fitted on the injected errors
   (:func:`.fusion.fit_levels`): a greedy allocation of the false-alarm budget that raises
   the (word, joint) recall under the constraint that at most ``false_alarm`` of the clean
   (word, joint) pairs are flagged. No label comes from the user.
5. *Do no harm on a different take*: the take's own typical values replace the context's
   where they are larger (a faster take than its context is not an error everywhere), and
   the digression cue is divided by the frame's median over the joints when that is high.

The result is a :class:`Calibration`; :meth:`Calibration.evidence` applies it to a take.
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
    """A fitted detector: per-joint null scales and levels, and the weight of each cue.

    Attributes
    ----------
    scales : dict of str -> ndarray (m,)
        Per-joint typical digression and acceleration on clean calibration cells, radians.
    levels : ndarray (m, K)
        Per-joint null level of each cue of :data:`.constants.CUES`.
    weights : ndarray (K,)
        ``lambda_k``: a cell is flagged by cue ``k`` above ``lambda_k`` times its null level
        (inf = cue unused).
    n_cells, n_error_cells : int
        Calibration cells used, and how many held an injected error.
    recall, false_alarm : float
        (word, joint) recall of the injected errors and share of clean pairs flagged, on
        the calibration clips.
    source : str
        ``context`` (leave-one-clip-out on the context) or ``self`` (the take itself).
    clips : list of str
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
            "clips": list(self.clips),
            "cells": self.n_cells,
            "error_cells": self.n_error_cells,
            "recall": round(self.recall, 4),
            "false_alarm": round(self.false_alarm, 5),
            "weights": {
                name: (None if not np.isfinite(w) else float(w)) for name, w in zip(CUES, self.weights, strict=True)
            },
        }


def calibration_clips(take, others: Sequence, frames: int, fps: float) -> tuple[list, str]:
    """The clips to calibrate on: the longest other context clips up to ``frames`` frames in
    all at the analysis rate ``fps`` (a clip's length counted in analysis frames, so a
    120-fps context calibrates on as many seconds as a 24-fps one), or the take itself when
    there is no other clip."""
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
    texture: Callable | None = None,
) -> tuple[list[dict[str, np.ndarray]], list[np.ndarray], list[str], str]:
    """Inject errors into the calibration clips and analyse them (steps 1-2 of the module doc).

    Parameters
    ----------
    take : Motion
        The take to be cleaned (used only when ``others`` is empty).
    others : sequence of Motion
        The context clips other than the take, at any rate.
    analyse : callable
        ``analyse(motion, context_list) -> DigressionResult`` (the cleaner's analysis with
        the clip itself included), so calibration sees exactly what the take will.
    joints : sequence of str
        Texture joints.
    fps : float
        Analysis rate.
    frames : int
        Calibration budget, frames at ``fps``.
    seed : int
    texture : callable, optional
        ``texture(motion) -> Texture``; default :func:`..paper.motion_words.motion_texture`.

    Returns
    -------
    raw cues per clip, injected-error masks per clip (T, m), clip names, source
    """
    from ..evaluation.error_injection import inject_at_density
    from ..paper.motion_words import motion_texture

    make = texture or (lambda m: motion_texture(m, joints, fps))
    clips, source = calibration_clips(take, others, frames, fps)
    cue_list, truth_list = [], []
    for i, clip in enumerate(clips):
        tex = make(clip)
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
    texture: Callable | None = None,
) -> Calibration:
    """:func:`calibration_material`, then the null scales and levels and the cue weights
    (steps 3-4 of the module doc); ``false_alarm`` is the target share of clean (word,
    joint) pairs flagged on the calibration clips."""
    cue_list, truth_list, names, source = calibration_material(
        take, others, analyse, joints, fps, frames=frames, seed=seed, texture=texture
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
