"""Seeded, documented capture-error injection with ground-truth masks (cleaning evaluation).

Errors are injected into the local joint rotations of a clean clip (normally already at
the cleaner's 24 fps analysis rate, so masks align with the MDM). Each kind imitates a
failure seen in optical capture; magnitudes and durations are drawn from the ranges below
with ``numpy.random.default_rng(seed)`` (frames at 24 fps; angles in degrees):

========  ==========================================================  ============  =========
kind      what                                                        duration      magnitude
========  ==========================================================  ============  =========
spike     single-frame peaks: the joint jumps away and back           1-2 frames    30-60
offset    rectangular distortion: a constant rotation held            8-24 frames   20-45
drift     slow drift: a rotation growing linearly, then snapping back 24-36 frames  30-60 end
freeze    frozen joint: the rotation at onset is held (gap filled by  12-24 frames  (motion)
          holding, as after an occlusion)
noise     heavy jitter: an independent random rotation per frame      12-24 frames  sd 15
swap      mislabelled markers: a left limb and its right mirror are   12-24 frames  (motion)
          exchanged (mirror across the sagittal plane)
========  ==========================================================  ============  =========

The paper (§6) gives no magnitudes or durations for its artificial errors, only that
about 1,000 of 8,000 words (12.5 %) held an error; with every kind once per test clip of
12-18 s, 36-44 % of our words and 0.8-1.5 % of the cells are erroneous (denser than the
paper: word precision is easier here, not harder).

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
from mocapflow.framework.motion import Motion

ERROR_KINDS: tuple[str, ...] = ("spike", "offset", "drift", "freeze", "noise", "swap")

#: (duration range in frames, magnitude range in degrees) per kind.
ERROR_RANGES: dict[str, tuple[tuple[int, int], tuple[float, float]]] = {
    "spike": ((1, 2), (30.0, 60.0)),
    "offset": ((8, 24), (20.0, 45.0)),
    "drift": ((24, 36), (30.0, 60.0)),
    "freeze": ((12, 24), (0.0, 0.0)),
    "noise": ((12, 24), (15.0, 15.0)),
    "swap": ((12, 24), (0.0, 0.0)),
}

#: Limb chains exchanged by a "swap" error (canonical names).
SWAP_CHAINS: tuple[tuple[tuple[str, ...], tuple[str, ...]], ...] = (
    (("lshoulder", "lelbow", "lwrist"), ("rshoulder", "relbow", "rwrist")),
    (("lhip", "lknee", "lankle"), ("rhip", "rknee", "rankle")),
)

#: Joints that single-joint errors pick from (the limbs, spine and head).
ERROR_JOINTS: tuple[str, ...] = (
    "lhip", "lknee", "lankle", "rhip", "rknee", "rankle", "lowerback", "chest", "neck", "head",
    "lshoulder", "lelbow", "lwrist", "rshoulder", "relbow", "rwrist",
)


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


def mirror(q: np.ndarray) -> np.ndarray:
    """Mirror local rotations across the sagittal (y-z) plane: (w, x, y, z) -> (w, x, -y, -z)."""
    out = np.array(q, dtype=float, copy=True)
    out[..., 2:] *= -1.0
    return out


def apply_error(rot: np.ndarray, motion: Motion, kind: str, start: int, end: int, joints: Sequence[int],
                magnitude: float, rng: np.random.Generator) -> None:
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


def inject_errors(motion: Motion, kinds: Sequence[str] = ERROR_KINDS, per_kind: int = 1, seed: int = 0,
                  min_angle: float = 10.0, margin: int = 12) -> tuple[Motion, np.ndarray, list[InjectedError]]:
    """Corrupt a clean clip with seeded errors at non-overlapping times.

    The clip is cut into equal slots, one error per slot, placed at random inside; when
    the clip is too short for every error, a seeded random subset that fits is injected
    (a slot needs the longest duration plus ``margin`` frames).

    Parameters
    ----------
    motion : Motion
        Clean clip (frames at the rate the durations are meant for, normally 24 fps).
    kinds : sequence of str
        Error kinds (:data:`ERROR_KINDS`); each is injected ``per_kind`` times.
    seed : int
    min_angle : float
        Degrees; cells changed by more are marked in the mask.
    margin : int
        Frames kept free between errors and at the clip ends.

    Returns
    -------
    corrupted : Motion
    mask : ndarray of bool, shape (T, J)
        Ground truth: cells more than ``min_angle`` away from the clean rotation.
    errors : list of InjectedError
    """
    rng = np.random.default_rng(seed)
    c = motion.skeleton.canonical
    rot = motion.rotations.copy()
    t = motion.n_frames
    jobs = [k for k in kinds for _ in range(per_kind)]
    rng.shuffle(jobs)
    need = max(ERROR_RANGES[k][0][1] for k in jobs) + margin if jobs else 1
    jobs = jobs[: max(1, (t - margin) // need)]
    # slots: equal stretches of the clip, one error each, placed randomly inside
    slot = (t - margin) // max(1, len(jobs))
    errors: list[InjectedError] = []
    for i, kind in enumerate(jobs):
        (dmin, dmax), (amin, amax) = ERROR_RANGES[kind]
        dur = int(rng.integers(dmin, dmax + 1))
        lo = margin + i * slot
        hi = lo + slot - dur - margin // 2
        if slot <= 0 or hi <= lo:
            raise DataError(f"motion {motion.name!r} ({t} frames) is too short for {len(jobs)} errors")
        start = int(rng.integers(lo, hi))
        if kind == "swap":
            chains = [ch for ch in SWAP_CHAINS if all(j in c for j in ch[0] + ch[1])]
            if not chains:
                continue
            left, right = chains[int(rng.integers(len(chains)))]
            joints = tuple(c[j] for j in left) + tuple(c[j] for j in right)
        else:
            pool = [c[j] for j in ERROR_JOINTS if j in c]
            joints = (pool[int(rng.integers(len(pool)))],)
        mag = float(rng.uniform(amin, amax))
        apply_error(rot, motion, kind, start, start + dur, joints, mag, rng)
        errors.append(InjectedError(kind, joints, start, start + dur, mag))
    rot = quat.normalize(rot)
    mask = np.rad2deg(quat.geodesic_angle(rot, motion.rotations)) > min_angle
    return motion.with_arrays(rotations=rot), mask, errors
