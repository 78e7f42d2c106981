"""Scores of the cleaning protocol (:mod:`.clean_eval`): baselines, detection counts, eq. 2,
and the source glitches of the "clean" references."""

from __future__ import annotations

from collections.abc import Mapping
from typing import cast

import numpy as np

from mocapflow.framework import quaternions as quat


def rotation_vectors(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, radians) of unit quaternions (..., 4), w >= 0."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(s, q[..., :1])
    return np.where(s > 1e-12, q[..., 1:] / np.where(s > 1e-12, s, 1.0) * ang, 2.0 * q[..., 1:])


def _log_norm_sq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """||log(a^-1 b)||^2 per quaternion pair (half-angle convention of eq. 1/2)."""
    return cast("np.ndarray", np.arccos(np.clip(np.abs(np.sum(a * b, -1)), 0.0, 1.0)) ** 2)


class RotationBaselines:
    """Baselines (a) limits and (b) derivative thresholds, learned from ``clean`` textures
    (T, m, 4) of the same joints and rate."""

    def __init__(self, clean: list[np.ndarray]) -> None:
        rv = np.concatenate([rotation_vectors(q) for q in clean], 0)
        self.low_ = rv.min(0)
        self.high_ = rv.max(0)
        speed = np.concatenate([quat.geodesic_angle(q[1:], q[:-1]) for q in clean if len(q) > 1], 0)
        self.max_speed_ = speed.max(0)

    def limits(self, q: np.ndarray) -> np.ndarray:
        rv = rotation_vectors(q)
        return cast("np.ndarray", np.any((rv < self.low_) | (rv > self.high_), axis=-1))

    def derivative(self, q: np.ndarray) -> np.ndarray:
        out = np.zeros(q.shape[:2], bool)
        if len(q) > 1:
            fast = quat.geodesic_angle(q[1:], q[:-1]) > self.max_speed_
            out[1:] |= fast
            out[:-1] |= fast
        return out


def scores(
    flagged: np.ndarray, truth: np.ndarray, starts: np.ndarray, n: int, moved: np.ndarray | None = None
) -> dict[str, int]:
    """Cell, word and (word, joint) true/false positive and false negative counts of
    ``flagged`` against ``truth`` (T, m); ``starts`` are the source words (length ``n``).

    ``moved`` (T, m): the cells the injection changed at all; false positives on cells moved
    below the ground truth's angle (a swapped leg's hip, restored exactly) are also counted
    apart (``*fp_sub``) for the "don't care" precision ``*_precision_dc``."""
    tp = int((flagged & truth).sum())
    fp = int((flagged & ~truth).sum())
    fn = int((~flagged & truth).sum())
    jt = np.array([truth[s : s + n].any(0) for s in starts], bool).reshape(len(starts), truth.shape[1])
    jf = np.array([flagged[s : s + n].any(0) for s in starts], bool).reshape(len(starts), truth.shape[1])
    wt, wf = jt.any(1), jf.any(1)
    out = {
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "word_tp": int((wt & wf).sum()),
        "word_fp": int((~wt & wf).sum()),
        "word_fn": int((wt & ~wf).sum()),
        "wj_tp": int((jt & jf).sum()),
        "wj_fp": int((~jt & jf).sum()),
        "wj_fn": int((jt & ~jf).sum()),
    }
    if moved is not None:
        jm = np.array([moved[s : s + n].any(0) for s in starts], bool).reshape(len(starts), truth.shape[1])
        out.update(
            {
                "fp_sub": int((flagged & ~truth & moved).sum()),
                "wj_fp_sub": int((~jt & jf & jm).sum()),
                "word_fp_sub": int((~wt & wf & jm.any(1)).sum()),
            }
        )
    return out


def _ratios(c: Mapping[str, int]) -> dict[str, float]:
    def div(a: int, b: int) -> float:
        return float(a) / b if b else float("nan")

    dc = {}
    if "fp_sub" in c:
        dc = {
            "precision_dc": div(c["tp"], c["tp"] + c["fp"] - c["fp_sub"]),
            "wj_precision_dc": div(c["wj_tp"], c["wj_tp"] + c["wj_fp"] - c["wj_fp_sub"]),
            "word_precision_dc": div(c["word_tp"], c["word_tp"] + c["word_fp"] - c["word_fp_sub"]),
        }
    return {
        **dc,
        "recall": div(c["tp"], c["tp"] + c["fn"]),
        "precision": div(c["tp"], c["tp"] + c["fp"]),
        "word_recall": div(c["word_tp"], c["word_tp"] + c["word_fn"]),
        "word_precision": div(c["word_tp"], c["word_tp"] + c["word_fp"]),
        "wj_recall": div(c["wj_tp"], c["wj_tp"] + c["wj_fn"]),
        "wj_precision": div(c["wj_tp"], c["wj_tp"] + c["wj_fp"]),
    }


def source_glitches(
    q: np.ndarray, far: float = 60.0, back: float = 45.0, typical: float = 30.0, step: float = 45.0, pad: int = 2
) -> np.ndarray:
    """Cells of a "clean" reference that are capture glitches of the source itself, (T, m) bool.

    A joint normally near its mean pose (median angle below ``typical`` degrees) that leaves
    it by more than ``far``, entering or leaving by a step over ``step`` degrees in one
    24-fps frame (the salsa ankles turned 160-176 degrees for 0.6-0.9 s, wrists out 130
    degrees within 0.1 s: no joint turns that far that fast), grown while above ``back``
    plus ``pad`` frames; a joint not near its mean pose that turns over ``2 step`` in a
    frame is broken throughout (the head of 60_06) and marked whole. The protocol scores
    repairs of these cells apart (eq. 2 against this reference counts them as damage)."""
    from ..calibrated.bounded_repair import _runs

    out = np.zeros(q.shape[:2], bool)
    for j in range(q.shape[1]):
        w, v = np.linalg.eigh(np.einsum("ti,tk->ik", q[:, j], q[:, j]))
        ang = np.rad2deg(quat.geodesic_angle(q[:, j], np.broadcast_to(v[:, -1], q[:, j].shape)))
        sp = np.rad2deg(quat.geodesic_angle(q[1:, j], q[:-1, j]))
        if np.median(ang) >= typical and len(sp) and sp.max() > 2 * step:
            out[:, j] = True  # broken throughout: far from any pose it holds, and turning > 90 degrees in a frame
            continue
        if np.median(ang) >= typical or not (ang > far).any():
            continue
        for a, b in _runs(ang > back):
            if (ang[a:b] > far).any() and (sp[max(0, a - 2) : b + 1] > step).any():
                out[max(0, a - pad) : b + pad, j] = True
    return out
