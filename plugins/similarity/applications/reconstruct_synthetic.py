"""Synthetic markers from a skeleton take, and the errors of its reconstruction: what the
evaluation of ``analyses.reconstruct`` (Krüger et al. 2010 §5.2, Table 3) runs.

:func:`synthetic_markers` / :func:`synthetic_heading` give the paper's control signal of a
take (±1 mm); :func:`reconstruct_motion` reconstructs a take from it with a
:class:`PosePrior` that withholds the take (:func:`withheld`, :class:`PriorCache`) and
reports :func:`joint_errors` in cm.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from mocapflow.framework import DataError, Motion
from mocapflow.framework.normalize import facing_angles

from .reconstruct import DEFAULT_MARKERS, MODEL, PosePrior, ReconstructModel, ReconstructParams, reconstruct
from .reconstruct_prior import PriorStore, bone_lengths
from .retarget import positions_to_motion


def synthetic_markers(
    motion: Motion,
    markers: Sequence[str] = DEFAULT_MARKERS,
    noise: float = 0.001,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Marker positions from a motion, each coordinate disturbed uniformly in ``±noise`` metres.

    Returns ndarray of shape (T, len(markers), 3), metres (the paper: ±1 mm).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    pos = motion.canonical_positions(tuple(markers))
    if np.isnan(pos).any():
        missing = [m for m, i in zip(markers, motion.skeleton.canonical_indices(tuple(markers)), strict=True) if i < 0]
        raise DataError(f"motion {motion.name!r} lacks marker joints {missing}")
    return pos + rng.uniform(-noise, noise, pos.shape)


def synthetic_heading(motion: Motion, noise: float = 0.001, rng: np.random.Generator | None = None) -> np.ndarray:
    """The root's heading (T,) radians from the hip joints, each coordinate disturbed
    uniformly in ``±noise`` metres (a pelvis marker cluster's orientation)."""
    hips = synthetic_markers(motion, ("lhip", "rhip"), noise, rng)
    return facing_angles(hips, ("lhip", "rhip"))


def joint_errors(recon: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Per-joint mean and max error (P,), overall average and max per-frame mean, all in cm.

    recon, truth : (T, P, 3) metres; NaN joints of ``truth`` are ignored.
    """
    err = np.linalg.norm(recon - truth, axis=-1) * 100.0
    ok = ~np.isnan(err)
    with np.errstate(invalid="ignore"):
        per_joint_mean = np.nanmean(np.where(ok, err, np.nan), 0)
        per_joint_max = np.nanmax(np.where(ok, err, np.nan), 0)
        frame_mean = np.nanmean(np.where(ok, err, np.nan), 1)
    return per_joint_mean, per_joint_max, float(np.nanmean(frame_mean)), float(np.nanmax(frame_mean))


def withheld(store: PriorStore, motion: Motion, leave_out: str) -> np.ndarray:
    """Mask (C,) of prior takes to leave out for a test clip: same name, same subject, or none
    (mirror images go with their take)."""
    if leave_out == "subject":
        subj = str(motion.metadata.get("subject", ""))
        return np.array([c["subject"] == subj for c in store.clips])
    if leave_out == "clip":
        return np.array([c["name"] == motion.name for c in store.clips])
    return np.zeros(len(store.clips), bool)


class PriorCache:
    """The last :class:`PosePrior` built from ``store``, reused while the kept takes and the
    performer's bone lengths stay the same (test clips of one performer)."""

    def __init__(self, store: PriorStore, model: ReconstructModel = MODEL) -> None:
        self.store, self.model = store, model
        self._key: bytes | None = None
        self._prior: PosePrior | None = None

    def get(self, keep: np.ndarray, lengths: np.ndarray) -> PosePrior:
        key = np.asarray(keep, bool).tobytes() + np.round(np.asarray(lengths), 4).tobytes()
        if key != self._key or self._prior is None:
            self._prior = PosePrior.build(self.store, lengths, keep, model=self.model)
            self._key = key
        return self._prior

    def for_motion(self, motion: Motion, leave_out: str) -> PosePrior:
        """The prior for a test clip: its ``leave_out`` takes withheld, its skeleton's bone lengths."""
        lengths = bone_lengths(motion.canonical_positions(self.store.joints), self.store.joints)
        if not np.isfinite(lengths).all():
            raise DataError(f"motion {motion.name!r} lacks pose joints of the prior {list(self.store.joints)}")
        return self.get(~withheld(self.store, motion, leave_out), lengths)


def reconstruct_motion(
    motion: Motion, prior: PosePrior, params: ReconstructParams | None = None, model: ReconstructModel = MODEL
) -> tuple[Motion, dict[str, Any]]:
    """Reconstruct one clip from its synthetic markers; the result and its errors.

    Returns the reconstructed Motion (test clip's skeleton, ``<name>_recon``) and a dict:
    ``joints``, ``mean_cm``/``max_cm`` per joint, ``avg_cm``, ``max_frame_cm`` (worst
    per-frame average), ``max_joint_cm`` (worst joint of any frame), ``fk_avg_cm``,
    ``seconds`` (reconstruction time, excluding the prior), ``confidence``, ``frame_cm``
    and ``frame_max_cm`` (T,) (per-frame confidence, mean and worst joint error),
    ``reconstruction`` (the :class:`Reconstruction`).
    """
    p = params or ReconstructParams()
    rng = np.random.default_rng(model.seed)
    markers = synthetic_markers(motion, model.markers, model.noise, rng)
    heading = synthetic_heading(motion, model.noise, rng) if model.root_heading else None
    t0 = time.perf_counter()
    rec = reconstruct(markers, prior, p, model, root_heading=heading, fps=motion.fps)
    world = rec.positions
    seconds = time.perf_counter() - t0
    truth = motion.canonical_positions(prior.joints)
    mean, mx, avg, worst = joint_errors(world, truth)
    out = positions_to_motion(
        motion.skeleton,
        world,
        prior.joints,
        motion.fps,
        name=f"{motion.name}_recon",
        metadata={**motion.metadata, "reconstructed_from": motion.name},
    )
    _, _, fk_avg, _ = joint_errors(out.canonical_positions(prior.joints), truth)
    return out, {
        "joints": prior.joints,
        "mean_cm": mean,
        "max_cm": mx,
        "avg_cm": avg,
        "max_frame_cm": worst,
        "max_joint_cm": float(np.nanmax(mx)),
        "fk_avg_cm": fk_avg,
        "seconds": seconds,
        "confidence": rec.confidence,
        "frame_cm": np.nanmean(np.linalg.norm(world - truth, axis=-1), 1) * 100.0,
        "frame_max_cm": np.nanmax(np.linalg.norm(world - truth, axis=-1), 1) * 100.0,
        "reconstruction": rec,
    }
