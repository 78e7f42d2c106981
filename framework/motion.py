"""Motion clips: arrays of joint rotations over time, and forward kinematics.

Quaternions are unit ``(w, x, y, z)``, scalar first. ``rotations[t, j]`` is joint ``j``'s
rotation relative to its parent (rest pose: identities); world rotation
``W_j = W_parent * rotations[:, j]``, world position ``p_j = p_parent + W_parent * offset_j``
in metres. Axes: right-handed, y up, rest pose facing +z. Frames are 0-based within a clip;
segments are half-open ``[start_frame, end_frame)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from .errors import DataError
from .joints import CANONICAL_JOINTS
from .skeleton import Skeleton


@dataclass(frozen=True, eq=False)
class Motion:
    """One clip: ``root_translation`` (T, 3) metres, local ``rotations`` (T, J, 4), ``fps``,
    JSON-serialisable ``metadata``, and ``local_translations`` (T, J, 3) metres for files
    that animate non-root translations (``None``: the skeleton offsets)."""

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

    def write(self, path: Any) -> None:
        """Deprecated (one release): ``mocapflow.write(motion, path)``, which this calls.

        Writes with the registered format for the extension of ``path``, atomically."""
        import importlib
        import warnings

        warnings.warn(
            "Motion.write is deprecated and goes in the next release: use mocapflow.write(motion, path)",
            DeprecationWarning,
            stacklevel=2,
        )
        # the facade, by name: the data model imports no layer above it (tests/repo/test_import_cycles.py)
        importlib.import_module("mocapflow").write(self, path)

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
    """World positions (T, J, 3) metres and rotations (T, J, 4), read-only, by the numba
    kernel (imported here: importing mocapflow never pays for numba)."""
    from ._fk_kernels import fk

    pos, glob = fk(skeleton.parents, skeleton.offsets, root_translation, rotations, local_translations)
    pos.setflags(write=False)
    glob.setflags(write=False)
    return pos, glob
