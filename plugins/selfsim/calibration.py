"""Self-supervised calibration of the cleaner on the user's own clean context (issue 14).

The paper flags a cell when its row-normalised digression exceeds a fixed level (§3.4, §4).
On real takes the clean digression of the fastest joints overlaps the errors
(docs/cleaning.md), so a fixed level either edits clean motion or misses errors. Here the
detector is fitted, for each take, on material the user already trusts: the clean context.

1. *Calibration clips*: the context clips other than the take (up to
   ``calibration_frames`` frames, longest first); with no other clip, the take itself.
2. *Self-supervision*: each calibration clip gets seeded synthetic errors
   (:func:`~mocapflow.plugins.selfsim.error_injection.inject_at_density`, ranges of
   :data:`CALIBRATION_RANGES`, wider than the evaluation's) and is analysed against the
   context without it plus itself (leave-one-clip-out, exactly as the take is analysed).
3. *Null*: on the cells with nothing injected, each joint's typical digression,
   acceleration and spread (medians) set the units of its cues (:func:`.cues.cue_values`),
   and each cue's ``null_quantile`` (0.99) per joint is that joint's null level.
4. *Fusion*: a cell's evidence of cue ``k`` is its value over ``lambda_k`` times the
   joint's null level; the cell is flagged when its largest evidence exceeds 1, and that
   cue is reported. The weights ``lambda_k`` are fitted on the injected errors
   (:func:`fit_levels`): a greedy allocation of the false-alarm budget that raises the
   (word, joint) recall under the constraint that at most ``false_alarm`` of the clean
   (word, joint) pairs are flagged. No label comes
   from the user.
5. *Do no harm on a different take*: the take's own typical values replace the context's
   where they are larger (a faster take than its context is not an error everywhere), and
   the digression cue is divided by the frame's median over the joints when that is high
   (cues doc).

The result is a :class:`Calibration`; :meth:`Calibration.detect` applies it to a take.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .cues import CUES, DEFAULT_CUES, cue_values, raw_cues, rotation_range, typical
from .fusion import _FLOORS, _grow, _near, cue_floor, fit_levels, word_joint

#: Error ranges of the self-supervised injection: wider than the evaluation protocol's
#: (issue 14) so the fusion is not fitted to the test distribution.
CALIBRATION_RANGES: dict[str, tuple[tuple[int, int], tuple[float, float]]] = {
    "spike": ((1, 3), (20.0, 100.0)),
    "offset": ((3, 24), (15.0, 60.0)),
    "drift": ((16, 36), (25.0, 60.0)),
    "freeze": ((8, 30), (0.0, 0.0)),
    "noise": ((6, 20), (8.0, 20.0)),
    "swap": ((8, 30), (0.0, 0.0)),
}

CALIBRATION_KINDS: tuple[str, ...] = ("spike", "offset", "drift", "freeze", "noise", "swap")


@dataclass
class Calibration:
    """A fitted detector: per-joint null scales and levels, and the weight of each cue.

    Attributes
    ----------
    scales : dict of str -> ndarray (m,)
        Per-joint typical digression, acceleration and spread on clean calibration cells, radians.
    levels : ndarray (m, K)
        Per-joint null level (``null_quantile``) of each cue of :data:`.cues.CUES`.
    weights : ndarray (K,)
        ``lambda_k``: a cell is flagged by cue ``k`` above ``lambda_k`` times its null level
        (inf = cue unused).
    low, high : ndarray (m, 3) or None
        Rotation-vector range of the clean context (the range cue).
    n_cells, n_error_cells : int
        Calibration cells used, and how many held an injected error.
    recall, false_alarm : float
        (word, joint) recall of the injected errors and share of clean pairs flagged, on
        the calibration clips.
    source : str
        ``context`` (leave-one-clip-out on the context) or ``self`` (the take itself).
    clips : list of str
    acc_persist : float or None
        Persistence factor of the acceleration cue (:func:`.cues.persistent`).
    jitter_half, freeze_hold
        Definition of the jitter and freeze cues (:func:`.cues.cue_values`).
    word_half, word_slack
        Definition of the words cue (:mod:`.word_noise`); ``word_half`` None: the cue is not
        computed (0 everywhere).
    """

    scales: dict[str, np.ndarray]
    levels: np.ndarray
    weights: np.ndarray
    low: np.ndarray | None
    high: np.ndarray | None
    n_cells: int
    n_error_cells: int
    recall: float
    false_alarm: float
    source: str
    clips: list[str] = field(default_factory=list)
    acc_persist: float | None = None
    jitter_half: int = 3
    freeze_hold: int | None = None
    word_half: int | None = None
    word_slack: int = 0
    word_erode: int = 0

    def evidence(self, q: np.ndarray, mean_q: np.ndarray, spread: np.ndarray, joints: Sequence[str],
                 word_amp: np.ndarray | None = None) -> np.ndarray:
        """Evidence of every cue (T, m, K): value over weight times null level (> 1 flags).
        ``word_amp``: the take's KNN words' amplitude (:func:`.word_noise.word_amplitude`),
        needed when ``word_half`` is set."""
        wj = None
        if self.word_half and word_amp is not None:
            from .word_noise import word_jitter

            wj = word_jitter(q, mean_q, word_amp, self.word_half, self.word_slack, erode=self.word_erode)
        cue = raw_cues(q, mean_q, spread, joints, self.low, self.high, wj)
        own = typical(cue)
        scale = {k: np.maximum(v, own[k]) for k, v in self.scales.items()}
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.nan_to_num(cue_values(cue, scale, self.acc_persist, self.jitter_half,
                                                 self.freeze_hold) / (self.levels * self.weights), nan=0.0, posinf=0.0)

    def detect(self, q: np.ndarray, mean_q: np.ndarray, spread: np.ndarray, joints: Sequence[str],
               grow: float = 1.0, word_amp: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Flags (T, m) bool, fused evidence (T, m) and the index of the deciding cue (T, m).

        ``grow`` < 1: hysteresis in time, a flagged run of a joint is extended along the
        neighbouring cells whose evidence exceeds ``grow`` (the whole error, not only its
        strongest cells; the mirror cue is not grown, swaps have their own intervals)."""
        return self.decide(self.evidence(q, mean_q, spread, joints, word_amp), grow)

    @staticmethod
    def decide(ev: np.ndarray, grow: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`detect` on evidence (T, m, K) already computed by :meth:`evidence`."""
        best = ev.max(axis=-1)
        dom = np.argmax(ev, axis=-1)
        flags = best > 1.0
        if grow < 1.0:
            weak = (best > grow) & (dom != CUES.index("mirror"))
            flags = _grow(flags, weak)
        return flags, best, dom

    def summary(self) -> dict:
        """JSON-friendly description (weight per cue, calibration figures, clips)."""
        return {"source": self.source, "clips": list(self.clips), "cells": self.n_cells,
                "error_cells": self.n_error_cells, "recall": round(self.recall, 4),
                "false_alarm": round(self.false_alarm, 5),
                "weights": {name: (None if not np.isfinite(w) else float(w)) for name, w in zip(CUES, self.weights)}}


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


@dataclass
class CalibrationMaterial:
    """Raw cues and injected-error masks of the calibration clips (before any fitting)."""

    cues: list[dict[str, np.ndarray]]
    truth: list[np.ndarray]
    names: list[str]
    source: str
    low: np.ndarray | None
    high: np.ndarray | None


def calibration_material(take, others: Sequence, analyse: Callable, joints: Sequence[str], fps: float, *,
                         frames: int = 600, density: float = 0.2, seed: int = 0,
                         texture: Callable | None = None, word_half: int | None = None,
                         word_slack: int = 0, word_erode: int = 0) -> CalibrationMaterial:
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
    density : float
        Share of calibration words given a synthetic error.
    seed : int
    texture : callable, optional
        ``texture(motion) -> Texture``; default :func:`.motion_words.motion_texture`.
    word_half, word_slack, word_erode : int
        With ``word_half``, the words cue is computed from each clip's warped KNN words
        (:mod:`.word_noise`); None: it is 0.
    """
    from .error_injection import inject_at_density

    from .motion_words import motion_texture

    make = texture or (lambda m: motion_texture(m, joints, fps))
    cache: dict[int, object] = {}

    def tex_of(m):
        if id(m) not in cache:
            cache[id(m)] = make(m)
        return cache[id(m)]

    clips, source = calibration_clips(take, others, frames, fps)
    cue_list, truth_list, names = [], [], []
    for i, clip in enumerate(clips):
        tex = tex_of(clip)
        rest = [c for c in others if c is not clip]
        low, high = rotation_range([tex_of(c).q for c in rest]) if rest else rotation_range([tex.q])
        bad, mask, _ = inject_at_density(tex.motion, density, CALIBRATION_KINDS, seed=seed + i,
                                         ranges=CALIBRATION_RANGES)
        res = analyse(bad, rest)
        wj = None
        if word_half is not None and res.neighbours:
            from .word_noise import word_amplitude, word_jitter

            wamp = word_amplitude(res.neighbours[0], res.mean_texture, word_half)
            wj = word_jitter(res.texture.q, res.mean_texture, wamp, word_half, word_slack, erode=word_erode)
        cue_list.append(raw_cues(res.texture.q, res.mean_texture, res.spread, joints, low, high, wj))
        truth_list.append(mask[:, tex.joint_index])
        names.append(clip.name)
    low, high = rotation_range([tex_of(c).q for c in others] if others else [tex_of(take).q])
    return CalibrationMaterial(cue_list, truth_list, names, source, low, high)


def fit_calibration(material: CalibrationMaterial, false_alarm: float = 0.004, null_quantile: float = 0.99,
                    cues: Sequence[str] = DEFAULT_CUES, acc_persist: float | None = None,
                    jitter_half: int = 3, freeze_hold: int | None = None,
                    cue_fa: dict[str, float] | None = None, word_half: int | None = None,
                    word_slack: int = 0, word_erode: int = 0, floor_only: Sequence[str] = (),
                    null_reach: dict[str, int] | None = None) -> Calibration:
    """Null scales and levels, and the cue weights, from :func:`calibration_material`
    (steps 3-4 of the module doc).

    Parameters
    ----------
    false_alarm : float
        Target share of clean (word, joint) pairs flagged on the calibration clips.
    null_quantile : float
        Quantile of a cue over a joint's clean calibration cells taken as its null level.
    cues : sequence of str
        Cues of :data:`.cues.CUES` the detector may use.
    acc_persist : float or None
        Persistence factor of the acceleration cue (:func:`.cues.persistent`; None = off).
    jitter_half : int
        Half window of the jitter cue (:func:`.cues.cue_values`).
    freeze_hold : int or None
        The freeze cue only on holds of at least that many frames (:func:`.cues.cue_values`;
        None = the windowed speed ratio).
    cue_fa : dict of str -> float, optional
        Per cue, a false-alarm rate of its own: the cue's weight is at most its
        :func:`cue_floor` (it may then add up to that share of clean pairs to the budget).
    floor_only : sequence of str
        Cues the greedy allocation may not use: their weight is their :func:`cue_floor`
        only (with a ``cue_fa`` rate; else they stay off).
    null_reach : dict of str -> int, optional
        Per cue, the clean cells within that many frames of an injected error are left out
        of its null level (a windowed cue leaks an error into its clean neighbours).
    word_half, word_slack, word_erode : int
        Recorded in the result: the take's words cue is computed as the material's was.
    """
    cue_list, truth_list = material.cues, material.truth
    clean = [~t for t in truth_list]
    scales = {k: np.median(np.stack([typical(c, ok)[k] for c, ok in zip(cue_list, clean)]), axis=0)
              for k in ("digression", "acceleration", "spread")}
    values = [cue_values(c, {k: np.maximum(v, typical(c)[k]) for k, v in scales.items()}, acc_persist, jitter_half,
                         freeze_hold) for c in cue_list]
    stacked = np.concatenate([np.where(ok[..., None], v, np.nan) for v, ok in zip(values, clean)], 0)
    levels = np.maximum(np.nan_to_num(np.nanquantile(stacked, null_quantile, axis=0), nan=0.0), _FLOORS)
    for name, reach in (null_reach or {}).items():
        k = CUES.index(name)
        far = [~_near(t, reach) for t in truth_list]
        col = np.concatenate([np.where(ok, v[..., k], np.nan) for v, ok in zip(values, far)], 0)
        if np.isfinite(col).any():
            levels[:, k] = np.maximum(np.nan_to_num(np.nanquantile(col, null_quantile, axis=0), nan=0.0), _FLOORS[k])
    lam = fit_levels(values, levels, truth_list, false_alarm, use=[c in cues and c not in floor_only for c in CUES])
    for name, fa in (cue_fa or {}).items():
        if name in cues:
            k = CUES.index(name)
            lam[k] = min(lam[k], cue_floor(values, levels, truth_list, k, fa))
    wj_t = [word_joint(t) for t in truth_list]
    wj_f = [word_joint((v / (levels * lam)).max(-1) > 1.0) for v in values]
    rec = sum(int((f & t).sum()) for f, t in zip(wj_f, wj_t)) / max(sum(int(t.sum()) for t in wj_t), 1)
    fa = sum(int((f & ~t).sum()) for f, t in zip(wj_f, wj_t)) / max(sum(int((~t).sum()) for t in wj_t), 1)
    return Calibration(scales, levels, lam, material.low, material.high, int(sum(t.size for t in truth_list)),
                       int(sum(t.sum() for t in truth_list)), rec, fa, material.source, list(material.names), acc_persist, jitter_half, freeze_hold,
                       word_half, word_slack, word_erode)


def calibrate(take, others: Sequence, analyse: Callable, joints: Sequence[str], fps: float, *,
              false_alarm: float = 0.004, frames: int = 600, density: float = 0.2, seed: int = 0,
              null_quantile: float = 0.99, cues: Sequence[str] = DEFAULT_CUES,
              texture: Callable | None = None, acc_persist: float | None = None,
              jitter_half: int = 3, freeze_hold: int | None = None,
              cue_fa: dict[str, float] | None = None, word_half: int | None = None,
              word_slack: int = 0, word_erode: int = 0, floor_only: Sequence[str] = (),
              null_reach: dict[str, int] | None = None) -> Calibration:
    """:func:`calibration_material` then :func:`fit_calibration` (the module doc's steps);
    ``word_half`` None: the words cue is not computed (0)."""
    mat = calibration_material(take, others, analyse, joints, fps, frames=frames, density=density, seed=seed,
                               texture=texture, word_half=word_half, word_slack=word_slack, word_erode=word_erode)
    return fit_calibration(mat, false_alarm, null_quantile, cues, acc_persist, jitter_half, freeze_hold, cue_fa,
                           word_half, word_slack, word_erode, floor_only, null_reach)
