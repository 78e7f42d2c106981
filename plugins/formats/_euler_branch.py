"""Euler angles written in the source's branch, and continuous.

A rotation has many Euler triples: every angle plus any multiple of 360 degrees, and for
three distinct axes the "flipped" triple ``(a + 180, 180 - b, c + 180)``. Readers of Euler
files (AMC, BVH) keep rotations as quaternions; writers decompose them again, which gives
the principal triple (each angle in (-180, 180], the middle one in [-90, 90]). A source
whose root turns past 180 degrees (``rx`` going 539.73 -> 541.23) would come back as
179.73 -> -178.77: a 360 degree step in a curve that was continuous.

So a reader records, compactly, where its file's values leave the principal branch
(:func:`record`: per channel the whole turns ``round(value / 360)`` and per three-axis
joint whether the middle angle is beyond +-90, both as runs ``[[frame, value], ...]`` and
only where they are not zero: ``metadata["euler_branch"]``), and a writer of the same
channels puts each frame back into that branch (:func:`apply`) and then removes any step
over 180 degrees left between frames (a motion edited since it was read, a source without
branch information: the curve is unwrapped from its first frame). A clip cut from a take
(``Motion.slice``) finds its frames through ``metadata["source_start_frame"]``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

KEY = "euler_branch"


def _runs(values: np.ndarray) -> list[list[int]]:
    """``[[frame, value], ...]`` at the frames where an integer series changes (from 0)."""
    v = values.astype(np.int64)
    change = np.flatnonzero(np.diff(np.r_[0, v]) != 0)
    return [[int(f), int(v[f])] for f in change]


def _series(runs: Sequence[Sequence[int]], start: int, n: int) -> np.ndarray:
    """The integer series of ``runs`` over frames ``start .. start + n``."""
    out = np.zeros(n, dtype=np.int64)
    for f, val in runs:
        a = max(int(f) - start, 0)
        if a < n:
            out[a:] = int(val)
    return out


def record(
    channels: Mapping[str, np.ndarray], triples: Mapping[str, np.ndarray], degrees: bool = True
) -> dict[str, Any]:
    """Branch information of a file's angles: ``channels`` maps a channel key
    (``"joint.rx"``) to its values (T,), ``triples`` a three-axis joint to its middle
    angle (T,). Returns ``{"turns": {key: runs}, "flips": {joint: runs}}`` with only the
    channels and joints that leave the principal branch (empty for most files)."""
    full = 360.0 if degrees else 2 * np.pi
    turns = {}
    for key, v in channels.items():
        w = np.round(np.asarray(v) / full)
        if np.any(w != 0):
            turns[key] = _runs(w)
    flips = {}
    for joint, mid in triples.items():
        m = np.asarray(mid) / full * 360.0
        wrapped = (m + 180.0) % 360.0 - 180.0
        f = np.abs(wrapped) > 90.0
        if f.any():
            flips[joint] = _runs(f)
    return {"turns": turns, "flips": flips, "degrees": degrees}


def _info(meta: Mapping[str, Any], fps: float) -> tuple[dict[str, Any], int]:
    info = meta.get(KEY)
    src_fps = meta.get("source_fps")
    if not isinstance(info, dict) or (src_fps is not None and abs(float(src_fps) - fps) > 1e-9 * fps):
        return {}, 0  # no record, or a resampled clip: its frames are not the file's
    return info, int(meta.get("source_start_frame", 0))


def apply(
    angles: np.ndarray,
    joint: str,
    keys: Sequence[str],
    meta: Mapping[str, Any],
    fps: float,
    degrees: bool = True,
) -> np.ndarray:
    """Angles ``(T, k)`` of one joint (principal branch, channels ``keys``) moved into the
    branch the source recorded (:func:`record`), then made continuous along time."""
    ang = np.array(angles, dtype=float)
    if ang.size == 0:
        return ang
    full = 360.0 if degrees else 2 * np.pi
    half = full / 2
    info, start = _info(meta, fps)
    n = ang.shape[0]
    if ang.shape[1] == 3 and joint in info.get("flips", {}):
        flip = _series(info["flips"][joint], start, n).astype(bool)
        alt = ang[flip] + np.array([half, 0.0, half])
        alt[:, 1] = half - ang[flip, 1]
        ang[flip] = (alt + half) % full - half
    turns = info.get("turns", {})
    for c, key in enumerate(keys):
        if key in turns:
            ang[:, c] += full * _series(turns[key], start, n)
    if n > 1:
        # continuity: remove steps over half a turn between frames, then shift each curve by
        # the whole turns most of its frames need to sit where the record puts them (a value
        # at +-180 can decompose on either side: one frame must not decide the branch)
        base = ang.copy()
        step = np.diff(ang, axis=0)
        ang[1:] += np.cumsum(-full * np.round(step / full), axis=0)
        for c in range(ang.shape[1]):
            d = np.round((base[:, c] - ang[:, c]) / full).astype(np.int64)
            vals, counts = np.unique(d, return_counts=True)
            ang[:, c] += full * vals[np.argmax(counts)]
    return ang
