"""Seeded, documented capture-error injection with ground-truth masks (cleaning evaluation).

Errors are injected into the local joint rotations of a clean clip (normally already at
the cleaner's 24 fps analysis rate, so masks align with the MDM). Each kind imitates a
failure seen in optical capture; magnitudes and durations are drawn from the ranges below
with ``numpy.random.default_rng(seed)`` (frames at 24 fps; angles in degrees). The default
ranges (:data:`ERROR_RANGES`) are those of the protocol of ``analyses.clean_eval``:

========  ==========================================================  ============  =========
kind      what                                                        duration      magnitude
========  ==========================================================  ============  =========
spike     peaks: the joint jumps away and back                        1-3 frames    30-90
offset    burst: a constant rotation held                             6-18 frames   20-45
drift     slow drift: a rotation growing linearly, then snapping back 24-36 frames  30-60 end
freeze    frozen joint: the rotation at onset is held (gap filled by  12-24 frames  (motion)
          holding, as after an occlusion)
noise     heavy jitter: an independent random rotation per frame      8-16 frames   sd 15
swap      mislabelled markers: a left limb and its right mirror are   12-24 frames  (motion)
          exchanged (mirror across the sagittal plane)
========  ==========================================================  ============  =========

:func:`inject_at_density` adds seeded random errors until a target share of the source
words (the paper's ~12.5 %, §6: about 1,000 of 8,000 words) holds an error, which is the
protocol of ``analyses.clean_eval``; :data:`PROTOCOL_KINDS` are its kinds (drift is used by
the calibration's self-supervision, with wider ranges).

The ground-truth mask marks the (frame, joint) cells whose rotation ends up more than
``min_angle`` (default 10 degrees) from the clean rotation: a drift's first frames and a
freeze of a joint that hardly moved are not errors anyone could see.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.motion import Motion

from ..calibrated.cues import mirror

ERROR_KINDS: tuple[str, ...] = ("spike", "offset", "drift", "freeze", "noise", "swap")

#: The kinds of the evaluation protocol at the paper's density.
PROTOCOL_KINDS: tuple[str, ...] = ("spike", "offset", "freeze", "noise", "swap")

Ranges = dict[str, tuple[tuple[int, int], tuple[float, float]]]

#: (duration range in frames, magnitude range in degrees) per kind.
ERROR_RANGES: Ranges = {
    "spike": ((1, 3), (30.0, 90.0)),
    "offset": ((6, 18), (20.0, 45.0)),
    "drift": ((24, 36), (30.0, 60.0)),
    "freeze": ((12, 24), (0.0, 0.0)),
    "noise": ((8, 16), (15.0, 15.0)),
    "swap": ((12, 24), (0.0, 0.0)),
}

#: Limb chains exchanged by a "swap" error (canonical names).
SWAP_CHAINS: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = (
    (("lshoulder", "lelbow", "lwrist"), ("rshoulder", "relbow", "rwrist")),
    (("lhip", "lknee", "lankle"), ("rhip", "rknee", "rankle")),
)

#: Joints that single-joint errors pick from (the limbs, spine and head).
_NOT_ERR = ("root", "ltoes", "rtoes", "upperback", "headtop", "lclavicle", "lfingers", "rclavicle", "rfingers")
ERROR_JOINTS: tuple[str, ...] = tuple(j for j in CANONICAL_JOINTS if j not in _NOT_ERR)


@dataclass(frozen=True)
class InjectedError:
    """One injected error: kind, skeleton joint indices, frames [start, end), magnitude (deg)."""

    kind: str
    joints: tuple[int, ...]
    start: int
    end: int
    magnitude: float


def _random_axis(rng: np.random.Generator, n: int = 1) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def apply_error(
    rot: np.ndarray,
    motion: Motion,
    kind: str,
    start: int,
    end: int,
    joints: Sequence[int],
    magnitude: float,
    rng: np.random.Generator,
) -> None:
    """Write one error into ``rot (T, J, 4)`` in place (see the module table)."""
    span = np.arange(start, end)
    n = len(span)
    if kind in ("spike", "offset"):
        for j in joints:
            off = quat.from_axis_angle(_random_axis(rng)[0], np.deg2rad(magnitude))
            rot[span, j] = quat.mul(rot[span, j], off)
    elif kind == "drift":
        for j in joints:
            axis = _random_axis(rng)[0]
            ang = np.deg2rad(magnitude) * (np.arange(1, n + 1) / n)
            rot[span, j] = quat.mul(rot[span, j], quat.from_axis_angle(np.broadcast_to(axis, (n, 3)), ang))
    elif kind == "freeze":
        for j in joints:
            rot[span, j] = rot[start, j]
    elif kind == "noise":
        for j in joints:
            ang = np.deg2rad(magnitude) * rng.standard_normal(n)
            rot[span, j] = quat.mul(rot[span, j], quat.from_axis_angle(_random_axis(rng, n), ang))
    elif kind == "swap":
        half = len(joints) // 2
        left, right = list(joints[:half]), list(joints[half:])
        lq, rq = rot[span][:, left].copy(), rot[span][:, right].copy()
        rot[np.ix_(span, left)] = mirror(rq)
        rot[np.ix_(span, right)] = mirror(lq)
    else:
        raise DataError(f"unknown error kind {kind!r} (known: {', '.join(ERROR_KINDS)})")


def _pick_joints(rng: np.random.Generator, motion: Motion, kind: str) -> tuple[int, ...] | None:
    """Skeleton joints of one error: a swapped limb pair (left chain then right) or one joint."""
    c = motion.skeleton.canonical
    if kind == "swap":
        chains = [ch for ch in SWAP_CHAINS if all(j in c for j in ch[0] + ch[1])]
        if not chains:
            return None
        left, right = chains[int(rng.integers(len(chains)))]
        return tuple(c[j] for j in left) + tuple(c[j] for j in right)
    pool = [c[j] for j in ERROR_JOINTS if j in c]
    return (pool[int(rng.integers(len(pool)))],) if pool else None


def inject_at_density(
    motion: Motion,
    density: float = 0.125,
    kinds: Sequence[str] = PROTOCOL_KINDS,
    seed: int = 0,
    min_angle: float = 10.0,
    ranges: Ranges | None = None,
    word_length: int = 15,
    word_step: int = 5,
    margin: int = 4,
    max_tries: int = 200,
) -> tuple[Motion, np.ndarray, list[InjectedError]]:
    """Corrupt a clean clip until about ``density`` of its source words hold an error.

    Errors (kind drawn uniformly from ``kinds``, joints, duration, magnitude and start drawn
    from ``numpy.random.default_rng(seed)``) are added one at a time at random places that
    keep ``margin`` frames from every earlier error, while the share of erroneous words
    (15-frame words every 5 frames, a word being erroneous when any of its cells is in the
    mask) is below ``density``; at least one error is injected when any fits. Short clips
    overshoot the density (one error is already several words); the measured share is
    what the evaluation reports.

    Parameters
    ----------
    motion : Motion
        Clean clip at the rate the durations are meant for (24 fps).
    density : float
        Target share of erroneous source words (the paper: ~0.125).
    kinds : sequence of str
    seed : int
    min_angle : float
        Degrees; cells changed by more are marked in the mask.
    ranges : dict, optional
        (duration range, magnitude range) per kind; default :data:`ERROR_RANGES`.
    word_length, word_step : int
        The source words the density is counted on (frames).
    margin : int
        Frames kept free between errors and at the clip ends.
    max_tries : int
        Random placements tried before giving up on reaching the density.

    Returns
    -------
    corrupted : Motion
    mask : ndarray of bool, shape (T, J)
    errors : list of InjectedError, in time order
    """
    from ..paper.motion_words import source_word_starts

    if not kinds:
        raise DataError("inject_at_density needs at least one error kind")
    unknown = [k for k in kinds if k not in ERROR_KINDS]
    if unknown:
        raise DataError(f"unknown error kinds {unknown} (known: {', '.join(ERROR_KINDS)})")
    ranges = {**ERROR_RANGES, **(ranges or {})}
    rng = np.random.default_rng(seed)
    rot = motion.rotations.copy()
    t = motion.n_frames
    starts = source_word_starts(t, word_length, word_step)
    busy = np.zeros(t, bool)
    errors: list[InjectedError] = []
    mask = np.zeros(rot.shape[:2], bool)
    for _ in range(max_tries):
        if len(starts) == 0:
            break
        share = np.mean([mask[s : s + word_length].any() for s in starts])
        if errors and share >= density:
            break
        kind = str(kinds[int(rng.integers(len(kinds)))])
        (dmin, dmax), (amin, amax) = ranges[kind]
        dur = int(rng.integers(dmin, dmax + 1))
        if t - 2 * margin - dur <= 0:
            continue
        start = int(rng.integers(margin, t - margin - dur + 1))
        if busy[max(0, start - margin) : start + dur + margin].any():
            continue
        joints = _pick_joints(rng, motion, kind)
        if joints is None:
            continue
        mag = float(rng.uniform(amin, amax))
        trial = rot.copy()
        apply_error(trial, motion, kind, start, start + dur, joints, mag, rng)
        trial = quat.normalize(trial)
        new_mask = np.rad2deg(quat.geodesic_angle(trial, motion.rotations)) > min_angle
        if not new_mask[start : start + dur].any():
            continue  # e.g. a freeze of a joint that hardly moves: nothing anyone could see
        rot, mask = trial, new_mask
        busy[start : start + dur] = True
        errors.append(InjectedError(kind, joints, start, start + dur, mag))
    errors.sort(key=lambda e: e.start)
    return motion.with_arrays(rotations=rot), mask, errors
