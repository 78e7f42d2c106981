"""A cleaning step's results in the form the page plays: MDM grids and cleaned takes."""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.schema import fixed_list_to_numpy

#: Cue shown for a flagged cell when the cleaner's table has no ``cue`` column.
DEFAULT_CUE = "MDM above threshold"


def apply_edits(motion: Any, edits: pa.Table, clip_id: int) -> Any:
    """The original take with the ``edits`` (``clip_id, frame, joint`` skeleton joint index,
    ``new_rotation`` (w, x, y, z)) of ``clip_id`` applied: the cleaned take."""
    sel = edits.filter(pc.equal(edits["clip_id"], clip_id))
    if not sel.num_rows:
        return motion
    rot = np.array(motion.rotations, copy=True)
    frame = sel["frame"].to_numpy().astype(np.int64)
    joint = sel["joint"].to_numpy().astype(np.int64)
    rot[frame, joint] = fixed_list_to_numpy(sel["new_rotation"], np.float64)
    return motion.with_arrays(rotations=rot)


def cleaned_positions(motion: Any, edits: pa.Table, clip_id: int) -> np.ndarray:
    """Canonical positions ``(T, 25, 3)`` in metres of the cleaned take."""
    return cast("np.ndarray", apply_edits(motion, edits, clip_id).canonical_positions(CANONICAL_JOINTS))


def mdm_grid(mdm: pa.Table, clip_id: int, n_frames: int, threshold: float) -> dict[str, Any] | None:
    """One clip's MDM as a dense grid for the heatmap, None if the clip has no MDM rows:
    ``values`` uint16 (T, m) (the value is ``values * scale``), ``scale``, ``cue`` uint8
    (T, m) (0 = not flagged, ``i`` = flagged by ``cues[i - 1]``: the ``cue`` column's
    label, or :data:`DEFAULT_CUE` for a flagged cell without one), ``joints`` (m row
    names), ``canonical`` (canonical joint index of each row, -1 if none), ``cues``,
    ``n_flagged`` (cells with a cue).
    """
    sel = mdm.filter(pc.equal(mdm["clip_id"], clip_id))
    if not sel.num_rows:
        return None
    names = sel["joint_name"].to_pylist()
    joints = list(dict.fromkeys(names))
    row = {n: i for i, n in enumerate(joints)}
    r = np.array([row[n] for n in names], np.int64)
    f = sel["frame"].to_numpy().astype(np.int64)
    ok = (f >= 0) & (f < n_frames)
    v = np.nan_to_num(sel["value"].to_numpy(zero_copy_only=False).astype(np.float64))
    # uint16 steps of max(1, largest value) / 65535: exact to 2e-5 on an MDM in [0, 1]
    scale = max(1.0, float(v.max(initial=0.0))) / 65535.0
    values = np.zeros((n_frames, len(joints)), np.uint16)
    values[f[ok], r[ok]] = np.clip(np.rint(v[ok] / scale), 0, 65535).astype(np.uint16)
    flagged = (
        sel["flagged"].to_numpy(zero_copy_only=False).astype(bool) if "flagged" in sel.column_names else v > threshold
    )
    cue = np.zeros(values.shape, np.uint8)
    # a cell's cue: the cue column's label where it names one, else the threshold if flagged
    raw = sel["cue"].to_pylist() if "cue" in sel.column_names else [None] * sel.num_rows
    labels = [str(c) if c not in (None, False, "", "False") else None for c in raw]
    labels = [DEFAULT_CUE if c == "True" or (c is None and fl) else c for c, fl in zip(labels, flagged, strict=True)]
    cues = sorted({c for c in labels if c is not None})
    code = {c: i + 1 for i, c in enumerate(cues)}
    codes = np.array([0 if c is None else code[c] for c in labels], np.uint8)
    cue[f[ok], r[ok]] = codes[ok]
    canonical = [CANONICAL_JOINTS.index(n) if n in CANONICAL_JOINTS else -1 for n in joints]
    return {
        "values": values,
        "scale": scale,
        "cue": cue,
        "joints": joints,
        "canonical": canonical,
        "cues": cues,
        "n_flagged": int((cue > 0).sum()),
    }
