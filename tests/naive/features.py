"""Slow, obviously correct references for the Krüger feature sets (one frame at a time)."""

from __future__ import annotations

import math

import numpy as np


def root_frame_pose(frame_positions: dict[str, np.ndarray], joints) -> np.ndarray:
    """One frame: joints relative to the root, turned so the hip axis lies along +x."""
    root = frame_positions["root"]
    across = frame_positions["lhip"] - frame_positions["rhip"]
    fwd = np.cross(across, [0.0, 1.0, 0.0])
    a = math.atan2(fwd[0], fwd[2])  # heading; rotate by -a about +y
    c, s = math.cos(-a), math.sin(-a)
    rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.concatenate([rot @ (frame_positions[j] - root) for j in joints])


def end_effector_features(motion, joints, samples=1, window=0.3) -> np.ndarray:
    names = list(motion.skeleton.canonical)
    pos = motion.canonical_positions(names)
    poses = [root_frame_pose({n: pos[t, i] for i, n in enumerate(names)}, joints) for t in range(motion.n_frames)]
    out = []
    for t in range(motion.n_frames):
        row = []
        for s in range(samples):
            if samples == 1:
                at = float(t)
            else:
                span = window * motion.fps
                first = t - span / 2
                at = first + s * span / (samples - 1)
            at = min(max(at, 0.0), motion.n_frames - 1.0)
            lo = int(math.floor(at))
            hi = min(lo + 1, motion.n_frames - 1)
            w = at - lo
            row.append((1 - w) * poses[lo] + w * poses[hi])
        out.append(np.concatenate(row))
    return np.array(out)
