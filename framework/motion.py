"""Motion clips: arrays of joint rotations over time, and forward kinematics.

Glossary
--------
quaternion
    Unit quaternion stored as ``(w, x, y, z)``, scalar first (:mod:`.quaternions`).
local rotation
    ``rotations[t, j]`` rotates joint ``j``'s frame relative to its parent's frame; the
    rest pose is all identities. World rotation ``W_j = W_parent(j) * rotations[:, j]``.
position
    ``positions[t, j]`` is the world position of joint ``j`` in **metres**, computed as
    ``p_j = p_parent + W_parent * offset_j`` (``offset_j`` from the skeleton, or from
    ``local_translations`` for files with per-joint translation channels).
axes
    Right-handed, **y up**. The facing direction of the rest pose is +z.
frame rate, fps
    Frames per second of a clip (CMU and HDM05: 120 Hz native). Features default to 30 Hz.
frame
    0-based index of a sample within its clip. Global frame ids of a
    :class:`~mocapflow.framework.database.MotionDatabase` count through all clips.
segment
    A half-open frame range ``[start_frame, end_frame)`` of one clip (end exclusive).
window
    A fixed span of time (seconds) sampled at ``l`` frames, used by windowed features.
word (motion-word)
    A short fixed-length window of consecutive frames treated as one unit (Aristidou 2018).
canonical joint
    A joint of the shared vocabulary in :mod:`.joints`, mapped from each source skeleton.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from . import quaternions as quat
from .errors import DataError
from .joints import CANONICAL_JOINTS
from .skeleton import Skeleton


@dataclass(frozen=True, eq=False)
class Motion:
    """One clip.

    Parameters
    ----------
    skeleton : Skeleton
    root_translation : ndarray of shape (T, 3), metres
        World position of the root joint per frame.
    rotations : ndarray of shape (T, J, 4)
        Local joint rotations, unit quaternions (w, x, y, z).
    fps : float
        Frames per second.
    name : str
        Clip name (usually the file stem).
    metadata : dict
        Source path, format, subject and anything else worth keeping (JSON-serialisable).
    local_translations : ndarray of shape (T, J, 3) or None, metres
        Per-frame joint offsets for files that animate translations of non-root joints
        (BVH position channels on every joint); ``None`` uses the skeleton offsets.
    """

    skeleton: Skeleton
    root_translation: np.ndarray
    rotations: np.ndarray
    fps: float
    name: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)
    local_translations: np.ndarray | None = None

    def __post_init__(self) -> None:
        rot = np.asarray(self.rotations, dtype=np.float64)
        root = np.asarray(self.root_translation, dtype=np.float64)
        t, j = rot.shape[:2] if rot.ndim == 3 else (-1, -1)
        if rot.ndim != 3 or rot.shape[2] != 4 or j != self.skeleton.n_joints:
            raise DataError(
                f"motion {self.name!r}: rotations must be (T, {self.skeleton.n_joints}, 4), got {rot.shape}"
            )
        if root.shape != (t, 3):
            raise DataError(f"motion {self.name!r}: root_translation must be ({t}, 3), got {root.shape}")
        if not self.fps > 0:
            raise DataError(f"motion {self.name!r}: fps must be positive, got {self.fps}")
        object.__setattr__(self, "rotations", rot)
        object.__setattr__(self, "root_translation", root)
        object.__setattr__(self, "fps", float(self.fps))
        if self.local_translations is not None:
            lt = np.asarray(self.local_translations, dtype=np.float64)
            if lt.shape != (t, j, 3):
                raise DataError(f"motion {self.name!r}: local_translations must be ({t}, {j}, 3), got {lt.shape}")
            object.__setattr__(self, "local_translations", lt)

    # --- shape ----------------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def n_joints(self) -> int:
        return self.skeleton.n_joints

    @property
    def duration(self) -> float:
        """Length in seconds (``n_frames / fps``)."""
        return self.n_frames / self.fps

    def __len__(self) -> int:
        return self.n_frames

    # --- kinematics -------------------------------------------------------------------
    @cached_property
    def _fk(self) -> tuple[np.ndarray, np.ndarray]:
        return forward_kinematics(self.skeleton, self.root_translation, self.rotations, self.local_translations)

    @property
    def positions(self) -> np.ndarray:
        """Joint world positions, ndarray of shape (T, J, 3), metres (cached, read-only)."""
        return self._fk[0]

    @property
    def global_rotations(self) -> np.ndarray:
        """Joint world rotations, ndarray of shape (T, J, 4) (cached, read-only)."""
        return self._fk[1]

    def canonical_positions(self, joints: tuple[str, ...] | list[str] = CANONICAL_JOINTS) -> np.ndarray:
        """Positions of canonical joints, shape (T, len(joints), 3), metres; NaN where absent."""
        idx = self.skeleton.canonical_indices(joints)
        out = np.full((self.n_frames, len(idx), 3), np.nan)
        ok = idx >= 0
        out[:, ok] = self.positions[:, idx[ok]]
        return out

    # --- editing ------------------------------------------------------------------------
    def slice(self, start: int, stop: int) -> Motion:
        """Frames ``[start, stop)`` as a new clip (metadata records the offset)."""
        meta = dict(self.metadata, source_start_frame=int(self.metadata.get("source_start_frame", 0)) + int(start))
        lt = None if self.local_translations is None else self.local_translations[start:stop]
        return replace(
            self,
            root_translation=self.root_translation[start:stop],
            rotations=self.rotations[start:stop],
            local_translations=lt,
            metadata=meta,
        )

    def with_arrays(self, **changes: Any) -> Motion:
        """Copy with some fields replaced (``rotations=...``, ``fps=...``)."""
        return replace(self, **changes)


def forward_kinematics(
    skeleton: Skeleton,
    root_translation: np.ndarray,
    rotations: np.ndarray,
    local_translations: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward kinematics in a compiled kernel.

    Joints are topologically ordered, so one pass over frames and joints suffices; the
    kernel (``_fk_kernels.py``) is checked against a per-frame matrix reference
    (``tests/naive/kinematics.py``) and against :func:`forward_kinematics_numpy`.

    Parameters
    ----------
    skeleton : Skeleton
    root_translation : ndarray of shape (T, 3), metres
    rotations : ndarray of shape (T, J, 4)
        Local rotations.
    local_translations : ndarray of shape (T, J, 3) or None

    Returns
    -------
    positions : ndarray of shape (T, J, 3), metres
    global_rotations : ndarray of shape (T, J, 4)
    """
    # compiled kernel (numba, cached on disk); imported here so that importing mocapflow
    # (and CLI start-up) never pays for numba
    from ._fk_kernels import fk

    pos, glob = fk(skeleton.parents, skeleton.offsets, root_translation, rotations, local_translations)
    pos.setflags(write=False)
    glob.setflags(write=False)
    return pos, glob


def forward_kinematics_numpy(
    skeleton: Skeleton,
    root_translation: np.ndarray,
    rotations: np.ndarray,
    local_translations: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The same as :func:`forward_kinematics` with one batched numpy operation per joint over
    all frames (no numba); kept as a readable second implementation for tests and benchmarks."""
    t, j = rotations.shape[:2]
    pos = np.empty((t, j, 3))
    glob = np.empty((t, j, 4))
    pos[:, 0] = root_translation
    glob[:, 0] = rotations[:, 0]
    for k in range(1, j):
        p = skeleton.parents[k]
        off = skeleton.offsets[k] if local_translations is None else local_translations[:, k]
        pos[:, k] = pos[:, p] + quat.rotate(glob[:, p], np.broadcast_to(off, (t, 3)))
        glob[:, k] = quat.mul(glob[:, p], rotations[:, k])
    return pos, glob
