"""A synthetic humanoid for tests and conformance checks: a 25-joint T-pose skeleton named
with the canonical joints and smooth random motions of it. Public through
:mod:`mocapflow.framework.testing`."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
from pydantic import ValidationError

from . import quaternions as quat
from .components import Component
from .joints import CANONICAL_JOINTS
from .motion import Motion
from .skeleton import Skeleton

C = TypeVar("C", bound=Component)

# joint, parent, offset (metres, y up, facing +z, left = +x)
_BONES = [
    ("root", None, (0, 0, 0)),
    ("lhip", "root", (0.1, -0.05, 0)),
    ("lknee", "lhip", (0, -0.42, 0)),
    ("lankle", "lknee", (0, -0.42, 0)),
    ("ltoes", "lankle", (0, -0.05, 0.12)),
    ("rhip", "root", (-0.1, -0.05, 0)),
    ("rknee", "rhip", (0, -0.42, 0)),
    ("rankle", "rknee", (0, -0.42, 0)),
    ("rtoes", "rankle", (0, -0.05, 0.12)),
    ("lowerback", "root", (0, 0.1, 0)),
    ("upperback", "lowerback", (0, 0.12, 0)),
    ("chest", "upperback", (0, 0.12, 0)),
    ("neck", "chest", (0, 0.12, 0)),
    ("head", "neck", (0, 0.08, 0)),
    ("headtop", "head", (0, 0.18, 0)),
    ("lclavicle", "chest", (0.03, 0.08, 0)),
    ("lshoulder", "lclavicle", (0.15, 0, 0)),
    ("lelbow", "lshoulder", (0.28, 0, 0)),
    ("lwrist", "lelbow", (0.25, 0, 0)),
    ("lfingers", "lwrist", (0.08, 0, 0)),
    ("rclavicle", "chest", (-0.03, 0.08, 0)),
    ("rshoulder", "rclavicle", (-0.15, 0, 0)),
    ("relbow", "rshoulder", (-0.28, 0, 0)),
    ("rwrist", "relbow", (-0.25, 0, 0)),
    ("rfingers", "rwrist", (-0.08, 0, 0)),
]


def synthetic_skeleton() -> Skeleton:
    """A 25-joint T-pose skeleton whose joint names are the canonical names."""
    names = [b[0] for b in _BONES]
    parents = [-1 if b[1] is None else names.index(b[1]) for b in _BONES]
    offsets = np.array([b[2] for b in _BONES], dtype=float)
    canonical = {n: i for i, n in enumerate(names) if n in CANONICAL_JOINTS}
    return Skeleton(tuple(names), np.array(parents), offsets, canonical=canonical, name="synthetic")


def synthetic_motion(n_frames: int = 60, fps: float = 30.0, seed: int = 0, amplitude_deg: float = 30.0) -> Motion:
    """Smooth random joint rotations (sums of sines) and a walking root."""
    rng = np.random.default_rng(seed)
    sk = synthetic_skeleton()
    t = np.arange(n_frames) / fps
    freq = rng.uniform(0.3, 2.0, size=(sk.n_joints, 3))
    phase = rng.uniform(0, 2 * np.pi, size=(sk.n_joints, 3))
    angles = amplitude_deg * np.sin(2 * np.pi * freq[None] * t[:, None, None] + phase[None])
    rot = quat.from_euler(angles, "zxy")
    root = np.stack([0.3 * t, 0.95 + 0.02 * np.sin(4 * t), 1.2 * t], axis=1)
    return Motion(sk, root, rot, fps, name=f"synthetic{seed}", metadata={"format": "synthetic"})


# --- checks -----------------------------------------------------------------------------


def _instance(cls: type[C]) -> C | None:
    """An instance with default or ``test_params``; None when required params are unknown."""
    params = cls.test_params
    try:
        return cls(cls.Params(**(params or {})))
    except ValidationError:
        return None
