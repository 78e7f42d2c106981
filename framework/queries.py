"""The default matcher step: how a step's inputs become a search space and query arrays.

:func:`run_matcher` builds the :class:`~.matching.SearchSpace` from ``database`` (an index
dataset; or features for matchers that need no index), the query features from ``query``
(motions, turned into features by the database's feature set re-created from provenance;
or features), calls ``matcher.match`` per query and writes ``data`` and ``queries``.
Features are computed on the whole query clip and then cut (``SOURCE[:START-END]``), so
windowed features match the database's frame for frame.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

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
    QueryMatches,
    QuerySpec,
    SearchSpace,
    drop_excluded,
    excluding,
    in_source_units,
    matches_table,
    parse_query_spec,
    self_rows,
)
from .motion import Motion
from .registry import Registries


@dataclass(frozen=True)
class Query:
    """One query: its features and where they came from (``clip_id`` -1 for a file)."""

    name: str
    features: np.ndarray
    clip_id: int = -1
    start_frame: int = 0
    end_frame: int = 0


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
    """Read one motion file with the registered reader for its extension, resampled to ``fps``."""
    from .normalize import resample

    motion = registries.motion_format(path).read(path)
    if not isinstance(motion, Motion):
        raise ConfigError(f"{path}: the reader returned {type(motion).__name__}, not a Motion")
    return resample(motion, fps) if fps else motion


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
        a, b = spec.frames(motion.fps, motion.n_frames)
        x = np.asarray(feature_set.transform_motion(motion), np.float32)[a:b]
        out.append(Query(spec.text(), x, cid, a, b))
    return out


def features_dataset(inputs: Mapping[str, Dataset]) -> Dataset | None:
    """The database's features dataset: the ``features`` input, the database itself, or the
    index's upstream features (provenance)."""
    db = inputs["database"]
    if "features" in inputs:
        return inputs["features"]
    return db if db.producer_kind == "features" else upstream(db, "features")


def search_space(matcher: Matcher, inputs: Mapping[str, Dataset], registries: Registries) -> SearchSpace:
    """The :class:`SearchSpace` of a step: rows of ``database``, its index when the matcher
    ``needs_index``, the features when :meth:`~.components.Matcher.uses_features`, clip names."""
    db = inputs["database"]
    if matcher.needs_index and db.producer_kind != "indexes":
        raise PipelineError(
            f"{matcher.key()}: input 'database' must be an index dataset, got {db.step!r} ({db.producer})"
        )
    clip_id, frame = db.frame_ids()
    index = db.index(registries) if matcher.needs_index else None
    x = None
    if matcher.uses_features():
        fds = features_dataset(inputs)
        if fds is None:
            raise PipelineError(
                f"{matcher.key()}: cannot find the database features of {db.step!r}; give a 'features' input"
            )
        fm = fds.features()
        if not (np.array_equal(fm.clip_id, clip_id) and np.array_equal(fm.frame, frame)):
            raise DataError(f"{matcher.key()}: rows of features {fds.step!r} differ from those of {db.step!r}")
        x = fm.x
    mds = upstream(features_dataset(inputs) or db, "motions")
    names = None
    if mds is not None and mds.has_table("clips"):
        t = mds.table("clips", columns=["clip_id", "name"])
        names = dict(zip(t["clip_id"].to_pylist(), t["name"].to_pylist(), strict=True))
    return SearchSpace(clip_id, frame, index, x, clip_names=names)


def step_queries(matcher: Matcher, inputs: Mapping[str, Dataset], ctx: StepContext) -> list[Query]:
    """Query features from the ``query`` input and the matcher's ``queries`` parameter."""
    qds = inputs["query"]
    specs = [parse_query_spec(s) for s in getattr(matcher.params, "queries", [])]
    if "features" in qds.schema("data").names:
        return feature_queries(qds, specs, matcher.key())
    fds = features_dataset(inputs)
    if fds is None:
        raise PipelineError(f"{matcher.key()}: query motions need the database's feature set; give a 'features' input")
    fs = feature_set_of(fds, ctx.registries)
    return motion_queries(
        specs, qds.motions(), fs, ctx.registries, ctx.resolve, what=f"{matcher.key()}: query input {qds.step!r}"
    )


def feature_queries(qds: Dataset, specs: list[QuerySpec], what: str) -> list[Query]:
    """Queries cut from a features dataset (specs name clips by id; ranges in frames)."""
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


def run_matcher(matcher: Matcher, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
    """The default matcher step (see module doc)."""
    if type(matcher).match is Matcher.match:
        raise NotImplementedError(f"{matcher.key()} implements neither match(query, space) nor run()")
    space = search_space(matcher, inputs, ctx.registries)
    queries = step_queries(matcher, inputs, ctx)
    mode = str(getattr(matcher.params, "exclude_self", "off"))
    own = _database_clip_ids(inputs) if mode != "off" else {}
    excluded = [self_rows(space, own.get(q.clip_id, -1), q.start_frame, q.end_frame, mode) for q in queries]
    results: list[Any]
    if ctx.executor.workers > 1 and len(queries) > 1:
        # one task per query; each worker loads the search space once, with the run's registries
        refs = {slot: DatasetRef.of(ds) for slot, ds in inputs.items() if slot != "query"}
        task = partial(_match_task, matcher, refs, ctx.registries)
        results = ctx.map(task, [(q.features, ex) for q, ex in zip(queries, excluded, strict=True)], desc=ctx.step_id)
    else:
        results = []
        for q, ex in zip(ctx.progress(queries, total=len(queries)), excluded, strict=False):
            with excluding(ex):
                results.append(matcher.match(q.features, space))
    for qi, q in enumerate(queries):
        if not isinstance(results[qi], QueryMatches):
            raise PipelineError(f"{matcher.key()}.match returned {type(results[qi]).__name__}, not QueryMatches")
        results[qi] = drop_excluded(results[qi], excluded[qi])
        matcher.after_match(qi, q, results[qi], space, ctx)
    table = with_source_units(matches_table(list(range(len(queries))), results, space), inputs)
    return StepOutput(
        {"data": table, "queries": queries_table(queries)},
        {"queries": len(queries), "matches": int(sum(len(r) for r in results))},
    )


#: Columns :func:`with_source_units` appends to a step's match table.
SOURCE_UNIT_COLUMNS = ("source_fps", "source_start_frame", "source_end_frame", "start_s", "end_s")


def with_source_units(table: pa.Table, inputs: Mapping[str, Dataset]) -> pa.Table:
    """The match table (frames at the database rate, as the features) with each hit in its
    take's own units appended: ``source_fps``, ``source_start_frame``/``source_end_frame``
    (frames of the source file, half-open) and ``start_s``/``end_s`` (seconds from the take's
    start), by :func:`~.matching.in_source_units`; unchanged when the database's motions
    (with their source rates) cannot be found."""
    mds = upstream(features_dataset(inputs) or inputs["database"], "motions")
    if mds is None or not mds.has_table("clips") or "source_fps" not in mds.schema("clips").names:
        return table
    t = mds.table("clips", columns=["clip_id", "fps", "source_fps", "source_frames"]).to_pylist()
    rates = {int(r["clip_id"]): (r["fps"], r["source_fps"], r["source_frames"]) for r in t}
    if not set(table["clip_id"].to_pylist()) <= set(rates):
        return table
    conv = in_source_units(table.select(["clip_id", "start_frame", "end_frame"]), rates)
    for name, col in zip(SOURCE_UNIT_COLUMNS, ("fps", "start_frame", "end_frame", "start_s", "end_s"), strict=True):
        table = table.append_column(name, conv[col])
    return table


def _database_clip_ids(inputs: Mapping[str, Dataset]) -> dict[int, int]:
    """Query clip id -> the database clip of the same source file (by path), for the
    queries that lie inside the database (``exclude_self``)."""
    qds = inputs["query"]
    fds = features_dataset(inputs)
    mds = upstream(fds or inputs["database"], "motions")
    qclips = qds if qds.has_table("clips") else upstream(qds, "motions")
    if mds is None or qclips is None or not (mds.has_table("clips") and qclips.has_table("clips")):
        return {}
    db = mds.table("clips", columns=["clip_id", "path"]).to_pylist()
    by_path = {r["path"]: r["clip_id"] for r in db if r["path"]}
    out = {}
    for r in qclips.table("clips", columns=["clip_id", "path"]).to_pylist():
        if r["path"] in by_path:
            out[int(r["clip_id"])] = int(by_path[r["path"]])
    return out


def _match_task(
    matcher: Matcher,
    refs: dict[str, DatasetRef],
    registries: Registries,
    job: tuple[np.ndarray, tuple[int, int] | None],
) -> QueryMatches:
    """One query of :func:`run_matcher` on a worker (the search space loaded once per process)."""
    key = (
        "search-space",
        matcher.key(),
        json.dumps(matcher.get_params(), sort_keys=True),
        tuple(sorted((s, r.path, r.fingerprint) for s, r in refs.items())),
    )
    space = cached(key, lambda: search_space(matcher, {s: r.dataset() for s, r in refs.items()}, registries))
    features, excluded = job
    with excluding(excluded):
        result: QueryMatches = matcher.match(features, space)
    return result


def queries_table(queries: list[Query]) -> pa.Table:
    """:data:`~.schema.QUERIES` of each query (clip_id -1: a file)."""
    rows = [{"query_id": i, **{k: getattr(q, k) for k in schema.QUERIES.names[1:]}} for i, q in enumerate(queries)]
    return pa.Table.from_pylist(rows, schema=schema.QUERIES)
