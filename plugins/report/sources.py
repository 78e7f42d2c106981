"""Where the report's motions come from: canonical positions of motions datasets (FK once per
shown clip), marker takes, and the motions dataset behind a step's input slot."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from mocapflow.framework.datasets import Dataset
from mocapflow.framework.joints import CANONICAL_JOINTS


class _Motions:
    """Canonical positions of clips of motions datasets, loaded once per dataset."""

    def __init__(self, datasets: Mapping[str, Dataset]) -> None:
        self.datasets = datasets
        self._pos: dict[str, dict[int, Any]] = {}  # a Motion until its FK is asked for, then (T, 25, 3)
        self._names: dict[str, dict[int, str]] = {}
        self._fps: dict[str, dict[int, float]] = {}

    def names(self, step: str) -> dict[int, str]:
        if step not in self._names:
            t = self.datasets[step].table("clips", columns=["clip_id", "name", "fps"])
            self._names[step] = dict(zip(t["clip_id"].to_pylist(), t["name"].to_pylist(), strict=True))
            self._fps[step] = dict(zip(t["clip_id"].to_pylist(), t["fps"].to_pylist(), strict=True))
        return self._names[step]

    def fps(self, step: str, clip_id: int) -> float:
        """Frame rate of a clip, frames per second."""
        self.names(step)
        return float(self._fps[step].get(int(clip_id)) or 30.0)

    def positions(self, step: str, clip_id: int) -> np.ndarray:
        """Canonical joint positions (T, 25, 3) of a clip, metres: forward kinematics of the
        stored rotations (motions datasets store no positions; FK once)."""
        if step not in self._pos:
            db = self.datasets[step].motions()
            self._pos[step] = {int(c): m for c, m in zip(db.clip_ids, db.motions, strict=True)}
        got = self._pos[step][int(clip_id)]
        if not isinstance(got, np.ndarray):  # FK only of the clips the report shows
            got = self._pos[step][int(clip_id)] = got.canonical_positions(CANONICAL_JOINTS).astype(np.float32)
        return cast("np.ndarray", got)


#: marker takes a markers view lists (the first, by path)
MARKER_CLIPS = 200


def is_markers(ds: Dataset) -> bool:
    """A markers dataset: ``clips`` with ``n_markers`` and ``data`` with ``positions``."""
    return (
        ds.has_table("clips")
        and ds.has_table("data")
        and "n_markers" in columns_of(ds, "clips")
        and "positions" in columns_of(ds, "data")
    )


def marker_positions(ds: Dataset) -> dict[int, tuple[dict[str, Any], np.ndarray]]:
    """clip id -> (its ``clips`` row, positions (T, M, 3) metres, y up, NaN in gaps) of a
    markers dataset (:func:`~mocapflow.framework.markers.to_y_up` of the file's axes)."""
    from mocapflow.framework.markers import Markers, to_y_up

    clips = ds.table("clips").to_pylist()
    data = ds.table("data", columns=["clip_id", "positions"])
    ids = data.column("clip_id").to_numpy()
    flat = data.column("positions").combine_chunks()
    values = flat.values.to_numpy(zero_copy_only=False).astype(np.float32)
    offsets = flat.offsets.to_numpy()
    out = {}
    for c in clips:
        rows = np.flatnonzero(ids == c["clip_id"])
        m = int(c["n_markers"])
        if not len(rows) or not m:
            continue
        a, b = offsets[rows[0]], offsets[rows[-1] + 1]  # a clip's rows are contiguous
        pos = values[a:b].reshape(len(rows), m, 3)
        mk = Markers(tuple(c["labels"] or ()), pos, float(c["fps"]), c["name"], {"up_axis": c["up_axis"] or "+y"})
        out[int(c["clip_id"])] = (c, to_y_up(mk).positions.astype(np.float32))
    return out


def motions_input(step: str, datasets: Mapping[str, Dataset]) -> str | None:
    """Step id of the nearest motions dataset (one with ``clips``) at or upstream of ``step``."""
    seen, todo = set(), [step]
    while todo:
        cur = todo.pop(0)
        if cur in seen or cur not in datasets:
            continue
        seen.add(cur)
        d = datasets[cur]
        if d.has_table("clips"):
            return cur
        ins = d.manifest.get("inputs", {})
        todo += [ins[name]["step"] for name in sorted(ins)]
    return None


def slot_motions(ds: Dataset, datasets: Mapping[str, Dataset], slots: tuple[str, ...]) -> str | None:
    """The motions dataset behind the first of ``slots`` that ``ds`` has as an input."""
    ins = ds.manifest.get("inputs", {})
    for slot in slots:
        if slot in ins:
            found = motions_input(ins[slot]["step"], datasets)
            if found is not None:
                return found
    return None


#: Input slots naming the searched database, then the queries, in order of preference.
HIT_SLOTS = ("database", "index", "motions", "query")
QUERY_SLOTS = ("query", "motions", "database", "index")


def columns_of(ds: Dataset, table: str) -> list[str]:
    """Column names of one of a dataset's tables, from its Parquet footer (no data read)."""
    import pyarrow.parquet as pq

    return cast("list[str]", pq.ParquetFile(ds.path / f"{table}.parquet").schema_arrow.names)
