"""Segments of a table written as clips, in their source's own format, rate, skeleton and
joint names (``mocapflow export``, :meth:`mocapflow.Matches.export`, the report's export
commands).

A segment is a frame range ``[start_frame, end_frame)`` of a source file at the file's own
rate. :func:`export_segments` reads each source once with the registered reader for its
extension, cuts the range widened by ``handle`` frames on each side (clamped to the take),
and writes it with the registered writer for the source's extension (or the format asked
for): BVH keeps its channels, units and joint names (a static root the reader dropped is
written back), AMC writes its ASF beside it. Files go to one folder per query, named
``<rank>_<clip>_<start>-<end><ext>``; ``index.csv`` lists them.

:func:`workspace_segments` turns any segment table of a finished workspace (a match table,
a template or classification table with ``clip_id, start_frame, end_frame``, or a cleaner's
per-frame table with ``flagged``, whose runs of flagged frames become segments) into
segments of the source files, through the provenance of its motions.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from .datasets import Dataset
from .errors import ConfigError, DataError
from .motion import Motion
from .registry import Registries
from .workspace import export_table

#: Columns of ``index.csv``: one row per written file. ``start_frame``/``end_frame`` are the
#: segment (source frames, half-open), ``clip_start``/``clip_end`` what the file holds
#: (the segment and its handles), ``fps`` the source rate, seconds from the take's start.
INDEX = pa.schema(
    [
        ("query", pa.string()),
        ("rank", pa.int32()),
        ("clip", pa.string()),
        ("source", pa.string()),
        ("fps", pa.float64()),
        ("start_frame", pa.int32()),
        ("end_frame", pa.int32()),
        ("start_s", pa.float64()),
        ("end_s", pa.float64()),
        ("clip_start", pa.int32()),
        ("clip_end", pa.int32()),
        ("file", pa.string()),
    ]
)


@dataclass(frozen=True)
class Segment:
    """Frames ``[start_frame, end_frame)`` of ``source`` (a file, or a key of the ``load``
    callable of :func:`export_segments`) at its own rate, the ``rank``-th hit of ``query``."""

    query: str
    rank: int
    clip: str
    source: str
    start_frame: int
    end_frame: int


def safe_name(text: str) -> str:
    """``text`` as a file name: runs of characters other than letters, digits, ``._-`` become ``_``."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "clip"


def export_segments(
    segments: Sequence[Segment],
    out_dir: str | Path,
    registries: Registries,
    *,
    handle: int = 0,
    format: str | None = None,
    readers: Mapping[str, Mapping[str, Any]] | None = None,
    load: Callable[[str], Motion] | None = None,
) -> pa.Table:
    """Write every segment as a clip under ``out_dir/<query>/`` and ``out_dir/index.csv``;
    returns the index (:data:`INDEX`).

    ``format``: a writer's registry name (``bvh``, ``amc``...); default the source's own
    format. ``readers``: reader parameters by format name (a pipeline's ``readers``).
    ``load``: how a source is read (default: the registered reader for its extension).
    """
    if handle < 0:
        raise ConfigError(f"handle must be >= 0 frames, got {handle}")
    out = Path(out_dir)
    cache: dict[str, Motion] = {}
    rows: list[dict[str, Any]] = []
    used: set[Path] = set()
    for seg in segments:
        if seg.source not in cache:
            cache.clear()  # one source in memory at a time (segments come grouped by query)
            cache[seg.source] = load(seg.source) if load else _read(seg.source, registries, readers or {})
        motion = cache[seg.source]
        if not 0 <= seg.start_frame < seg.end_frame <= motion.n_frames:
            raise DataError(
                f"{seg.source}: segment [{seg.start_frame}, {seg.end_frame}) outside the take's {motion.n_frames} frames"
            )
        a, b = max(0, seg.start_frame - handle), min(motion.n_frames, seg.end_frame + handle)
        writer, ext = _writer(seg.source, motion, registries, format)
        folder = out / safe_name(seg.query)
        dest = folder / f"{seg.rank:02d}_{safe_name(seg.clip)}_{seg.start_frame}-{seg.end_frame}{ext}"
        if dest in used:
            raise DataError(f"two segments would both be written to {dest}")
        used.add(dest)
        clip = motion.slice(a, b)
        _write_into(writer, clip, dest)
        rows.append(
            {
                "query": seg.query,
                "rank": seg.rank,
                "clip": seg.clip,
                "source": seg.source,
                "fps": motion.fps,
                "start_frame": seg.start_frame,
                "end_frame": seg.end_frame,
                "start_s": seg.start_frame / motion.fps,
                "end_s": seg.end_frame / motion.fps,
                "clip_start": a,
                "clip_end": b,
                "file": dest.relative_to(out).as_posix(),
            }
        )
    index = pa.Table.from_pylist(rows, schema=INDEX)
    out.mkdir(parents=True, exist_ok=True)
    export_table(index, out / "index.csv", "csv")
    return index


def _write_into(writer: Any, clip: Motion, dest: Path) -> None:
    """Write ``clip`` to ``dest``, creating its folder; a writer that refuses leaves no
    folder this call created behind."""
    created, d = [], dest.parent
    while not d.exists():
        created.append(d)
        d = d.parent
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        writer.write_atomic(clip, dest)
    except BaseException:
        for d in created:  # deepest first; only the empty ones
            try:
                d.rmdir()
            except OSError:
                break
        raise


def _read(source: str, registries: Registries, readers: Mapping[str, Mapping[str, Any]]) -> Motion:
    path = Path(source)
    if not path.is_file():
        raise ConfigError(f"{source}: the source file of this segment is gone (moved or deleted since the run)")
    cls = type(registries.motion_format(path))
    motion = cls(dict(readers.get(cls.name, {}))).read(path)
    if not isinstance(motion, Motion):
        raise DataError(f"{source}: the reader returned {type(motion).__name__}, not a Motion")
    return motion


def _writer(source: str, motion: Motion, registries: Registries, format: str | None) -> tuple[Any, str]:
    """The writer for ``format`` (registry name) or for the source's own format, and its extension."""
    if format is None:
        ext = Path(source).suffix.lower() or f".{motion.metadata.get('format', 'bvh')}"
        try:
            return registries.motion_format(Path("clip" + ext), writing=True), ext
        except ConfigError:
            raise ConfigError(
                f"{source}: no registered writer for {ext!r} files; choose one with format (e.g. bvh)"
            ) from None
    cls = registries["formats"].get(format)
    if getattr(cls, "produces", "") != "motion" or not cls.can_write() or not cls.extensions:
        raise ConfigError(f"format {format!r} has no motion writer")
    return cls(), cls.extensions[0]


def clip_sources(motions: Dataset) -> dict[int, dict[str, Any]]:
    """``clip_id -> {name, path, fps, source_fps, source_frames}`` of a motions dataset."""
    cols = ["clip_id", "name", "path", "fps", "source_fps", "source_frames"]
    return {int(r["clip_id"]): r for r in motions.table("clips", columns=cols).to_pylist()}


def motions_of(ds: Dataset, datasets: Mapping[str, Dataset]) -> Dataset | None:
    """The motions dataset (with source paths) a dataset's rows come from, through provenance."""
    seen, todo = set(), [ds]
    while todo:
        d = todo.pop(0)
        if d.step in seen:
            continue
        seen.add(d.step)
        if d.has_table("clips") and "source_fps" in d.schema("clips").names:
            return d
        for up in d.manifest.get("inputs", {}).values():
            step = up.get("step") if isinstance(up, dict) else up
            if isinstance(step, str) and step in datasets:
                todo.append(datasets[step])
    return None


def workspace_segments(ds: Dataset, datasets: Mapping[str, Dataset], *, top: int | None = None) -> list[Segment]:
    """Segments of the source files for the rows of ``ds``'s main table (module doc), best
    ``top`` per query (all when None)."""
    names = ds.schema("data").names
    mds = motions_of(ds, datasets)
    if mds is None:
        raise ConfigError(f"{ds.step}: cannot trace its rows back to the motion files they come from")
    clips = clip_sources(mds)
    source_units = "start_frame_analysis" in names
    if {"clip_id", "start_frame", "end_frame"} <= set(names):
        cols = [c for c in ("query_id", "rank", "label", "clip_id", "start_frame", "end_frame") if c in names]
        rows = ds.table("data", columns=cols).to_pylist()
    elif {"clip_id", "frame", "flagged"} <= set(names):
        rows = _flagged_runs(ds.table("data", columns=["clip_id", "frame", "flagged"]))
    else:
        raise ConfigError(
            f"{ds.step}: its table has no segments (clip_id, start_frame, end_frame) nor flagged frames "
            f"(clip_id, frame, flagged); columns: {', '.join(names)}"
        )
    qnames: dict[int, str] = {}
    if ds.has_table("queries"):
        q = ds.table("queries", columns=["query_id", "name"])
        qnames = dict(zip(q["query_id"].to_pylist(), q["name"].to_pylist(), strict=True))
    out: list[Segment] = []
    ranks: dict[str, int] = {}
    for r in rows:
        if "query_id" in r:
            query = str(qnames.get(r["query_id"], f"query_{r['query_id']}"))
        else:
            query = str(r.get("label") or ds.step)
        rank = int(r.get("rank") or ranks.get(query, 0) + 1)
        ranks[query] = rank
        if top is not None and rank > top:
            continue
        c = clips.get(int(r["clip_id"]))
        if c is None:
            raise DataError(f"{ds.step}: clip {r['clip_id']} is not a clip of {mds.step!r}")
        if source_units:  # a matcher step's table: already frames of the take's own file
            sf, ef = int(r["start_frame"]), int(r["end_frame"])
        else:
            sf, ef = source_frames(r["start_frame"], r["end_frame"], c["fps"], c["source_fps"], c["source_frames"])
        out.append(Segment(query, rank, str(c["name"]), str(c["path"]), sf, ef))
    return sorted(out, key=lambda s: (s.query, s.rank))


def source_frames(start: int, end: int, fps: float, source_fps: float, n_source: int) -> tuple[int, int]:
    """Frames ``[start, end)`` at ``fps`` (a resampled clip) as source frames at
    ``source_fps``, half-open, within the take's ``n_source`` frames (the same rule as
    :func:`~.matching.in_source_units`)."""
    a = int(np.clip(round(start / fps * source_fps), 0, max(n_source - 1, 0)))
    b = int(max(min(round(end / fps * source_fps), n_source), a + 1))
    return a, b


def _flagged_runs(t: pa.Table) -> list[dict[str, Any]]:
    """Runs of consecutive frames with any flagged cell, per clip, longest first."""
    cid = t["clip_id"].to_numpy()
    fr = t["frame"].to_numpy()
    flagged = t["flagged"].to_numpy(zero_copy_only=False).astype(bool)
    runs: list[dict[str, Any]] = []
    for c in np.unique(cid[flagged]):
        frames = np.unique(fr[flagged & (cid == c)])
        cuts = np.flatnonzero(np.diff(frames) > 1) + 1
        for part in np.split(frames, cuts):
            runs.append({"clip_id": int(c), "start_frame": int(part[0]), "end_frame": int(part[-1]) + 1})
    return sorted(runs, key=lambda r: (r["start_frame"] - r["end_frame"], r["clip_id"], r["start_frame"]))
