"""``features.end_effectors``: Krüger et al. 2010's F_E^15, F_E^30, F_E^39 and their windowed F^{n×l}.

All positions are taken in the normalised root frame (:func:`~mocapflow.framework.normalize.to_root_frame`:
root moved to the origin, facing direction turned to +z, heights relative to the root).

Joint choice (canonical names, :mod:`mocapflow.framework.joints`):

* ``joints: 5`` (F_E^15): ``lwrist, rwrist, lankle, rankle, head``. The paper says "4
  end-effectors and head"; its Fig. 1 visualises "the wrist and ankle joints as well as head
  joints", so wrists and ankles it is (they are also present in every skeleton we read,
  while finger and toe joints are not).
* ``joints: 10`` (F_E^30): plus ``lelbow, relbow, lknee, rknee, chest``.
* ``joints: 13`` (F_E^39): plus ``lshoulder, rshoulder, lowerback``.

Windows (``samples: l > 1``): the frame features at ``l`` instants spread evenly over a
window of ``window`` seconds (paper: 0.3 s), concatenated oldest first, each sample
normalised in its own root frame (the paper extends "every frame-based feature set F^n to
one on a window of l frames F^{n×l}"), frame ``t`` in the middle (``t - w/2 .. t + w/2``).
Sample instants that fall between frames are interpolated linearly (at 30 Hz, 0.3 s
is 9 frame intervals, so the 3-sample window's ends sit at ±4.5 frames). At the clip edges
the instants are clamped to the first/last frame: a window never straddles two clips
(features are computed clip by clip) and never reads outside its clip.
"""

from __future__ import annotations

from typing import ClassVar, Literal, cast

import numpy as np
from pydantic import Field

from mocapflow.framework import FeatureSet
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion
from mocapflow.framework.normalize import to_root_frame

#: Canonical joints of F_E^15 / F_E^30 / F_E^39, in feature order.
JOINT_SETS: dict[int, tuple[str, ...]] = {
    5: ("lwrist", "rwrist", "lankle", "rankle", "head"),
}
JOINT_SETS[10] = JOINT_SETS[5] + ("lelbow", "relbow", "lknee", "rknee", "chest")
JOINT_SETS[13] = JOINT_SETS[10] + ("lshoulder", "rshoulder", "lowerback")

_FRAME_JOINTS = ("root", "lhip", "rhip")  # needed by the root-frame normalisation


def body_frame_positions(motion: Motion, joints: tuple[str, ...]) -> np.ndarray:
    """Canonical joint positions in the normalised root frame, shape (T, len(joints), 3), metres."""
    names = _FRAME_JOINTS + tuple(j for j in joints if j not in _FRAME_JOINTS)
    pos = motion.canonical_positions(names)
    missing = [n for n, i in zip(names, motion.skeleton.canonical_indices(names), strict=True) if i < 0]
    if missing:
        raise DataError(f"motion {motion.name!r} (skeleton {motion.skeleton.name!r}) lacks canonical joints {missing}")
    local = to_root_frame(pos, names)
    return local[:, [names.index(j) for j in joints]]


def window_offsets(samples: int, window: float, fps: float) -> np.ndarray:
    """Sample instants relative to the frame, in frames (float), oldest first, shape (samples,)."""
    if samples == 1:
        return np.zeros(1)
    span = window * fps
    return -0.5 * span + np.linspace(0.0, span, samples)


def sample_window(frames: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Frame features at fractional instants ``t + offsets``, clamped to the clip, concatenated.

    Parameters
    ----------
    frames : ndarray of shape (T, n)
    offsets : ndarray of shape (l,), frames

    Returns
    -------
    ndarray of shape (T, n * l)
    """
    t = frames.shape[0]
    if t == 0:
        return np.zeros((0, frames.shape[1] * len(offsets)), frames.dtype)
    at = np.clip(np.arange(t)[:, None] + offsets[None, :], 0.0, t - 1)  # (T, l)
    i0 = np.floor(at).astype(np.int64)
    i1 = np.minimum(i0 + 1, t - 1)
    w = (at - i0)[..., None]
    out = (1.0 - w) * frames[i0] + w * frames[i1]  # (T, l, n)
    return cast("np.ndarray", out.reshape(t, -1))


class EndEffectorFeatures(FeatureSet):
    """End-effector positions in the root frame, optionally over a short time window.

    ``joints`` 5/10/13 give F_E^15/30/39; ``samples`` 3 or 5 give F^{n×3}/F^{n×5} over
    ``window`` seconds (see the module docstring for clip edges). Output:
    float32 (T, 3 * joints * samples), metres, joint-major within a sample, samples oldest first.
    """

    name: ClassVar[str] = "end_effectors"
    inputs: ClassVar = {"motions": True}

    class Params(BaseParams):
        joints: Literal[5, 10, 13] = Field(5, description="5, 10 or 13 joints: F_E^15, F_E^30, F_E^39")
        samples: int = Field(1, ge=1, le=32, description="samples per window (1 = pose only; paper: 3 or 5)")
        window: float = Field(0.3, gt=0, le=10, description="window length in seconds (paper: 0.3)")

    params: Params

    @property
    def dim(self) -> int:
        return 3 * self.params.joints * self.params.samples

    @property
    def joint_names(self) -> tuple[str, ...]:
        return JOINT_SETS[self.params.joints]

    def transform_motion(self, motion: Motion) -> np.ndarray:
        """Features of one clip, shape (T, dim), float32 (see class docstring)."""
        p = self.params
        pose = body_frame_positions(motion, self.joint_names).reshape(motion.n_frames, -1)
        if p.samples > 1:
            pose = sample_window(pose, window_offsets(p.samples, p.window, motion.fps))
        return pose.astype(np.float32)
