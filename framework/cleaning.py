"""What a cleaner produces: digression and edit tables, one clip's result. A clip's summary
(stored in the provenance) holds no timing and no path: identical runs, identical provenance."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa

from . import schema
from .errors import DataError
from .motion import Motion
from .quaternions import geodesic_angle


@dataclass
class CleanedClip:
    """One clip through a cleaner step: its :data:`~.schema.DIGRESSIONS` and
    :data:`~.schema.EDITS` rows, the cleaned clip (None once a worker wrote it) and a
    deterministic JSON summary."""

    digressions: pa.Table
    edits: pa.Table
    cleaned: Motion | None = None
    summary: dict[str, Any] = field(default_factory=dict)


def check_take(motion: Motion, what: str = "cleaning") -> None:
    """Raise :class:`DataError` unless ``motion`` is a Motion with finite rotations and root
    translation (a NaN would otherwise surface as a linear-algebra error deep inside)."""
    if not isinstance(motion, Motion):
        raise DataError(f"{what}: expected a Motion, got {type(motion).__name__}")
    for name, arr in (("rotations", motion.rotations), ("root_translation", motion.root_translation)):
        bad = ~np.isfinite(np.asarray(arr, np.float64).reshape(motion.n_frames, -1)).all(axis=1)
        if bad.any():
            raise DataError(
                f"{what}: motion {motion.name!r} has NaN or inf {name} at frame {int(np.argmax(bad))} "
                f"({int(bad.sum())} frames); fill or cut them first"
            )


def digression_table(
    value: np.ndarray,
    motion: Motion,
    clip_id: int = 0,
    *,
    joints: np.ndarray | None = None,
    threshold: float = 0.5,
    cue: np.ndarray | None = None,
) -> pa.Table:
    """:data:`~.schema.DIGRESSIONS` rows, frame-major, of a digression map ``value`` (T, J)
    for ``joints`` (default all); ``flagged = value > threshold``; ``cue`` (T, len(joints))
    says what flagged a cell (kept where flagged)."""
    v = np.asarray(value, dtype=np.float64)
    t = motion.n_frames
    if v.shape != (t, motion.n_joints):
        raise DataError(f"digression map must be (n_frames={t}, n_joints={motion.n_joints}), got {v.shape}")
    cols = np.arange(motion.n_joints) if joints is None else np.asarray(joints, np.int64)
    vals = v[:, cols]
    flagged = vals.reshape(-1) > threshold
    cues = (
        np.full(len(flagged), None, dtype=object)
        if cue is None
        else np.where(flagged, np.asarray(cue, dtype=object).reshape(-1), np.full(len(flagged), None, dtype=object))
    )
    names = np.array(motion.skeleton.names, dtype=object)[cols]
    return pa.table(
        {
            "clip_id": pa.array(np.full(t * len(cols), clip_id, np.int32)),
            "frame": pa.array(np.repeat(np.arange(t, dtype=np.int32), len(cols))),
            "joint": pa.array(np.tile(cols.astype(np.int32), t)),
            "joint_name": pa.array(np.tile(names, t).tolist(), pa.string()),
            "value": pa.array(vals.reshape(-1).astype(np.float32)),
            "flagged": pa.array(flagged),
            "cue": pa.array(cues.tolist(), pa.string()),
        },
        schema=schema.DIGRESSIONS,
    )


def edits_table(
    motion: Motion,
    cleaned: Motion,
    changed: np.ndarray | None = None,
    clip_id: int = 0,
    cue: list[str | None] | np.ndarray | None = None,
) -> pa.Table:
    """:data:`~.schema.EDITS` rows per ``changed`` (T, J) cell (default: rotation differs),
    frame-major; ``cue``: one entry per changed cell."""
    if cleaned.rotations.shape != motion.rotations.shape:
        raise DataError(f"cleaned motion has rotations {cleaned.rotations.shape}, the input {motion.rotations.shape}")
    if changed is None:
        changed = np.any(cleaned.rotations != motion.rotations, axis=-1)
    f, j = np.nonzero(changed)
    old, new = motion.rotations[f, j].reshape(-1, 4), cleaned.rotations[f, j].reshape(-1, 4)
    deg = np.rad2deg(geodesic_angle(old, new)) if len(f) else np.zeros(0)
    names = np.array(motion.skeleton.names, dtype=object)
    cues = [None] * len(f) if cue is None else list(cue)
    return pa.table(
        {
            "clip_id": pa.array(np.full(len(f), clip_id, np.int32)),
            "frame": pa.array(f.astype(np.int32)),
            "joint": pa.array(j.astype(np.int32)),
            "joint_name": pa.array(names[j].tolist() if len(j) else [], pa.string()),
            "old_rotation": schema.fixed_list(np.asarray(old, np.float64)),
            "new_rotation": schema.fixed_list(np.asarray(new, np.float64)),
            "edit_deg": pa.array(np.asarray(deg, np.float32)),
            "cue": pa.array(cues, pa.string()),
        },
        schema=schema.EDITS,
    )


def with_clip_id(table: pa.Table, clip_id: int) -> pa.Table:
    """``table`` with its ``clip_id`` column (the first) set to ``clip_id``."""
    return table.set_column(0, "clip_id", pa.array(np.full(table.num_rows, clip_id, np.int32)))


def clip_result(motion: Motion, value: np.ndarray, cleaned: Motion, edits: pa.Table, clip_id: int) -> CleanedClip:
    """A :class:`CleanedClip` from a digression map and a repair (the default ``detect_and_repair``)."""
    digressions = digression_table(value, motion, clip_id)
    edits = with_clip_id(edits, clip_id)
    summary = {
        "clip": motion.name,
        "flagged_cells": int(digressions["flagged"].to_numpy().sum()),
        "edited_cells": edits.num_rows,
    }
    return CleanedClip(digressions, edits, cleaned, summary)
