"""A second injector family (family B), written and committed before any cleaner figure was
measured on it: errors no detector of the calibrated cleaner was designed for, modelled on
what optical capture pipelines produce (:func:`apply_error_b`, durations in frames at the
injection rate, angles in degrees):

* ``gapfill``: an occlusion bridged by the capture software: the joint slerped linearly
  from its rotation before the gap to its rotation after it (the motion inside is lost);
* ``pop``: a marker relabelled for a moment: an offset that appears at once and decays
  exponentially (time constant a third of the span), then is cut at the span's end;
* ``lag``: a solver fed stale markers: the joint repeats its own rotation ``d`` frames
  earlier (``d`` from the magnitude range, in 24-fps frames times the rate factor);
* ``overshoot``: the joint's rotation away from its pose at the span's start scaled by a
  factor ``1 + magnitude / 100``;
* ``tremor``: a sinusoidal wobble of 6-10 Hz about a random axis, amplitude ``magnitude``.

:func:`inject_b` places them at a share of the words exactly as
:func:`.error_injection.inject_at_density` does (that function, with this ``apply``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion

from .error_injection import Ranges, _random_axis, inject_at_density

if TYPE_CHECKING:  # pragma: no cover
    from .error_injection import InjectedError

KINDS_B: tuple[str, ...] = ("gapfill", "pop", "lag", "overshoot", "tremor")

#: (duration range in 24-fps frames, magnitude range) per kind: degrees (pop, tremor), the
#: delay in 24-fps frames (lag), the scale in per cent over 1 (overshoot); gapfill none.
RANGES_B: Ranges = {
    "gapfill": ((3, 30), (0.0, 0.0)),
    "pop": ((3, 20), (15.0, 80.0)),
    "lag": ((4, 30), (2.0, 8.0)),
    "overshoot": ((6, 30), (50.0, 150.0)),
    "tremor": ((6, 30), (5.0, 25.0)),
}


def apply_error_b(
    rot: np.ndarray,
    motion: Motion,
    kind: str,
    start: int,
    end: int,
    joints: Sequence[int],
    magnitude: float,
    rng: np.random.Generator,
) -> None:
    """Write one family-B error into ``rot (T, J, 4)`` in place (module doc)."""
    n = end - start
    r = max(1.0, motion.fps / 24.0)
    t = np.arange(n)
    for j in joints:
        if kind == "gapfill":
            a, b = rot[max(start - 1, 0), j], rot[min(end, len(rot) - 1), j]
            b = np.where(np.sum(a * b) < 0, -b, b)
            rot[start:end, j] = quat.slerp(np.broadcast_to(a, (n, 4)), np.broadcast_to(b, (n, 4)), (t + 1) / (n + 1))
        elif kind == "pop":
            ang = np.deg2rad(magnitude) * np.exp(-t / max(n / 3.0, 1.0))
            axis = np.broadcast_to(_random_axis(rng)[0], (n, 3))
            rot[start:end, j] = quat.mul(rot[start:end, j], quat.from_axis_angle(axis, ang))
        elif kind == "lag":
            d = int(round(magnitude * r))
            src = np.clip(np.arange(start, end) - d, 0, None)
            rot[start:end, j] = rot[src, j].copy()
        elif kind == "overshoot":
            base = rot[start, j]
            rel = quat.mul(quat.conjugate(np.broadcast_to(base, (n, 4))), rot[start:end, j])
            rel = np.where(rel[:, :1] < 0, -rel, rel)
            s = np.linalg.norm(rel[:, 1:], axis=1)
            ang = 2.0 * np.arctan2(s, rel[:, 0])
            axis = np.where(s[:, None] > 1e-9, rel[:, 1:] / np.maximum(s[:, None], 1e-12), [1.0, 0.0, 0.0])
            scaled = quat.from_axis_angle(axis, ang * (1.0 + magnitude / 100.0))
            rot[start:end, j] = quat.mul(np.broadcast_to(base, (n, 4)), scaled)
        elif kind == "tremor":
            hz = rng.uniform(6.0, 10.0)
            ang = np.deg2rad(magnitude) * np.sin(2 * np.pi * hz * t / motion.fps)
            axis = np.broadcast_to(_random_axis(rng)[0], (n, 3))
            rot[start:end, j] = quat.mul(rot[start:end, j], quat.from_axis_angle(axis, ang))
        else:
            raise DataError(f"unknown family-B error kind {kind!r} (known: {', '.join(KINDS_B)})")


def inject_b(
    motion: Motion, seed: int, density: float = 0.125, min_angle: float = 5.0
) -> tuple[Motion, np.ndarray, list[InjectedError]]:
    """Family-B errors at ``density`` of the words of ``motion`` at its own rate (a 24-fps
    frame is ``fps / 24`` input frames): the corrupted motion, the (T, J) mask of cells
    moved more than ``min_angle`` degrees and the :class:`.error_injection.InjectedError` list."""
    r = max(1, int(round(motion.fps / 24.0)))
    ranges = {k: ((d0 * r, d1 * r), m) for k, ((d0, d1), m) in RANGES_B.items()}
    return inject_at_density(
        motion,
        density,
        KINDS_B,
        seed=seed,
        min_angle=min_angle,
        ranges=ranges,
        word_length=15 * r,
        word_step=5 * r,
        margin=4 * r,
        apply=apply_error_b,
        known=KINDS_B,
    )
