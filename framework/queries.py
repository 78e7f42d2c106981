"""The matcher step, written once: how inputs become a search space, queries and matches.

Every search goes through :func:`match_query` (one query against a :class:`SearchSpace`:
the query's own span excluded explicitly, an empty result with its reason) and
:func:`~.matching.in_source_units` (the one unit convention users read): the pipeline step
(:func:`run_matcher`), the Python facade and the ``mocapflow search`` server alike.

:class:`MatchInputs` resolves once, from a step's inputs, what a search needs (the index or
features of the database, the database's motions with their source rates, the query
input's clips). Query ranges (``SOURCE[:START-END]``) count frames of the take's own file
(or seconds), like the ``start_frame``/``end_frame`` a search prints, so any printed hit is a
valid next query. Features are computed on the whole query clip and then cut, so windowed
features match the database's frame for frame.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from functools import cached_property, partial
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pyarrow as pa

from . import schema
from .clip_refs import DatasetRef, cached
from .components import FeatureSet, Matcher
from .context import StepContext
from .database import MotionDatabase
from .datasets import Dataset, StepOutput
from .errors import ConfigError, DataError, PipelineError
from .matching import (
    EXCLUDE_SELF,
    ClipUnits,
    NeighbourIndex,
    QueryMatches,
    QuerySpec,
    SearchSpace,
    analysis_span,
    drop_excluded,
    in_source_units,
    matches_table,
    min_frames_of,
    parse_query_spec,
    self_rows,
)
from .motion import Motion
from .registry import Registries

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Query:
    """One query: its features and where they came from (``clip_id`` -1 for a file).

    ``start_frame``/``end_frame`` are frames of the take's own file (as printed and as typed
    in ``SOURCE:START-END``); ``start_frame_analysis``/``end_frame_analysis`` the rows of
    ``features`` within the clip at the analysis rate (what the search space counts)."""

    name: str
    features: np.ndarray
    clip_id: int = -1
    start_frame: int = 0
    end_frame: int = 0
    start_frame_analysis: int = -1
    end_frame_analysis: int = -1

    def __post_init__(self) -> None:
        if self.start_frame_analysis < 0:  # no source rate known: one frame is one row
            object.__setattr__(self, "start_frame_analysis", self.start_frame)
            object.__setattr__(self, "end_frame_analysis", self.end_frame)


def upstream(ds: Dataset, slot: str) -> Dataset | None:
    """The dataset feeding ``slot`` of the step that wrote ``ds`` (a workspace sibling)."""
    up = ds.manifest.get("inputs", {}).get(slot)
    step = up.get("step") if isinstance(up, dict) else up
    if not step or not (ds.path.parent / step).is_dir():
        return None
    return Dataset(ds.path.parent / step)


def feature_set_of(features: Dataset, registries: Registries) -> FeatureSet:
    """The configured (and, if needed, fitted) feature set that wrote ``features``."""
    cls = registries.resolve(features.producer)
    if not issubclass(cls, FeatureSet):
        raise PipelineError(f"dataset {features.step!r} was written by {features.producer}, not a feature set")
    fs = cls(features.manifest.get("params", {}))
    if cls.requires_fit:
        fs.load_state(features.path)
    return fs


def read_motion_file(path: Path, registries: Registries, fps: float | None) -> Motion:
    """Read one motion file with the registered reader for its extension, resampled to
    ``fps`` (its own rate and frame count kept as ``source_fps``/``source_frames``)."""
    from .normalize import resample

    motion = registries.motion_format(path).read(path)
    if not isinstance(motion, Motion):
        raise ConfigError(f"{path}: the reader returned {type(motion).__name__}, not a Motion")
    motion.metadata.setdefault("source_fps", motion.fps)
    motion.metadata.setdefault("source_frames", motion.n_frames)
    return resample(motion, fps) if fps else motion


def source_rate(motion: Motion) -> tuple[float, int]:
    """``(fps, frames)`` of the file ``motion`` was read from (its own, when not resampled)."""
    return float(motion.metadata.get("source_fps", motion.fps)), int(
        motion.metadata.get("source_frames", motion.n_frames)
    )


def query_segment(spec: QuerySpec, motion: Motion, what: str = "query") -> tuple[int, int, int, int]:
    """``(source start, source end, analysis start, analysis end)`` of ``spec`` on ``motion``
    (read at the analysis rate): the range counts frames of the take's own file (or
    seconds), validated against it with an error naming the rate."""
    src_fps, n_src = source_rate(motion)
    units = f"frames of the take's own file, at {src_fps:g} fps"
    try:
        sa, sb = spec.frames(src_fps, n_src, units)
    except ConfigError as exc:
        raise ConfigError(f"{what}: {exc}") from None
    if spec.start is None:
        return sa, sb, 0, motion.n_frames
    a, b = analysis_span(sa, sb, src_fps, motion.fps, motion.n_frames)
    return sa, sb, a, b


def motion_queries(
    specs: list[QuerySpec],
    mdb: MotionDatabase,
    feature_set: FeatureSet,
    registries: Registries,
    resolve: Callable[[str], Path],
    what: str = "query",
    fps: float | None = None,
) -> list[Query]:
    """Features of query segments (no ``specs``: every clip) of clips of ``mdb`` (by name,
    file name, stem or path suffix) or of files (``resolve``d, resampled to ``fps``)."""
    names: dict[str, int] = {}
    for pos, m in enumerate(mdb.motions):
        p = str(m.metadata.get("path") or "")
        for key in {m.name, Path(p).name, Path(p).stem, p} - {""}:
            names.setdefault(key, pos)
    fps = fps if fps is not None else (mdb.fps if mdb.n_clips else None)
    out = []
    for spec in specs or [QuerySpec(m.name) for m in mdb.motions]:
        found = names.get(spec.source)
        if found is None:
            found = next((i for k, i in names.items() if k.endswith("/" + spec.source)), None)
        if found is not None:
            motion, cid = mdb.motions[found], int(mdb.clip_ids[found])
        else:
            path = resolve(spec.source)
            if not path.is_file():
                raise ConfigError(f"{what}: query {spec.source!r} is neither a clip nor a file")
            motion, cid = read_motion_file(path, registries, fps), -1
        sa, sb, a, b = query_segment(spec, motion, what)
        x = np.asarray(feature_set.transform_motion(motion), np.float32)[a:b]
        out.append(Query(spec.text(), x, cid, sa, sb, a, b))
    return out


def features_dataset(inputs: Mapping[str, Dataset]) -> Dataset | None:
    """The database's features dataset: the ``features`` input, the database itself, or the
    index's upstream features (provenance)."""
    db = inputs["database"]
    if "features" in inputs:
        return inputs["features"]
    return db if db.producer_kind == "features" else upstream(db, "features")


@dataclass(frozen=True)
class MatchInputs:
    """What a matcher step reads, resolved once from its inputs (provenance walked once).

    ``database`` (an index, or features for matchers that need no index), ``features`` its
    feature rows (the ``features`` input, the database itself or the index's upstream
    features), ``motions`` the database's motions (clips with their source rates; None when
    provenance does not reach them), ``query`` the query input and ``query_clips`` the
    dataset with its ``clips`` table (itself or its upstream motions)."""

    database: Dataset
    features: Dataset | None = None
    motions: Dataset | None = None
    query: Dataset | None = None
    query_clips: Dataset | None = None

    @classmethod
    def of(cls, inputs: Mapping[str, Dataset]) -> MatchInputs:
        db, qds = inputs["database"], inputs.get("query")
        fds = features_dataset(inputs)
        mds = upstream(fds or db, "motions")
        if mds is not None and not mds.has_table("clips"):
            mds = None
        qclips = None
        if qds is not None:
            qclips = qds if qds.has_table("clips") else upstream(qds, "motions")
            if qclips is not None and not qclips.has_table("clips"):
                qclips = None
        return cls(db, fds, mds, qds, qclips)

    def search_slots(self) -> dict[str, Dataset]:
        """The datasets a search space is built from (what a worker is sent, by reference)."""
        return {"database": self.database, **({"features": self.features} if self.features else {})}

    @cached_property
    def clip_names(self) -> dict[int, str] | None:
        """Database clip id -> name (None without motions)."""
        if self.motions is None:
            return None
        t = self.motions.table("clips", columns=["clip_id", "name"])
        return dict(zip(t["clip_id"].to_pylist(), t["name"].to_pylist(), strict=True))

    @cached_property
    def units(self) -> ClipUnits | None:
        """Database clip id -> (analysis fps, source fps, source frames) (None: unknown)."""
        if self.motions is None or "source_fps" not in self.motions.schema("clips").names:
            return None
        t = self.motions.table("clips", columns=["clip_id", "fps", "source_fps", "source_frames"]).to_pylist()
        return {int(r["clip_id"]): (r["fps"], r["source_fps"], r["source_frames"]) for r in t}

    def own_clip(self, clip_id: int) -> int:
        """The database clip a query clip is (``exclude_self``; -1: none): the same clip
        when the query input is the database's own features or motions, else the clip of
        the same source file (:attr:`own_clips`)."""
        q, same = self.query, False
        if q is not None:
            same = any(d is not None and d.path.resolve() == q.path.resolve() for d in (self.features, self.motions))
        if same:
            return clip_id
        return self.own_clips.get(clip_id, -1)

    @cached_property
    def own_clips(self) -> dict[int, int]:
        """Query clip id -> the database clip of the same source file (by path), for the
        queries that lie inside the database (``exclude_self``)."""
        if self.motions is None or self.query_clips is None:
            return {}
        db = self.motions.table("clips", columns=["clip_id", "path"]).to_pylist()
        by_path = {r["path"]: r["clip_id"] for r in db if r["path"]}
        out = {}
        for r in self.query_clips.table("clips", columns=["clip_id", "path"]).to_pylist():
            if r["path"] in by_path:
                out[int(r["clip_id"])] = int(by_path[r["path"]])
        return out


def search_space(
    matcher: Matcher,
    inputs: MatchInputs | Mapping[str, Dataset],
    registries: Registries,
    index: NeighbourIndex | None = None,
) -> SearchSpace:
    """The :class:`SearchSpace` of a step: rows of ``database``, its index when the matcher
    ``needs_index`` (``index``: already loaded), the features when
    :meth:`~.components.Matcher.uses_features`, clip names. Rows and features come from the
    index's memory-mapped row sidecars (``index.rows()``) when it has them."""
    mi = inputs if isinstance(inputs, MatchInputs) else MatchInputs.of(inputs)
    db = mi.database
    if matcher.needs_index and db.producer_kind != "indexes":
        raise PipelineError(
            f"{matcher.key()}: input 'database' must be an index dataset, got {db.step!r} ({db.producer})"
        )
    if index is None and matcher.needs_index:
        index = db.index(registries)
    rows_of = getattr(index, "rows", None)
    sidecar = rows_of() if rows_of is not None else None
    if sidecar is not None:
        xs, clip_id, frame = sidecar
    else:
        clip_id, frame = db.frame_ids()
    x = None
    if matcher.uses_features():
        if sidecar is not None:
            x = xs
        else:
            fds = mi.features
            if fds is None:
                raise PipelineError(
                    f"{matcher.key()}: cannot find the database features of {db.step!r}; give a 'features' input"
                )
            fm = fds.features()
            if not (np.array_equal(fm.clip_id, clip_id) and np.array_equal(fm.frame, frame)):
                raise DataError(f"{matcher.key()}: rows of features {fds.step!r} differ from those of {db.step!r}")
            x = fm.x
    return SearchSpace(clip_id, frame, index if matcher.needs_index else None, x, clip_names=mi.clip_names)


def memory_space(motions: MotionDatabase, features: np.ndarray, index: NeighbourIndex | None) -> SearchSpace:
    """The :class:`SearchSpace` of an in-memory database (the Python facade's): every frame
    of ``motions`` with its ``features`` rows and the ``index`` built over them."""
    clip_id, frame = motions.frame_ids
    names = {int(c): m.name for c, m in zip(motions.clip_ids, motions, strict=True)}
    return SearchSpace(clip_id, frame, index, features, clip_names=names)


def step_queries(matcher: Matcher, inputs: MatchInputs | Mapping[str, Dataset], ctx: StepContext) -> list[Query]:
    """Query features from the ``query`` input and the matcher's ``queries`` parameter."""
    mi = inputs if isinstance(inputs, MatchInputs) else MatchInputs.of(inputs)
    qds = mi.query
    if qds is None:
        raise PipelineError(f"{matcher.key()}: no 'query' input")
    specs = [parse_query_spec(s) for s in getattr(matcher.params, "queries", [])]
    if "features" in qds.schema("data").names:
        return feature_queries(qds, specs, matcher.key())
    if mi.features is None:
        raise PipelineError(f"{matcher.key()}: query motions need the database's feature set; give a 'features' input")
    fs = feature_set_of(mi.features, ctx.registries)
    return motion_queries(
        specs, qds.motions(), fs, ctx.registries, ctx.resolve, what=f"{matcher.key()}: query input {qds.step!r}"
    )


def feature_queries(qds: Dataset, specs: list[QuerySpec], what: str) -> list[Query]:
    """Queries cut from a features dataset (specs name clips by id; ranges in feature rows)."""
    fm = qds.features()
    bounds = np.flatnonzero(np.diff(fm.clip_id)) + 1
    clips = {int(c[0]): (s, len(c)) for c, s in zip(np.split(fm.clip_id, bounds), np.r_[0, bounds], strict=True)}
    out = []
    for spec in specs or [QuerySpec(str(c)) for c in clips]:
        try:
            cid = int(spec.source)
            s, n = clips[cid]
        except (ValueError, KeyError):
            raise ConfigError(
                f"{what}: feature queries are named by clip id; {spec.source!r} is not one of {qds.step!r}"
            ) from None
        if spec.seconds:
            raise ConfigError(f"{what}: give feature query ranges in frames ({spec.text()!r})")
        a, b = spec.frames(1.0, n)
        out.append(Query(spec.text(), fm.x[s + a : s + b], cid, a, b))
    return out


@dataclass(frozen=True)
class MatchResult:
    """The matches of one query (:func:`match_query`): index rows, the ``excluded`` rows
    (closed; the query's own span, None when nothing was excluded) and, when there is no
    match, the ``reason`` (empty otherwise)."""

    matches: QueryMatches
    excluded: tuple[int, int] | None = None
    reason: str = ""


def own_rows(space: SearchSpace, query: Query, own_clip: int, mode: str) -> tuple[int, int] | None:
    """Index rows the query excludes as its own (:func:`~.matching.self_rows`; ``own_clip``
    -1: the query is not a database take)."""
    return self_rows(space, own_clip, query.start_frame_analysis, query.end_frame_analysis, mode)


def exclude_mode(value: object) -> str:
    """An ``exclude_self`` value as a mode (``False``, as YAML reads an unquoted ``off``: "off")."""
    mode = "off" if value is False or value is None else str(value)
    if mode not in EXCLUDE_SELF:
        raise ConfigError(f"exclude_self must be one of {', '.join(EXCLUDE_SELF)} (or False), got {value!r}")
    return mode


def match_query(
    matcher: Matcher,
    query: Query,
    space: SearchSpace,
    own_clip: int = -1,
    *,
    exclude_self: object = None,
    excluded: tuple[int, int] | None | Literal["auto"] = "auto",
) -> MatchResult:
    """One query against ``space``: the matcher searches the space with the query's own span
    excluded and any match overlapping it is dropped; an empty result says why.

    The span: ``own_clip`` is the database clip the query is cut from (-1: none), the mode
    ``exclude_self`` (None: the matcher's parameter; see :func:`~.matching.self_rows`); or
    precomputed ``excluded`` rows (closed; None: nothing)."""
    if type(matcher).match is Matcher.match:
        raise NotImplementedError(f"{matcher.key()} implements neither match(query, space) nor run()")
    if excluded == "auto":
        mode = exclude_mode(
            exclude_self if exclude_self is not None else getattr(matcher.params, "exclude_self", "off")
        )
        excluded = own_rows(space, query, own_clip, mode)
    res = matcher.match(query.features, space.excluding(excluded))
    if not isinstance(res, QueryMatches):
        raise PipelineError(f"{matcher.key()}.match returned {type(res).__name__}, not QueryMatches")
    res = drop_excluded(res, excluded)
    return MatchResult(res, excluded, "" if len(res) else empty_reason(matcher, query, space, excluded))


def empty_reason(matcher: Matcher, query: Query, space: SearchSpace, excluded: tuple[int, int] | None) -> str:
    """Why a search found no match: every database frame excluded as the query's own, no
    stretch of the database long enough for ``min_span``, or none within ``max_cost``."""
    p = matcher.params
    free = np.ones(space.n_rows, bool)
    if excluded is not None:
        free[excluded[0] : excluded[1] + 1] = False
    mode = getattr(p, "exclude_self", "off")
    if space.n_rows and not free.any():
        return f"every database frame is the query's own (exclude_self={mode!r}; 'off' searches them too)"
    # the longest stretch of consecutive free rows of one clip
    run = longest = 0
    for ok, cont in zip(free, space.continues, strict=True):
        run = run + 1 if ok and cont and run else int(ok)
        longest = max(longest, run)
    need = min_frames_of(float(getattr(p, "min_span", 0.0)), len(query.features))
    if longest < need:
        what = "outside the query's own span " if excluded is not None else ""
        return (
            f"the longest database stretch {what}is {longest} frames, shorter than min_span="
            f"{getattr(p, 'min_span', 0):g} x the query's {len(query.features)} frames ({need}; lower min_span)"
        )
    max_cost = getattr(p, "max_cost", None)
    if max_cost is not None:
        return f"no match costs at most max_cost={max_cost:g}"
    return "the matcher found no match"


def run_matcher(matcher: Matcher, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
    """The default matcher step: :class:`MatchInputs` resolved once, then :func:`match_query`
    per query (on workers when the executor has several) and one table in users' units."""
    if type(matcher).match is Matcher.match:
        raise NotImplementedError(f"{matcher.key()} implements neither match(query, space) nor run()")
    mi = MatchInputs.of(inputs)
    space = search_space(matcher, mi, ctx.registries)
    queries = step_queries(matcher, mi, ctx)
    mode = str(getattr(matcher.params, "exclude_self", "off"))
    excluded = [own_rows(space, q, mi.own_clip(q.clip_id) if q.clip_id >= 0 else -1, mode) for q in queries]
    results: list[MatchResult]
    if ctx.executor.workers > 1 and len(queries) > 1:
        # one task per query; each worker loads the search space once, with the run's registries
        refs = {slot: DatasetRef.of(ds) for slot, ds in mi.search_slots().items()}
        task = partial(_match_task, matcher, refs, ctx.registries)
        results = ctx.map(task, list(zip(queries, excluded, strict=True)), desc=ctx.step_id)
    else:
        results = [
            match_query(matcher, q, space, excluded=ex)
            for q, ex in zip(ctx.progress(queries, total=len(queries)), excluded, strict=False)
        ]
    for qi, (q, r) in enumerate(zip(queries, results, strict=True)):
        if r.reason:
            log.warning("step %r: query %s: no match: %s", ctx.step_id, q.name, r.reason)
        matcher.after_match(qi, q, r.matches, space, ctx)
    table = match_step_table([r.matches for r in results], space, mi.units)
    return StepOutput(
        {"data": table, "queries": queries_table(queries)},
        {"queries": len(queries), "matches": int(sum(len(r.matches) for r in results))},
    )


#: Deprecated duplicates a matcher step keeps for one release (the names before the frame
#: columns were unified): old name -> the column it repeats.
DEPRECATED_MATCH_COLUMNS = {"source_fps": "fps", "source_start_frame": "start_frame", "source_end_frame": "end_frame"}


def match_step_table(results: list[QueryMatches], space: SearchSpace, units: ClipUnits | None) -> pa.Table:
    """The ``data`` table of a matcher step: :func:`~.matching.in_source_units` of the
    matches, query ids by position, with the :data:`DEPRECATED_MATCH_COLUMNS` appended."""
    table = in_source_units(matches_table(list(range(len(results))), results, space), units)
    for old, new in DEPRECATED_MATCH_COLUMNS.items():
        table = table.append_column(old, table[new])
    return table


def in_user_units(out: StepOutput, inputs: Mapping[str, Dataset]) -> StepOutput:
    """The output of a matcher's own ``run`` with its ``data`` table (when it starts with the
    :data:`~.schema.MATCHES` columns at the analysis rate) in users' units, as the default
    step's (:func:`~.matching.in_source_units`); other tables unchanged."""
    table = out.tables.get("data")
    if not isinstance(table, pa.Table) or "start_frame_analysis" in table.column_names:
        return out
    head = pa.schema(list(table.schema)[: len(schema.MATCHES)])
    if not head.equals(schema.MATCHES):
        return out
    units = MatchInputs.of(inputs).units
    if units is None or not set(table["clip_id"].to_pylist()) <= set(units):
        return out
    return replace(out, tables={**out.tables, "data": in_source_units(table, units)})


def _match_task(
    matcher: Matcher,
    refs: dict[str, DatasetRef],
    registries: Registries,
    job: tuple[Query, tuple[int, int] | None],
) -> MatchResult:
    """One query of :func:`run_matcher` on a worker (the search space loaded once per process)."""
    key = (
        "search-space",
        matcher.key(),
        json.dumps(matcher.get_params(), sort_keys=True),
        tuple(sorted((s, r.path, r.fingerprint) for s, r in refs.items())),
    )
    space = cached(key, lambda: search_space(matcher, {s: r.dataset() for s, r in refs.items()}, registries))
    query, excluded = job
    return match_query(matcher, query, space, excluded=excluded)


def queries_table(queries: list[Query]) -> pa.Table:
    """:data:`~.schema.QUERIES` of each query (clip_id -1: a file): frames of the take's own
    file, then the analysis-rate frames."""
    rows = [{"query_id": i, **{k: getattr(q, k) for k in schema.QUERIES.names[1:]}} for i, q in enumerate(queries)]
    return pa.Table.from_pylist(rows, schema=schema.QUERIES)


def query_spans_error(
    component: Any, query_step: str | None, steps: Mapping[str, Any], base_dir: Path, registries: Registries
) -> str | None:
    """Plan-time check of a matcher's ``queries`` ranges against their takes: each
    ``SOURCE:START-END`` naming a file (relative to ``base_dir``) or a take the ``query``
    input loads (``steps``: planned steps with ``component`` and ``inputs``; the take is found
    among the files of the first upstream step with a ``paths`` parameter) must lie within
    the file's own frames. The error, or None (takes not found are checked at run time)."""
    import glob

    specs = [parse_query_spec(t) for t in getattr(component.params, "queries", []) or [] if isinstance(t, str)]
    specs = [s for s in specs if s.start is not None]
    if not specs or not isinstance(component, Matcher):
        return None
    files: list[Path] = []
    todo, seen = [query_step], set()
    while todo:  # the files the query input is read from: the nearest step with `paths`
        sid = todo.pop(0)
        if sid is None or sid in seen or sid not in steps:
            continue
        seen.add(sid)
        paths = getattr(steps[sid].component.params, "paths", None)
        if isinstance(paths, (list, tuple)) and paths:
            for pat in paths:
                p = Path(str(pat)).expanduser()
                files += [
                    Path(f) for f in sorted(glob.glob(str(p if p.is_absolute() else base_dir / p), recursive=True))
                ]
            break
        todo += list(steps[sid].inputs.values())
    for spec in specs:
        direct = Path(spec.source).expanduser()
        direct = direct if direct.is_absolute() else base_dir / direct
        path = direct if direct.is_file() else None
        for f in files if path is None else ():
            if spec.source in (f.name, f.stem) or str(f).endswith("/" + spec.source):
                path = f
                break
        if path is None:
            continue
        try:
            motion = registries.motion_format(path).read(path)
        except Exception:  # an unreadable take is reported by the step that reads it
            continue
        if not isinstance(motion, Motion):
            continue
        try:
            query_segment(spec, motion, path.name)
        except ConfigError as exc:
            return str(exc)
    return None
