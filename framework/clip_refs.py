"""Work by reference: clips read by the workers themselves.

:func:`~mocapflow.framework.executors.map_clips` sends :class:`ClipSlice` items (a motions
dataset's path, fingerprint and a clip range) instead of pickled motions; each worker reads
those clips from the workspace's Parquet file itself, only the row groups it needs, and keeps
what every task of a step needs in a small per-process cache (:func:`cached`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from functools import partial
from itertools import pairwise
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from .database import MotionDatabase
    from .datasets import Dataset


T = TypeVar("T")
_CACHE: OrderedDict[tuple[Hashable, ...], Any] = OrderedDict()
_CACHE_ENTRIES = 64


#: Decoded row groups kept per process, of all tables (a slice rarely spans more than two of
#: a table; a row group of motions is MBs, so the general 64 entries could hold gigabytes).
_GROUP_ENTRIES = 8


def cached(key: tuple[Hashable, ...], load: Callable[[], T], entries: int = _CACHE_ENTRIES) -> T:
    """``load()`` once per process for ``key`` (least recently used entries are dropped).

    Workers keep what every task of a step needs (a dataset's small tables, decoded row
    groups, a loaded index shard) instead of reading it once per task. ``entries``: at most
    this many entries that share ``key[0]`` (its kind) are kept.
    """
    if key in _CACHE:
        _CACHE.move_to_end(key)
        found: T = _CACHE[key]
        return found
    value = load()
    _CACHE[key] = value
    same = [k for k in _CACHE if k[:1] == key[:1]]
    for k in same[: max(0, len(same) - entries)]:
        del _CACHE[k]
    while len(_CACHE) > _CACHE_ENTRIES:
        _CACHE.popitem(last=False)
    return value


def clear_cache() -> None:
    """Forget everything :func:`cached` holds in this process."""
    _CACHE.clear()


@dataclass(frozen=True)
class DatasetRef:
    """A finished dataset by path and fingerprint: what a task carries instead of its data."""

    path: str
    fingerprint: str

    @classmethod
    def of(cls, dataset: Dataset) -> DatasetRef:
        return cls(str(dataset.path), dataset.fingerprint)

    def dataset(self) -> Dataset:
        from .datasets import Dataset

        return Dataset(self.path)

    def motions(self) -> MotionDatabase:
        """The whole motions dataset, read once per process."""
        return cached(("motions", self.path, self.fingerprint), lambda: self.dataset().motions())


@dataclass(frozen=True)
class ClipSlice:
    """Clips ``[start, stop)`` (positions in the ``clips`` table; ``stop=-1``: to the end)
    of a motions dataset on disk."""

    path: str
    fingerprint: str
    start: int
    stop: int

    def _meta(self) -> tuple[Any, Any, np.ndarray, np.ndarray, np.ndarray | None]:

        from .datasets import Dataset

        def load() -> tuple[Any, Any, np.ndarray, np.ndarray, np.ndarray | None]:
            ds = Dataset(self.path)
            clips, skeletons = ds.table("clips"), ds.table("skeletons")
            rows = np.concatenate([[0], np.cumsum(clips["n_frames"].to_numpy().astype(np.int64))])
            rot = ds.path / "rotations.parquet"
            return (
                clips,
                skeletons,
                rows,
                row_groups(ds.path / "data.parquet"),
                row_groups(rot) if rot.is_file() else None,
            )

        return cached(("clip-meta", self.path, self.fingerprint), load)

    def motions(self) -> MotionDatabase:
        """The slice's clips as a :class:`MotionDatabase`, reading only the Parquet row
        groups that hold them (each decoded once per process)."""

        from . import schema
        from .motion_tables import database_from_tables

        clips, skeletons, rows, groups, rot_groups = self._meta()
        stop = clips.num_rows if self.stop < 0 else self.stop
        r0, r1 = int(rows[self.start]), int(rows[stop])
        columns = list(schema.MOTION_COLUMNS if rot_groups is not None else schema.MOTION_COLUMNS_V1)
        frames = self._rows("data", groups, r0, r1, columns)
        if frames is None:
            return database_from_tables(clips.slice(0, 0), skeletons.slice(0, 0), _empty_frames())
        rotations = None if rot_groups is None else self._rows("rotations", rot_groups, self.start, stop, None)
        mine = clips.slice(self.start, stop - self.start)
        # only the skeletons of these clips: each definition is JSON parsed when rebuilt
        used = set(mine["skeleton"].to_pylist())
        keep = [i for i, k in enumerate(skeletons["skeleton"].to_pylist()) if k in used]
        return database_from_tables(mine, skeletons.take(keep), frames, rotations)

    def _rows(self, table: str, groups: np.ndarray, r0: int, r1: int, columns: list[str] | None) -> Any:
        return read_rows(self.path, self.fingerprint, table, groups, r0, r1, columns)


def row_groups(path: Any) -> np.ndarray:
    """First row of each row group of a Parquet file, and its row count last."""
    import pyarrow.parquet as pq

    md = pq.ParquetFile(path).metadata
    n = [md.row_group(i).num_rows for i in range(md.num_row_groups)]
    return np.concatenate([[0], np.cumsum(n)]).astype(np.int64)


def read_rows(
    path: str, fingerprint: str, table: str, groups: np.ndarray, r0: int, r1: int, columns: list[str] | None = None
) -> Any:
    """Rows ``[r0, r1)`` of one table of a dataset, from the row groups that hold them (each
    decoded once per process, :func:`row_groups` ``groups``); ``None`` for no row."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    g0 = max(int(np.searchsorted(groups, r0, side="right") - 1), 0)
    g1 = int(np.searchsorted(groups, r1, side="left"))
    opened: list[pq.ParquetFile] = []

    def read(g: int) -> Any:
        if not opened:
            opened.append(pq.ParquetFile(f"{path}/{table}.parquet", memory_map=True))
        return opened[0].read_row_group(g, columns=columns)

    key = ("row-group", path, fingerprint, table, tuple(columns or ()))
    parts = [cached((*key, g), partial(read, g), entries=_GROUP_ENTRIES) for g in range(g0, g1)]
    return pa.concat_tables(parts).slice(r0 - int(groups[g0]), r1 - r0) if parts and r1 > r0 else None


def _empty_frames() -> Any:
    from . import schema

    return schema.motion_frames().empty_table()


#: Frames per batch of a step that streams its output (:func:`clip_batches`): what a
#: process holds at once (65,536 frames of 31 joints: 65 MB of float64 rotations while they
#: are turned into features), whatever the library's size.
BATCH_FRAMES = 65536


def clip_batches(dataset: Dataset, max_frames: int | None = None) -> list[tuple[int, int]]:
    """Consecutive clip ranges ``[start, stop)`` (positions in ``clips``) of at most
    ``max_frames`` frames each (default :data:`BATCH_FRAMES`; a longer clip is a batch of its own)."""
    max_frames = BATCH_FRAMES if max_frames is None else int(max_frames)
    frames = dataset.table("clips", columns=["n_frames"])["n_frames"].to_numpy().astype(np.int64)
    out, a, size = [], 0, 0
    for i, t in enumerate(frames):
        if size and size + int(t) > max_frames:
            out.append((a, i))
            a, size = i, 0
        size += int(t)
    if a < len(frames):
        out.append((a, len(frames)))
    return out


def clip_slices(dataset: Dataset, n_slices: int, clips: tuple[int, int] | None = None) -> list[ClipSlice]:
    """At most ``n_slices`` contiguous clip ranges of a motions dataset (or of its clips
    ``[start, stop)``), about equal in frames."""
    frames = dataset.table("clips", columns=["n_frames"])["n_frames"].to_numpy().astype(np.int64)
    first = 0
    if clips is not None:
        first = int(clips[0])
        frames = frames[first : int(clips[1])]
    n = len(frames)
    if n == 0:
        return []
    k = max(1, min(int(n_slices), n))
    if k == n:  # one clip per slice
        bounds = np.arange(n + 1)
    else:  # cut at the clip boundary nearest to each k-th of the frames
        cum = np.concatenate([[0], np.cumsum(frames)])
        want = cum[-1] * np.arange(1, k) / k
        right = np.clip(np.searchsorted(cum, want, side="left"), 1, n)
        cuts = np.where(cum[right] - want <= want - cum[right - 1], right, right - 1)
        bounds = np.unique(np.clip(np.concatenate([[0], cuts, [n]]), 0, n))
    ref = DatasetRef.of(dataset)
    return [ClipSlice(ref.path, ref.fingerprint, first + int(a), first + int(b)) for a, b in pairwise(bounds) if b > a]


@dataclass(frozen=True)
class _SliceTask:
    """``[fn(motion) ...]`` (or ``fn(motion, clip_id)``) over the clips of one slice."""

    fn: Callable[..., Any]
    with_ids: bool = False

    def __call__(self, piece: ClipSlice) -> list[Any]:
        db = piece.motions()
        if self.with_ids:
            return [self.fn(m, int(c)) for m, c in zip(db.motions, db.clip_ids, strict=True)]
        return [self.fn(m) for m in db.motions]
