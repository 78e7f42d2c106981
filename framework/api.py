"""The Python API (``mocapflow.read``, ``mocapflow.Database``...): a thin facade over the
registered components the pipelines use; ``mocapflow`` re-exports it.

Every call goes through the registries (built once, lazily, by
:func:`.plugins.default_registries`), so a third-party plugin's formats, feature sets,
indexes, matchers and cleaners are available here under their names too. Searches go
through the pipelines' own query path (:func:`.queries.match_query`).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Union

if TYPE_CHECKING:
    import numpy as np
    import pyarrow as pa

    from .markers import Markers
    from .motion import Motion
    from .registry import Registries

#: What the facade reads as motions: a Motion, a file, a folder, or a sequence of them.
MotionsLike = Union["Motion", str, Path, Iterable[Union["Motion", str, Path]]]


def registries() -> Registries:
    """The registries of every installed plugin (built once per process)."""
    from .plugins import default_registries

    return default_registries()


def read(path: str | Path) -> Motion | Markers:
    """Read a motion or marker file with the registered format for its extension (ASF found
    beside AMC).

    Returns a :class:`~mocapflow.framework.Motion` for skeletal files (rotations, metres;
    ``.positions`` is ``(T, J, 3)`` in metres) and :class:`~mocapflow.framework.Markers` for
    marker files (C3D, TRC: ``.labels``, ``.positions`` ``(T, M, 3)`` metres, NaN in gaps).
    """
    from .errors import ConfigError

    path = Path(path).expanduser()
    ext = path.suffix.lower()
    formats = [cls for _, cls in registries()["formats"] if cls.produces in ("motion", "markers")]
    for cls in formats:
        if ext in cls.extensions:
            out: Motion | Markers = cls().read(path)
            return out
    what = f"{ext!r} files" if ext else "a path without a file extension"
    if path.is_dir():
        what = "a folder (give a file; Database(folder) reads a folder's takes)"
    motion = sorted({e for c in formats if c.produces == "motion" for e in c.extensions})
    markers = sorted({e for c in formats if c.produces == "markers" for e in c.extensions})
    raise ConfigError(
        f"{path}: no registered reader for {what}; motion files: {', '.join(motion)}; marker files: {', '.join(markers)}"
    )


def write(motion: Motion | Markers, path: str | Path) -> None:
    """Write ``motion`` (a Motion, or Markers to a marker format such as TRC) with the
    registered format for the extension of ``path``, atomically."""
    from .markers import Markers

    path = Path(path).expanduser()
    produces = "markers" if isinstance(motion, Markers) else "motion"
    ext = path.suffix.lower()
    writer = next(
        (c for _, c in registries()["formats"] if ext in c.extensions and c.produces == produces and c.can_write()),
        None,
    )
    if writer is None:
        from .errors import ConfigError

        what = f"{ext!r} files" if ext else "a path without a file extension"
        raise ConfigError(f"{path}: no registered {produces} writer for {what}")
    path.parent.mkdir(parents=True, exist_ok=True)
    writer().write_atomic(motion, path)


def _motions(motions: MotionsLike) -> list[Motion]:
    from .motion import Motion

    items = [motions] if isinstance(motions, (Motion, str, Path)) else list(motions)
    out: list[Motion] = []
    for m in items:
        if isinstance(m, Motion):
            out.append(m)
        elif Path(m).expanduser().is_dir():
            out.extend(_motion(read(f), f) for f in _motion_files(Path(m).expanduser()))
        else:
            out.append(_motion(read(m), m))
    return out


def _motion(obj: Motion | Markers, path: str | Path) -> Motion:
    """``obj`` when it is a Motion; a marker file where a motion is needed is refused."""
    from .errors import ConfigError
    from .motion import Motion

    if not isinstance(obj, Motion):
        raise ConfigError(f"{path}: a marker file, not a motion (mocapflow.read returns its Markers)")
    return obj


def _motion_files(folder: Path) -> list[Path]:
    """The files below ``folder`` that a registered motion format reads, in path order."""
    from .errors import ConfigError

    exts = {e for _, c in registries()["formats"] for e in c.extensions if c.produces == "motion"}
    files = sorted(f for f in folder.rglob("*") if f.suffix.lower() in exts and f.is_file())
    if not files:
        raise ConfigError(f"{folder}: no motion file in this folder or below ({', '.join(sorted(exts))})")
    return files


def features(name: str, motions: MotionsLike, **params: Any) -> np.ndarray:
    """Per-frame features of ``motions`` (Motions or paths) with ``features.<name>``.

    Returns an ndarray of float32, shape ``(total frames, dim)``, clips concatenated in order.
    """
    from .database import MotionDatabase

    db = MotionDatabase(_motions(motions))
    x: np.ndarray = registries()["features"].get(name)(params).fit(db).transform(db)
    return x


class Database:
    """Motions, their features and an index over them, ready for similarity search.

    Parameters
    ----------
    motions : sequence of Motion or paths, or a folder
        The clips (a folder: every motion file below it, in path order); clip ``i`` gets
        ``clip_id == i``.
    features : str
        Feature set (``features.<name>``); ``feature_params`` go to it.
    index : str
        Index (``indexes.<name>``) built over the features.
    fps : float or None
        Resample every clip (and each query) to this rate, Hz (the pipelines use 30); None keeps them.
    """

    def __init__(
        self,
        motions: MotionsLike,
        features: str = "end_effectors",
        index: str = "kdtree",
        *,
        fps: float | None = 30.0,
        feature_params: dict[str, Any] | None = None,
        index_params: dict[str, Any] | None = None,
    ) -> None:
        from .database import MotionDatabase
        from .normalize import resample
        from .queries import memory_space

        regs = registries()
        self.fps = fps
        #: the clips as given, at their own rates (what :meth:`Matches.export` writes)
        self.sources = _motions(motions)
        ms = [resample(m, fps) if fps else m for m in self.sources]
        self.motions = MotionDatabase(ms)
        self.feature_set = regs["features"].get(features)(feature_params or {}).fit(self.motions)
        x = self.feature_set.transform(self.motions)
        self.index = regs["indexes"].get(index)(index_params or {}).build(x)
        self.space = memory_space(self.motions, x, self.index)
        self.clip_names: dict[int, str] = self.space.clip_names or {}

    def search(
        self,
        query: Motion | str | Path,
        matcher: str = "search",
        count: int = 10,
        exclude_self: str | bool = "span",
        **params: Any,
    ) -> Matches:
        """Segments most similar to ``query`` (a Motion or path, resampled to the database rate).

        A query cut from a database clip (same source file) finds no match overlapping its
        own span widened by half its length on each side (``exclude_self="span"``), none in
        its clip (``"clip"``), or itself too (``"off"`` or ``False``).

        Returns :class:`Matches`: the match table in the clips' own units (``fps``, source
        frames ``start_frame``/``end_frame`` half-open, ``start_s``/``end_s`` seconds; the
        analysis-rate frames in ``*_analysis`` columns), ready to :meth:`~Matches.export`;
        an empty result says why in ``.reason``.
        """
        from .matching import in_source_units, matches_table
        from .normalize import resample
        from .queries import Query, exclude_mode, match_query

        mode = exclude_mode(exclude_self)
        q = _motions(query)[0]
        first = int(q.metadata.get("source_start_frame", 0))
        label = f"{q.name or 'query'}:{first}-{first + q.n_frames}" if "source_start_frame" in q.metadata else q.name
        own, a, b = self._own_span(q)
        n_src = q.n_frames
        q = resample(q, self.fps) if self.fps else q
        cls = registries()["matchers"].get(matcher)
        if "exclude_self" in cls.Params.model_fields:
            params["exclude_self"] = mode
        m = cls({"count": count, **params})
        x = self.feature_set.transform(q)
        res = match_query(
            m, Query(label or "query", x, own, first, first + n_src, a, b), self.space, own, exclude_self=mode
        )
        table = matches_table([0], [res.matches], self.space)
        rates = {
            int(c): (a.fps, s.metadata.get("source_fps", s.fps), s.metadata.get("source_frames", s.n_frames))
            for c, a, s in zip(self.motions.clip_ids, self.motions, self.sources, strict=True)
        }
        table = in_source_units(table, rates)
        return Matches(
            table.add_column(3, "clip", pa_names(table, self.clip_names)), self, label or "query", res.reason
        )

    def _own_span(self, q: Motion) -> tuple[int, int, int]:
        """``(clip_id, start, end)`` of ``q`` in database frames when it is cut from a clip
        of the same source file (its ``path``, ``source_start_frame``), else ``(-1, 0, 0)``."""
        path = q.metadata.get("path")
        if not path:
            return -1, 0, 0
        for c, src, m in zip(self.motions.clip_ids, self.sources, self.motions, strict=True):
            if src.metadata.get("path") and Path(src.metadata["path"]).resolve() == Path(path).resolve():
                t0 = (
                    int(q.metadata.get("source_start_frame", 0)) - int(src.metadata.get("source_start_frame", 0))
                ) / q.fps
                a = int(round(t0 * m.fps))
                return int(c), a, a + max(1, int(round(q.duration * m.fps)))
        return -1, 0, 0


def pa_names(table: pa.Table, names: dict[int, str]) -> pa.Array:
    import pyarrow as pa

    return pa.array([names[c] for c in table["clip_id"].to_pylist()], pa.string())


#: Columns of :class:`Matches` renamed when frame columns were unified: old -> new (the old
#: name still works in ``Matches[...]`` for one release, with a warning).
RENAMED_COLUMNS = {"analysis_fps": "fps_analysis", "analysis_path": "path_analysis"}


class Matches:
    """The matches of one search (:meth:`Database.search`): ``.table`` (pyarrow) in the clips'
    own units; table methods (``select``, ``to_pylist``, ``num_rows``...) work on it directly."""

    def __init__(self, table: pa.Table, database: Database, query: str, reason: str = "") -> None:
        self.table = table
        self.database = database
        self.query = query
        #: why there is no match (empty when there are matches)
        self.reason = reason

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("table", "database", "query", "reason"):  # copy/pickle before __init__
            raise AttributeError(name)
        return getattr(self.table, name)

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, str) and key in RENAMED_COLUMNS:
            warnings.warn(
                f"Matches[{key!r}] is deprecated; use Matches[{RENAMED_COLUMNS[key]!r}]",
                DeprecationWarning,
                stacklevel=2,
            )
            key = RENAMED_COLUMNS[key]
        return self.table[key]

    def __len__(self) -> int:
        return int(self.table.num_rows)

    def __repr__(self) -> str:
        head = f"Matches({self.query!r}, {self.table.num_rows} rows)"
        if self.reason:
            head += f": no match: {self.reason}"
        return f"{head}\n{self.table.drop_columns(['path_analysis'])}"

    def export(
        self, out_dir: str | Path, *, handle: int = 0, format: str | None = None, top: int | None = None
    ) -> pa.Table:
        """Write each match as a clip under ``out_dir/<query>/`` in its source's own format
        (or ``format``: bvh, amc...), rate, skeleton and joint names, widened by ``handle``
        source frames on each side, plus ``out_dir/index.csv``; returns the index table."""
        from .export import Segment, export_segments

        db = self.database
        by_id = {int(c): (m, src) for c, m, src in zip(db.motions.clip_ids, db.motions, db.sources, strict=True)}
        segs: list[Segment] = []
        sources: dict[str, Motion] = {}
        for r in self.table.select(["rank", "clip_id", "start_frame", "end_frame"]).to_pylist():
            if top is not None and r["rank"] > top:
                continue
            m, src = by_id[r["clip_id"]]
            key = str(src.metadata.get("path") or f"{src.name or r['clip_id']}.{src.metadata.get('format', 'bvh')}")
            sources[key] = src
            segs.append(Segment(self.query, r["rank"], m.name, key, r["start_frame"], r["end_frame"]))
        return export_segments(
            segs, Path(out_dir).expanduser(), registries(), handle=handle, format=format, load=sources.__getitem__
        )


def clean(take: Motion | str | Path, context: MotionsLike = (), **params: Any) -> tuple[Motion, pa.Table]:
    """Clean ``take`` against ``context`` takes with ``cleaners.mdm`` (Aristidou 2018).

    Returns ``(cleaned Motion, edits)``: the edits are an Arrow table (one row per edited
    joint and frame).
    """
    cleaner = registries()["cleaners"].get("mdm")({"write_bvh": False, "heatmaps": False, **params})
    cleaned, edits = cleaner.repair(_motions(take)[0], _motions(context))
    return cleaned, edits
