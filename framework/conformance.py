"""Conformance checks of matchers and cleaners (part of :mod:`mocapflow.framework.testing`).

Segment matchers run on a synthetic space served by :class:`ReferenceIndex` (defined here:
a third party needs no built-in plugin): valid matches, the query's own segment found,
determinism, clear errors. Matchers with their own step run their ``test_pipeline`` twice
through the runner; cleaners run on a synthetic clip (map, edits, tables, determinism).
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import pyarrow as pa

from . import schema
from .components import Analysis, Cleaner, Component, Index, Matcher
from .errors import DataError, MocapflowError

if TYPE_CHECKING:
    from .matching import SearchSpace


class ReferenceIndex(Index):
    """Exact kNN by brute force (float64 distances): the reference of the conformance suite."""

    name = "reference"

    def build(self, features: np.ndarray) -> ReferenceIndex:
        x = np.asarray(features, np.float32)
        if x.ndim != 2:
            raise DataError(f"features must be (n, dim), got {x.shape}")
        self.x_ = x
        return self

    def query(self, x: np.ndarray, k: int, radius: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        q = np.asarray(x, np.float64)
        if q.ndim != 2 or q.shape[1] != self.x_.shape[1]:
            raise DataError(f"queries must be (m, {self.x_.shape[1]}), got {q.shape}")
        if not np.isfinite(q).all():
            raise DataError("queries contain NaN or inf")
        d = np.sqrt(((q[:, None, :] - self.x_[None].astype(np.float64)) ** 2).sum(-1))
        order = np.argsort(d, axis=1, kind="stable")[:, :k]
        dist = np.take_along_axis(d, order, 1)
        ids = order.astype(np.int64)
        if radius is not None:
            ids = np.where(dist <= radius, ids, -1)
            dist = np.where(dist <= radius, dist, np.inf)
        pad = k - ids.shape[1]
        if pad > 0:
            ids = np.pad(ids, ((0, 0), (0, pad)), constant_values=-1)
            dist = np.pad(dist, ((0, 0), (0, pad)), constant_values=np.inf)
        return dist.astype(np.float32), ids

    def save(self, directory: Path) -> None:
        Path(directory).mkdir(parents=True, exist_ok=True)
        np.save(Path(directory) / "x.npy", self.x_)

    @classmethod
    def load(cls, directory: Path) -> ReferenceIndex:
        return cls().build(np.load(Path(directory) / "x.npy"))


#: Clip lengths (frames) of :func:`synthetic_space` and where its query comes from.
SPACE_CLIPS = (40, 25, 60)
QUERY_CLIP, QUERY_FRAMES = 2, (10, 30)


def synthetic_space(dim: int = 6, seed: int = 0, index: bool = True, features: bool = True) -> tuple[Any, np.ndarray]:
    """A small :class:`~.matching.SearchSpace` of smooth random feature tracks and a query.

    Three clips (:data:`SPACE_CLIPS` frames) of cumulative Gaussian steps in ``dim``
    dimensions; the query is frames :data:`QUERY_FRAMES` of clip :data:`QUERY_CLIP` with a
    little noise. ``index`` / ``features``: whether the space carries a
    :class:`ReferenceIndex` / the vectors.

    Returns
    -------
    space : SearchSpace
    query : ndarray of float32, shape (20, dim)
    """
    from .matching import SearchSpace

    rng = np.random.default_rng(seed)
    x = np.concatenate([np.cumsum(rng.normal(scale=0.3, size=(n, dim)), 0) for n in SPACE_CLIPS]).astype(np.float32)
    clip_id = np.repeat(np.arange(len(SPACE_CLIPS), dtype=np.int32), SPACE_CLIPS)
    frame = np.concatenate([np.arange(n, dtype=np.int32) for n in SPACE_CLIPS])
    a, b = QUERY_FRAMES
    rows = np.flatnonzero(clip_id == QUERY_CLIP)[a:b]
    query = (x[rows] + rng.normal(scale=0.01, size=(len(rows), dim))).astype(np.float32)
    space = SearchSpace(
        clip_id,
        frame,
        ReferenceIndex().build(x) if index else None,
        x if features else None,
        clip_names={i: f"clip{i}" for i in range(len(SPACE_CLIPS))},
    )
    return space, query


# --- matchers ---------------------------------------------------------------------------


def _raises_clear(fn: Any, what: str, who: str) -> None:
    try:
        fn()
    except MocapflowError:
        return
    except Exception as exc:  # the point of the check: anything but a MocapflowError fails it
        raise AssertionError(
            f"{who}: {what} raised {type(exc).__name__}: {exc} (expected a MocapflowError subclass)"
        ) from exc
    raise AssertionError(f"{who}: {what} raised nothing (expected a MocapflowError subclass)")


def _same(a: Any, b: Any, who: str) -> None:
    for f in ("start", "end", "cost", "length"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f"{who}: two runs differ in {f}")
    assert len(a.paths) == len(b.paths) and all(np.array_equal(p, q) for p, q in zip(a.paths, b.paths, strict=True)), (
        f"{who}: two runs differ in their warping paths"
    )


def rows_of_query(space: SearchSpace) -> tuple[int, int]:
    """Index rows (closed) of the synthetic query's own span in ``space``."""
    a, b = QUERY_FRAMES
    rows = np.flatnonzero(space.clip_id == QUERY_CLIP)[[a, b - 1]]
    return int(rows[0]), int(rows[1])


def check_matcher(cls: type[Component]) -> None:
    """``match(query, space)`` on a synthetic space: valid, found, deterministic, clear errors."""
    from .matching import QueryMatches, matches_table
    from .synthetic import _instance

    if not issubclass(cls, Matcher) or cls.match is Matcher.match:
        return
    inst = _instance(cls)
    if inst is None:
        return
    who = cls.key()
    space, query = synthetic_space()
    res = inst.match(query, space)
    assert isinstance(res, QueryMatches), f"{who}.match returned {type(res).__name__}, not QueryMatches"
    res.validate(space, who)
    assert len(res) >= 1, f"{who}: no match of a query cut from the database"
    assert np.all(np.isfinite(res.cost)), f"{who}: non-finite match costs"
    for r, p in enumerate(res.paths):
        p = np.asarray(p)
        assert p.ndim == 2 and p.shape[1] == 2, f"{who}: path {r} must be (n, 2) (query frame, row)"
        # starts at query frame 0 (a logical search's later rounds align other queries' frames)
        assert p[0, 0] == 0, f"{who}: path {r} does not start at the first query frame"
        assert p[0, 1] == res.start[r] and p[-1, 1] == res.end[r] - 1, (
            f"{who}: path {r} does not span rows [start, end)"
        )
        assert np.all(np.diff(p, axis=0) >= 0), f"{who}: path {r} is not monotone"
    table = matches_table([0], [res], space)
    head = pa.schema(list(table.schema)[: len(schema.MATCH_TABLE)])
    assert head.equals(schema.MATCH_TABLE), f"{who}: match table does not start with schema.MATCH_TABLE"
    # the query's own span excluded (SearchSpace.excluded): still valid matches (a matcher
    # should rank around it with select_matches(excluded=...); the core drops any overlap)
    ex = inst.match(query, space.excluding(rows_of_query(space)))
    assert isinstance(ex, QueryMatches), f"{who}.match returned {type(ex).__name__}, not QueryMatches"
    ex.validate(space, f"{who} (query span excluded)")
    a, b = QUERY_FRAMES
    rows = np.flatnonzero(space.clip_id == QUERY_CLIP)[[a, b - 1]]
    assert np.any((res.start <= rows[1]) & (res.end > rows[0])), (
        f"{who}: the query's own segment is not among its matches"
    )
    _same(res, inst.match(query.copy(), space), who)
    d = query.shape[1]
    _raises_clear(lambda: inst.match(np.zeros((0, d), np.float32), space), "an empty query", who)
    _raises_clear(lambda: inst.match(np.zeros((5, d + 1), np.float32), space), "a query of the wrong dimension", who)
    bad = query.copy()
    bad[3, 1] = np.nan
    _raises_clear(lambda: inst.match(bad, space), "a query with NaN", who)
    # a space lacking the index or the features: a clear error, or valid matches (a setting may not need it)
    for what, sp in (
        ("a space without an index", synthetic_space(index=False)[0]),
        ("a space without features", synthetic_space(features=False)[0]),
    ):
        try:
            got = inst.match(query, sp)
        except MocapflowError:
            continue
        except Exception as exc:
            raise AssertionError(
                f"{who}: {what} raised {type(exc).__name__}: {exc} (expected a MocapflowError subclass)"
            ) from exc
        assert isinstance(got, QueryMatches), f"{who}: {what} gave {type(got).__name__}"
        got.validate(sp, f"{who} ({what})")


class SyntheticMotions(Analysis):
    """Synthetic clips (:func:`~.synthetic.synthetic_motion`) as a motions dataset, for pipelines in tests."""

    name = "conformance_motions"
    inputs: ClassVar[Mapping[str, bool]] = {}
    output_kind: ClassVar[str | None] = "motions"

    def run(self, inputs: Mapping[str, Any], ctx: Any) -> Any:
        from .datasets import StepOutput
        from .motion_tables import motions_to_tables
        from .synthetic import synthetic_motion

        clips = [synthetic_motion(n, seed=s) for s, n in enumerate((90, 60, 90, 75))]
        return StepOutput(motions_to_tables(clips), {"clips": len(clips)})


class _Plugin:
    """Registers :class:`SyntheticMotions` and the component under test (if not registered yet)."""

    def __init__(self, extra: dict[str, list[type]]) -> None:
        from .plugins import hookimpl

        for kind, classes in extra.items():
            # pluggy takes the hook name from the attribute; one function per kind
            setattr(self, f"register_{kind}", hookimpl(lambda classes=classes: list(classes)))


def run_test_pipeline(
    cls: type[Component], spec: Mapping[str, Any], workspace: Path, inputs: Mapping[str, str] | None = None
) -> Any:
    """Run ``spec`` and return the tested step's dataset.

    ``spec``: ``steps`` (upstream steps, pipeline syntax), ``inputs`` / ``with`` (the tested
    step's), optionally ``plugins`` (plugin objects registering the other components the
    steps use; built-ins are always there, entry points are not loaded). A ``motions`` step
    of :class:`SyntheticMotions` (clips ``synthetic0`` .. ``synthetic3``) is provided; the
    tested class is registered if no plugin registers it.
    """
    import yaml

    from .datasets import Dataset
    from .plugins import build_registries, get_plugin_manager
    from .runner import run_pipeline

    plugins = list(spec.get("plugins", ()))  # the tested package's plugin module(s), for its other components
    base = build_registries(get_plugin_manager(entry_points=False, extra=plugins))
    extra: dict[str, list[type]] = {"analyses": [SyntheticMotions]}
    if cls.name not in base[cls.kind]:
        extra.setdefault(cls.kind, []).append(cls)
    pm = get_plugin_manager(entry_points=False, extra=[*plugins, _Plugin(extra)])
    steps = {
        "motions": {"uses": SyntheticMotions.key()},
        **spec.get("steps", {}),
        "tested": {"uses": cls.key(), "inputs": dict(inputs or spec["inputs"]), "with": dict(spec.get("with", {}))},
    }
    workspace.mkdir(parents=True, exist_ok=True)
    path = workspace / "pipeline.yaml"
    path.write_text(yaml.safe_dump({"name": "conformance", "workspace": "ws", "steps": steps}, sort_keys=False))
    run_pipeline(path, pm=pm, jobs=1)
    return Dataset(workspace / "ws" / "tested")


def check_matcher_pipeline(cls: type[Component]) -> None:
    """A matcher with its own step and a ``test_pipeline``: equal tables over two runs, the
    shared match columns first, a clear error for ``bad_inputs``."""
    if not issubclass(cls, Matcher) or cls.test_pipeline is None:
        return
    spec = cls.test_pipeline
    who = cls.key()
    with tempfile.TemporaryDirectory() as tmp:
        one = run_test_pipeline(cls, spec, Path(tmp) / "one")
        two = run_test_pipeline(cls, spec, Path(tmp) / "two")
        t1, t2 = one.table("data"), two.table("data")
        assert t1.num_rows >= 1, f"{who}: no match on the synthetic pipeline"
        head = pa.schema(list(t1.schema)[: len(schema.MATCHES)])
        assert head.equals(schema.MATCHES), f"{who}: the match table does not start with schema.MATCHES ({t1.schema})"
        assert t1.equals(t2), f"{who}: two runs of the synthetic pipeline differ"
        if spec.get("bad_inputs"):
            _raises_clear(
                lambda: run_test_pipeline(cls, spec, Path(tmp) / "bad", spec["bad_inputs"]),
                f"inputs {spec['bad_inputs']}",
                who,
            )


# --- cleaners ---------------------------------------------------------------------------


def check_cleaner(cls: type[Component]) -> None:
    """detect / repair / detect_and_repair on a synthetic clip: shapes, schemas, determinism, clear errors."""
    from .cleaning import CleanedClip
    from .motion import Motion
    from .synthetic import _instance, synthetic_motion

    if not issubclass(cls, Cleaner) or cls.detect is Cleaner.detect:
        return
    inst = _instance(cls)
    if inst is None:
        return
    who = cls.key()
    m = synthetic_motion(72, fps=24.0, seed=5)
    value = np.asarray(inst.detect(m))
    assert value.shape == (m.n_frames, m.n_joints), (
        f"{who}.detect: shape {value.shape}, expected {(m.n_frames, m.n_joints)}"
    )
    assert np.all(np.isfinite(value)) and value.min() >= 0 and value.max() <= 1, f"{who}.detect: values outside [0, 1]"
    np.testing.assert_array_equal(value, inst.detect(m), err_msg=f"{who}.detect: two runs differ")
    cleaned, edits = inst.repair(m)
    assert isinstance(cleaned, Motion) and cleaned.rotations.shape == m.rotations.shape, (
        f"{who}.repair: not a Motion like its input"
    )
    assert isinstance(edits, pa.Table) and edits.schema.equals(schema.EDITS), (
        f"{who}.repair: edits schema {edits.schema}"
    )
    f, j = edits["frame"].to_numpy(), edits["joint"].to_numpy()
    np.testing.assert_allclose(
        schema.fixed_list_to_numpy(edits["old_rotation"], np.float64),
        m.rotations[f, j],
        err_msg=f"{who}.repair: old_rotation is not the input's",
    )
    untouched = np.ones(m.rotations.shape[:2], bool)
    untouched[f, j] = False
    np.testing.assert_array_equal(
        cleaned.rotations[untouched],
        m.rotations[untouched],
        err_msg=f"{who}.repair: a cell changed that has no edits row",
    )
    again, edits2 = inst.repair(m)
    assert edits.equals(edits2) and np.array_equal(again.rotations, cleaned.rotations), f"{who}.repair: two runs differ"
    out = inst.detect_and_repair(m, None, 7, None)
    assert isinstance(out, CleanedClip), f"{who}.detect_and_repair returned {type(out).__name__}, not CleanedClip"
    assert out.digressions.schema.equals(schema.DIGRESSIONS), f"{who}: digression table schema {out.digressions.schema}"
    assert out.edits.schema.equals(schema.EDITS), f"{who}: step edits schema {out.edits.schema}"
    assert set(out.digressions["clip_id"].to_pylist()) <= {7} and set(out.edits["clip_id"].to_pylist()) <= {7}
    import json

    json.dumps(out.summary)  # the summary goes into the provenance
    _raises_clear(lambda: inst.detect(m, context="not a motion"), "a context that is not motions", who)
    short = synthetic_motion(3, fps=24.0)
    try:  # shorter than any analysis window: a clear error, or a valid (all but empty) map
        v = np.asarray(inst.detect(short))
    except MocapflowError:
        pass
    except Exception as exc:
        raise AssertionError(f"{who}: a clip of 3 frames raised {type(exc).__name__}: {exc}") from exc
    else:
        assert v.shape == (3, short.n_joints) and np.all((v >= 0) & (v <= 1)), (
            f"{who}.detect: bad map of a 3-frame clip"
        )
    bad = m.with_arrays(rotations=np.where(np.arange(m.n_frames)[:, None, None] == 10, np.nan, m.rotations))
    _raises_clear(lambda: inst.detect(bad), "a clip with NaN rotations", who)
