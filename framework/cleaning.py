"""The cleaner contract: digression and edit tables, and the default cleaner step.

A cleaner implements :meth:`~mocapflow.framework.components.Cleaner.detect` (a digression
map, shape (T, J) in [0, 1]) and :meth:`~mocapflow.framework.components.Cleaner.repair`
(the cleaned motion and an :data:`~.schema.EDITS` table, :func:`edits_table`). The default
step :func:`run_cleaner` cleans every clip of its ``motions`` input against the optional
``context`` input through ``Cleaner.clean_clip`` (default :func:`clean_clip`) and writes
``data`` (:data:`~.schema.DIGRESSIONS`, :func:`digression_table`) and ``edits``. Its
summary (stored in the provenance) holds no timing and no path, so identical runs give
identical provenance.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa

from . import schema
from .errors import DataError

if TYPE_CHECKING:  # pragma: no cover
    from .components import Cleaner
    from .datasets import StepOutput
    from .motion import Motion


@dataclass
class CleanedClip:
    """One clip through a cleaner step.

    Attributes
    ----------
    digressions : pyarrow.Table
        :data:`~.schema.DIGRESSIONS` rows of the clip.
    edits : pyarrow.Table
        :data:`~.schema.EDITS` rows of the clip.
    cleaned : Motion or None
        The cleaned clip (None once it was written where it belongs, on a worker).
    summary : dict
        JSON-compatible, deterministic (no timing, no path): stored in the provenance.
    """

    digressions: pa.Table
    edits: pa.Table
    cleaned: Motion | None = None
    summary: dict[str, Any] = field(default_factory=dict)


def check_take(motion: Motion, what: str = "cleaning") -> None:
    """Raise :class:`DataError` unless ``motion`` is a Motion with finite rotations and root
    translation (a NaN would otherwise surface as a linear-algebra error deep in a cleaner)."""
    from .motion import Motion

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
    """:data:`~.schema.DIGRESSIONS` rows of one clip, frame-major.

    Parameters
    ----------
    value : ndarray of shape (T, J), in [0, 1]
        A digression map at the clip's frames (:meth:`.Cleaner.detect`).
    joints : ndarray of int, optional
        Skeleton joints to report (default: every joint).
    threshold : float
        ``flagged = value > threshold``.
    cue : ndarray of object, shape (T, len(joints)), optional
        What flagged each cell; kept only where flagged.
    """
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
        else np.where(flagged, np.asarray(cue).reshape(-1), None)
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
    cue: list | np.ndarray | None = None,
) -> pa.Table:
    """:data:`~.schema.EDITS` rows: one per changed (frame, joint), frame-major.

    ``changed`` (T, J) bool defaults to the cells whose rotation differs; ``cue`` gives one
    entry per changed cell (default null).
    """
    from .quaternions import geodesic_angle

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


def clean_clip(cleaner: Cleaner, motion: Motion, context: Any, clip_id: int) -> CleanedClip:
    """The default ``Cleaner.clean_clip``: :meth:`detect` for the map, :meth:`repair` for the edits."""
    value = cleaner.detect(motion, context)
    cleaned, edits = cleaner.repair(motion, context)
    digressions = digression_table(value, motion, clip_id)
    edits = with_clip_id(edits, clip_id)
    return CleanedClip(
        digressions,
        edits,
        cleaned,
        {
            "clip": motion.name,
            "flagged_cells": int(digressions["flagged"].to_numpy().sum()),
            "edited_cells": edits.num_rows,
        },
    )


def _clean_task(cleaner: Cleaner, context: Any, out_dir: Path, motion: Motion, clip_id: int) -> CleanedClip:
    """One clip of :func:`run_cleaner` (module-level: executors pickle it); the context
    motions are read once per worker process."""
    out = cleaner.clean_clip(motion, context.motions() if context is not None else None, clip_id, out_dir)
    out.cleaned = None  # files are written; the motion itself need not travel back
    return out


def run_cleaner(cleaner: Cleaner, inputs: Mapping[str, Any], ctx: Any) -> StepOutput:
    """The default cleaner step: every clip of ``motions`` against itself plus the optional
    ``context`` dataset. Tables ``data`` (digressions), ``edits``; files per clip; summary
    ``{"clips": [clip summaries]}``."""
    from .datasets import StepOutput
    from .clip_refs import DatasetRef

    # clips and context go to the workers by reference (each reads them from the workspace)
    context = DatasetRef.of(inputs["context"]) if inputs.get("context") is not None else None
    digressions, edits, summary = [], [], []
    for out in ctx.map_clips(partial(_clean_task, cleaner, context, ctx.out_dir), inputs["motions"], with_ids=True):
        digressions.append(out.digressions)
        edits.append(out.edits)
        summary.append(out.summary)
    data = pa.concat_tables(digressions) if digressions else None
    ed = pa.concat_tables(edits) if edits else None
    tables = {k: v for k, v in (("data", data), ("edits", ed)) if v is not None}
    return StepOutput(tables, {"clips": summary})


__all__ = ["CleanedClip", "check_take", "clean_clip", "digression_table", "edits_table", "run_cleaner", "with_clip_id"]
