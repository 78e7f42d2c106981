"""Seeded capture-error injection with ground-truth masks (cleaning evaluation).

Errors go into the local joint rotations of a clean clip at the 24 fps analysis rate
(durations in frames, angles in degrees, :data:`ERROR_RANGES` the protocol's): ``spike``
(the joint jumps away and back; ``flip``: by 150-175 degrees, as a solver's flipped
joint), ``offset`` (a constant rotation held), ``drift`` (growing
linearly, then snapping back; the calibration's only), ``freeze`` (the onset rotation held,
as after an occlusion), ``noise`` (a random rotation per frame), ``swap`` (a left limb and
its right mirror exchanged); ``ramp`` (a smooth drifting offset: eased in over a quarter of
the span, its axis turning while held, eased out, as a marker sliding off and back; the
generalization protocol's family the cleaner was never tuned on). :func:`inject_at_density` adds them until a share of the
source words holds one (the paper's ~12.5 %, §6). The mask marks the cells moved more than
``min_angle`` (a drift's first frames or a still joint's freeze are invisible).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.motion import Motion

from ..calibrated.cues import MIRROR_CHAINS, mirror

ERROR_KINDS: tuple[str, ...] = ("spike", "offset", "drift", "freeze", "noise", "swap", "ramp", "flip")

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
    "ramp": ((8, 32), (20.0, 60.0)),
    "flip": ((1, 3), (150.0, 175.0)),
}

#: Limb chains exchanged by a "swap" error (canonical names).
SWAP_CHAINS = MIRROR_CHAINS

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
    return cast("np.ndarray", v / np.linalg.norm(v, axis=1, keepdims=True))


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
    if kind in ("spike", "offset", "flip"):
        for j in joints:
            off = quat.from_axis_angle(_random_axis(rng)[0], np.deg2rad(magnitude))
            rot[span, j] = quat.mul(rot[span, j], off)
    elif kind == "drift":
        for j in joints:
            axis = _random_axis(rng)[0]
            ang = np.deg2rad(magnitude) * (np.arange(1, n + 1) / n)
            rot[span, j] = quat.mul(rot[span, j], quat.from_axis_angle(np.broadcast_to(axis, (n, 3)), ang))
    elif kind == "ramp":
        r = max(1, n // 4)
        ease = np.minimum(np.minimum(np.arange(1, n + 1), np.arange(n, 0, -1)) / r, 1.0)
        ease = ease * ease * (3.0 - 2.0 * ease)  # smoothstep in and out
        for j in joints:
            a0, a1 = _random_axis(rng, 2)
            w = np.linspace(0.0, 0.5, n)[:, None]
            axis = (1.0 - w) * a0 + w * a1
            axis /= np.linalg.norm(axis, axis=1, keepdims=True)
            rot[span, j] = quat.mul(rot[span, j], quat.from_axis_angle(axis, np.deg2rad(magnitude) * ease))
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
        rot[np.ix_(span, np.asarray(left))] = mirror(rq)
        rot[np.ix_(span, np.asarray(right))] = mirror(lq)
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
    apply: Callable[..., None] | None = None,
    known: Sequence[str] = ERROR_KINDS,
) -> tuple[Motion, np.ndarray, list[InjectedError]]:
    """Corrupt a clean ``motion`` (24 fps) until about ``density`` of its source words
    (``word_length`` frames every ``word_step``) hold an error.

    Errors (kind from ``kinds``; joints, duration, magnitude and start drawn from
    ``default_rng(seed)``; ``ranges`` over :data:`ERROR_RANGES`) are added one at a time
    ``margin`` frames from every earlier one and the clip ends, at least one when any fits,
    up to ``max_tries`` placements; short clips overshoot. ``apply`` (default
    :func:`apply_error`) writes one error of the ``known`` kinds (another injector family:
    :mod:`.injection_b`). Returns the corrupted motion, the
    mask (T, J) of cells moved more than ``min_angle`` degrees, and the errors in time order.
    """
    from ..paper.motion_words import source_word_starts

    if not kinds:
        raise DataError("inject_at_density needs at least one error kind")
    unknown = [k for k in kinds if k not in known]
    if unknown:
        raise DataError(f"unknown error kinds {unknown} (known: {', '.join(known)})")
    apply = apply or apply_error
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
        apply(trial, motion, kind, start, start + dur, joints, mag, rng)
        trial = quat.normalize(trial)
        new_mask = np.rad2deg(quat.geodesic_angle(trial, motion.rotations)) > min_angle
        if not new_mask[start : start + dur].any():
            continue  # e.g. a freeze of a joint that hardly moves: nothing anyone could see
        rot, mask = trial, new_mask
        busy[start : start + dur] = True
        errors.append(InjectedError(kind, joints, start, start + dur, mag))
    errors.sort(key=lambda e: e.start)
    return motion.with_arrays(rotations=rot), mask, errors
