"""Motion textures, joint groups, the pose distance (eq. 1) and motion-words (Aristidou 2018).

* texture: local rotations of ``m`` joints at 24 fps, (T, m, 4) unit quaternions (w, x, y,
  z), sign-continuous per joint, time first; root heading removed
  (:func:`~mocapflow.framework.normalize.align_facing`) and root translation dropped, so
  poses compare wherever and whichever way the performer stands.
* joint group: a named, possibly overlapping subset of the texture joints.
* eq. 1: ``dist(i, j) = sum_k ||log(q_jk^-1 q_ik)||^2`` over the group's joints without the
  ``drop`` largest terms (robust to a few wrong joints); a term is ``arccos(|w|)^2``.
* source words: N frames every step; target words: up to M frames at every context frame,
  never straddling two clips, at least N frames left in the clip.
* ``|T - T̄|``: the geodesic angle to the chordal L2 mean of the KNN quaternions of a cell
  (principal eigenvector of ``sum q q^T``, Markley et al. 2007), sign invariant.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.database import MotionDatabase
from mocapflow.framework.errors import ConfigError, DataError
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.motion import Motion
from mocapflow.framework.normalize import align_facing, resample

#: The paper's "24 most informative joints": the canonical vocabulary without the head top
#: (an end site that carries no rotation).
DEFAULT_JOINTS: tuple[str, ...] = tuple(j for j in CANONICAL_JOINTS if j != "headtop")

_SPINE = ("lowerback", "upperback", "chest", "neck", "head")
_LEFT_ARM = ("lclavicle", "lshoulder", "lelbow", "lwrist", "lfingers")
_RIGHT_ARM = ("rclavicle", "rshoulder", "relbow", "rwrist", "rfingers")
_LEFT_LEG = ("lhip", "lknee", "lankle", "ltoes")
_RIGHT_LEG = ("rhip", "rknee", "rankle", "rtoes")

#: Default groups as (name, canonical joints, number of largest joint distances dropped).
#: Empty joints = every texture joint. The halves share the spine (groups may overlap).
DEFAULT_GROUPS: tuple[tuple[str, tuple[str, ...], int], ...] = (
    ("whole", (), 3),
    ("upper", _SPINE + _LEFT_ARM + _RIGHT_ARM, 1),
    ("lower", ("root",) + _LEFT_LEG + _RIGHT_LEG, 1),
    ("left", ("root",) + _SPINE + _LEFT_ARM + _LEFT_LEG, 1),
    ("right", ("root",) + _SPINE + _RIGHT_ARM + _RIGHT_LEG, 1),
)


@dataclass(frozen=True)
class Texture:
    """A clip's motion texture: ``q`` (T, m, 4) at ``fps``, sign-continuous; ``joints`` the
    canonical names of its columns; ``joint_index`` (m,) their skeleton indices; ``motion``
    the resampled, facing-aligned motion it was taken from."""

    q: np.ndarray
    joints: tuple[str, ...]
    joint_index: np.ndarray
    fps: float
    motion: Motion

    @property
    def n_frames(self) -> int:
        return int(self.q.shape[0])


@dataclass(frozen=True)
class JointGroups:
    """Joint groups resolved against a texture's joints: ``names`` (G,), ``mask`` (G, m) bool,
    ``drop`` (G,) largest joint terms eq. 1 leaves out."""

    names: tuple[str, ...]
    mask: np.ndarray
    drop: np.ndarray

    @property
    def n_groups(self) -> int:
        return len(self.names)


def motion_texture(motion: Motion, joints: Sequence[str] = DEFAULT_JOINTS, fps: float = 24.0) -> Texture:
    """Resample ``motion`` to ``fps``, remove heading and root translation, take the texture
    of ``joints`` (canonical names the skeleton must all map)."""
    missing = [j for j in joints if j not in motion.skeleton.canonical]
    if missing:
        raise DataError(f"motion {motion.name!r}: skeleton lacks texture joints {missing}")
    m = resample(motion, fps)
    if {"lhip", "rhip"} <= set(m.skeleton.canonical):
        m = align_facing(m)
    idx = np.array([m.skeleton.canonical[j] for j in joints], dtype=np.int64)
    q = quat.make_continuous(m.rotations[:, idx], axis=0)
    return Texture(np.ascontiguousarray(q), tuple(joints), idx, float(fps), m)


def resolve_groups(texture_joints: Sequence[str], groups: Sequence[tuple[str, Sequence[str], int]]) -> JointGroups:
    """Resolve (name, canonical joints, drop) groups to masks over ``texture_joints``.

    Joints of a group that are not in the texture are ignored (a skeleton without
    ``upperback`` still has an upper body); a group left with no joint is an error.
    """
    tj = list(texture_joints)
    names, masks, drops = [], [], []
    for name, members, drop in groups:
        mask = np.ones(len(tj), bool) if not members else np.isin(tj, list(members))
        if not mask.any():
            raise ConfigError(f"joint group {name!r} has none of the texture joints {tj}")
        names.append(name)
        masks.append(mask)
        # never drop every joint of a small group
        drops.append(min(int(drop), int(mask.sum()) - 1))
    return JointGroups(tuple(names), np.array(masks, bool).reshape(len(names), len(tj)), np.array(drops, np.int64))


def joint_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared quaternion log-norm distances ``||log(b^-1 a)||^2`` (..., m) per joint of
    ``a``, ``b`` (..., m, 4), radians squared (half-angle convention)."""
    d = np.abs(np.sum(a * b, axis=-1))
    return cast("np.ndarray", np.arccos(np.clip(d, 0.0, 1.0)) ** 2)


def trimmed_sum(terms: np.ndarray, mask: np.ndarray, drop: int) -> np.ndarray:
    """Sum of ``terms[..., mask]`` without its ``drop`` largest entries (eq. 1)."""
    t = np.sort(terms[..., mask], axis=-1)
    keep = t.shape[-1] - drop
    return cast("np.ndarray", t[..., :keep].sum(axis=-1))


def pose_distance(a: np.ndarray, b: np.ndarray, mask: np.ndarray, drop: int) -> np.ndarray:
    """Eq. 1 between poses ``a`` and ``b`` of shape (..., m, 4) for one joint group."""
    return trimmed_sum(joint_distances(a, b), np.asarray(mask, bool), int(drop))


def source_word_starts(n_frames: int, length: int, step: int) -> np.ndarray:
    """Start frames of the source words: every ``step`` frames, plus a last word flush with
    the clip end so every frame is covered. Empty when the clip is shorter than a word."""
    if n_frames < length:
        return np.zeros(0, np.int64)
    starts = np.arange(0, n_frames - length + 1, step, dtype=np.int64)
    if starts[-1] != n_frames - length:
        starts = np.append(starts, n_frames - length)
    return starts


def target_word_layout(
    clip_lengths: Sequence[int] | np.ndarray, source_length: int, target_length: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of a concatenated context: the target-word length ``min(target_length,
    frames left in the clip)`` (0 where fewer than ``source_length`` are left) and the
    frame's clip position, both int64."""
    lengths, clips = [], []
    for c, n in enumerate(clip_lengths):
        left = n - np.arange(n, dtype=np.int64)
        ln = np.minimum(left, target_length)
        ln[left < source_length] = 0
        lengths.append(ln)
        clips.append(np.full(n, c, np.int64))
    if not lengths:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(lengths), np.concatenate(clips)


def context_motions(motion: Motion, context: Any, include_self: bool = True) -> list[Motion]:
    """The clips to search for ``motion``: itself (first) and the context without duplicates
    of it (same object, or same name and length)."""
    if context is None:
        others: list[Motion] = []
    elif isinstance(context, Motion):
        others = [context]
    elif isinstance(context, MotionDatabase):
        others = list(context.motions)
    elif isinstance(context, Sequence) and not isinstance(context, str):
        others = list(context)
        if not all(isinstance(c, Motion) for c in others):
            raise DataError("a cleaning context list must hold Motions only")
    else:
        raise DataError(
            f"cleaning context must be a Motion, a list of Motions or a MotionDatabase, got {type(context).__name__}"
        )
    others = [c for c in others if c is not motion and not (c.name == motion.name and c.n_frames == motion.n_frames)]
    if not include_self and not others:
        raise DataError(f"motion {motion.name!r}: include_self is off and the context is empty")
    return ([motion] if include_self else []) + others
