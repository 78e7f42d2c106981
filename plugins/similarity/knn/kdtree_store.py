"""What :class:`.kdtree.KDTreeIndex` saves and loads: the arrays of the layouts, the checks of
``index.json`` and the rows of an index that reads them from its features dataset."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework.errors import DataError, PipelineError

#: The arrays of a built tree (attribute names; files drop the trailing underscore).
ARRAYS = tuple(
    f"{a}_"
    for a in ["data", "perm", "groups", "frames", "sqnorms", "mean", "start", "end", "left", "right", "sdim", "sval"]
)
#: What an index saved with ``rows_from`` keeps: the tree, not the rows (read from the features).
TREE_ARRAYS = tuple(a for a in ARRAYS if a not in ("data_", "groups_", "frames_", "sqnorms_"))
#: 1: every array and rows_*.npy; 2: also ``rows_from`` (the tree only, rows read from the features dataset).
INDEX_LAYOUT = 2


def sqnorms(data: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Squared norms of the rows centred on ``mean``, in blocks (no transient centred copy)."""
    out = np.empty(data.shape[0], np.float32)
    for a in range(0, data.shape[0], 65536):
        c = data[a : a + 65536] - mean
        out[a : a + 65536] = np.einsum("ij,ij->i", c, c)
    return out


def read_meta(d: Path, name: str) -> tuple[dict[str, Any], tuple[str, ...]]:
    """``index.json`` of a saved index and the arrays its layout holds, checked: present, a
    layout this version reads, every array file there."""
    if not (d / "index.json").is_file():
        raise DataError(f"{d} holds no saved {name} index (no index.json)")
    meta: dict[str, Any] = json.loads((d / "index.json").read_text())
    layout = int(meta.get("layout", 1))
    if layout > INDEX_LAYOUT:
        raise DataError(
            f"{d}: index layout {layout} was written by a newer mocapflow (this one reads up to {INDEX_LAYOUT}): "
            "upgrade mocapflow, or rebuild the index with `mocapflow run PIPELINE --force`"
        )
    arrays = TREE_ARRAYS if meta.get("rows_from") else ARRAYS
    missing = [f"{a.rstrip('_')}.npy" for a in arrays if not (d / f"{a.rstrip('_')}.npy").is_file()]
    if missing:
        raise DataError(
            f"{d}: index incomplete or built by an older version (missing {', '.join(missing)}): "
            "rebuild it with `mocapflow run PIPELINE --force`"
        )
    return meta, arrays


def rows_from_dataset(
    d: Path, ref: dict[str, Any], perm: np.ndarray
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The tree's permutation (int64) and the rows ``(features, clip_id, frame)`` in dataset
    order of an index saved in ``d`` with ``rows_from`` (``ref``): read from that features
    dataset (the step ``ref["step"]`` of the index's workspace), checked against its fingerprint
    and row count. The features are writable (the kernels' one signature)."""
    from mocapflow.framework.datasets import Dataset

    src = d.parent.parent / str(ref["step"])
    try:
        ds = Dataset(src)
        fp = ds.fingerprint
    except (OSError, ValueError, KeyError, PipelineError):  # a missing or unreadable dataset: one message
        fp = None
    if fp != ref.get("fingerprint"):
        state = "is missing" if fp is None else "has changed since"
        raise DataError(
            f"{d}: the index reads its rows from the features dataset {src}, which {state} the index was "
            "built: rebuild the index with `mocapflow run PIPELINE` (or --force)"
        )
    feats = ds.features()
    perm = np.asarray(perm, np.int64)
    if len(perm) != feats.x.shape[0]:
        raise DataError(f"{d}: {len(perm)} indexed rows, features dataset {src} has {feats.x.shape[0]}")
    x = feats.x if feats.x.flags.writeable else feats.x.copy()
    return perm, (x, feats.clip_id, feats.frame)
