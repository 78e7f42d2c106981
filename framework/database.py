"""Many clips as one frame-wise concatenated document (Müller 2005, §5)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from functools import cached_property

import numpy as np

from .errors import DataError
from .joints import CANONICAL_JOINTS
from .motion import Motion


class MotionDatabase:
    """Clips concatenated frame-wise with global frame ids; clip ``i`` has id ``clip_ids[i]``
    (default ``i``); ``offsets`` (n_clips + 1,) int64: each clip's first global frame."""

    def __init__(self, motions: Sequence[Motion], clip_ids: Sequence[int] | None = None) -> None:
        self.motions: list[Motion] = list(motions)
        ids = np.arange(len(self.motions)) if clip_ids is None else np.asarray(clip_ids, dtype=np.int64)
        if ids.shape != (len(self.motions),):
            raise DataError(f"{len(ids)} clip ids for {len(self.motions)} motions")
        self.clip_ids = ids.astype(np.int32)
        lengths = np.array([m.n_frames for m in self.motions], dtype=np.int64)
        self.offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)

    # --- sizes -----------------------------------------------------------------------
    @property
    def n_clips(self) -> int:
        return len(self.motions)

    @property
    def n_frames(self) -> int:
        return int(self.offsets[-1])

    def __len__(self) -> int:
        return self.n_clips

    def __iter__(self) -> Iterator[Motion]:
        return iter(self.motions)

    def __getitem__(self, i: int) -> Motion:
        return self.motions[i]

    @property
    def fps(self) -> float:
        """The common frame rate; raises if clips differ (resample on ingest)."""
        rates = {m.fps for m in self.motions}
        if len(rates) != 1:
            raise DataError(f"clips have different frame rates {sorted(rates)}; resample them on ingest (fps: ...)")
        return rates.pop()

    # --- frame ids -------------------------------------------------------------------
    @cached_property
    def frame_clip_index(self) -> np.ndarray:
        """Clip position (0..n_clips-1) of every global frame, shape (n_frames,)."""
        return np.repeat(np.arange(self.n_clips, dtype=np.int32), np.diff(self.offsets))

    @cached_property
    def frame_ids(self) -> tuple[np.ndarray, np.ndarray]:
        """``(clip_id, frame)`` columns for every global frame, int32 each."""
        pos = self.frame_clip_index
        frame = (np.arange(self.n_frames, dtype=np.int64) - self.offsets[pos]).astype(np.int32)
        return self.clip_ids[pos], frame

    def locate(self, global_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map global frame ids to ``(clip position, frame within clip)``."""
        g = np.asarray(global_ids, dtype=np.int64)
        pos = np.searchsorted(self.offsets, g, side="right") - 1
        return pos, g - self.offsets[pos]

    # --- arrays -------------------------------------------------------------------------
    def canonical_positions(self, joints: tuple[str, ...] | list[str] = CANONICAL_JOINTS) -> np.ndarray:
        """Canonical joint positions of all frames, shape (n_frames, len(joints), 3), metres."""
        if not self.motions:
            return np.zeros((0, len(joints), 3))
        return np.concatenate([m.canonical_positions(joints) for m in self.motions], axis=0)
