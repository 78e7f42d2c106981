"""The base classes of every registry kind (scikit-learn's estimator contract).

``name`` is the registry key; parameters live in a frozen pydantic ``Params`` that
``__init__`` only validates and stores; fitted state ends in ``_``. A step gets finished
upstream :class:`~.datasets.Dataset` objects by input slot and returns a
:class:`~.datasets.StepOutput`; each kind has a default step (:mod:`.steps`). Planning
checks dataset kinds (``output_kind`` / ``input_kinds``; undeclared: not checked), nested
``ParamsOf`` parameters and :meth:`Component.check_plan`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, TypeVar

import numpy as np
from pydantic import ValidationError

from .cleaning import CleanedClip, clip_result
from .context import StepContext
from .database import MotionDatabase
from .datasets import Dataset, StepOutput
from .errors import ConfigError
from .matching import QueryMatches, SearchSpace, query_files_fingerprint
from .motion import Motion
from .params import Params as Params  # re-exported: components declare Params here
from .params import ParamsOf as ParamsOf
from .registry import Registries, params_error
from .workspace import atomic_path

#: The base of every ``Params`` (a name that the class attribute ``Component.Params`` does not hide).
ParamsModel = Params
#: a component class, for methods that return an instance of the caller's class
_C = TypeVar("_C", bound="Component")


class Component:
    """Base of all components. Subclasses set ``kind`` (via their kind base) and ``name``."""

    kind: ClassVar[str] = ""
    name: ClassVar[str] = ""
    #: Bump when the component's output changes for the same parameters; part of the
    #: step fingerprint, so outputs computed by an older version are recomputed.
    version: ClassVar[str] = "1"
    #: Input slots of the pipeline step: slot name -> required.
    inputs: ClassVar[Mapping[str, bool]] = {}
    #: Whether the component can be a pipeline step (has a ``run``).
    is_step: ClassVar[bool] = True
    #: Kind of dataset the step writes (``"motions"``, ``"features"``...); ``None``: unchecked.
    output_kind: ClassVar[str | None] = None
    #: Input slot -> dataset kinds it accepts; a slot not listed accepts any dataset.
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {}
    Params: ClassVar[type[Params]] = Params
    #: Parameters the conformance suite builds an instance with (for required ones).
    test_params: ClassVar[Mapping[str, Any] | None] = None

    def __init__(self, params: ParamsModel | Mapping[str, Any] | None = None, **kwargs: Any) -> None:
        if params is None or isinstance(params, Mapping):
            try:
                params = self.Params(**{**(params or {}), **kwargs})
            except ValidationError as exc:  # the component and parameter by name, not pydantic's dump
                raise ConfigError(params_error(self.key(), exc, self.Params)[1]) from None
        elif kwargs:
            params = params.model_copy(update=kwargs)
        elif not isinstance(params, self.Params):
            raise ConfigError(f"{self.key()}: expected {self.Params.__qualname__}, got {type(params).__name__}")
        self.params: ParamsModel = params

    @classmethod
    def key(cls) -> str:
        return f"{cls.kind}.{cls.name}"

    def get_params(self) -> dict[str, Any]:
        """Parameters as a plain dict (JSON-compatible)."""
        return self.params.model_dump(mode="json")

    def clone(self: _C, **changes: Any) -> _C:
        """An unfitted copy with some parameters changed."""
        return type(self)(self.params.model_copy(update=changes) if changes else self.params)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        """A step of the component's own (not overridden: its kind's default step runs)."""
        raise NotImplementedError(f"{self.key()} cannot run as a pipeline step")

    def check_plan(self, base_dir: Path) -> list[str]:
        """Plan-time checks beyond ``Params``: raise :class:`ConfigError` for what cannot run,
        return one-line warnings (a glob that matches no file). Cheap; writes nothing."""
        return []

    def source_fingerprint(self, base_dir: Path) -> str:
        """Digest of files the step reads (paths, sizes, mtimes), part of the step
        fingerprint so that an edited file recomputes the step. Default: none."""
        return ""

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


class Format(Component):
    """A file format: readers set ``extensions`` and implement :meth:`read` (raising
    :class:`~.errors.ParseError` with file and line); writers implement :meth:`write`."""

    kind = "formats"
    is_step = False
    #: Lower-case file extensions handled, with the dot (``(".bvh",)``).
    extensions: ClassVar[tuple[str, ...]] = ()
    #: What :meth:`read` returns: ``"motion"`` (skeletal) or ``"markers"``.
    produces: ClassVar[str] = "motion"

    def read(self, path: str | Path) -> Any:
        raise NotImplementedError(f"{self.key()} cannot read")

    def write(self, obj: Any, path: str | Path) -> None:
        raise NotImplementedError(f"{self.key()} cannot write")

    def write_atomic(self, obj: Any, path: str | Path) -> None:
        """:meth:`write` through :func:`~.workspace.atomic_path` (for files outside a step's folder)."""
        with atomic_path(path) as tmp:
            self.write(obj, tmp)

    @classmethod
    def can_write(cls) -> bool:
        return cls.write is not Format.write


class FeatureSet(Component):
    """Per-frame feature vectors: :meth:`transform_motion` (one clip -> ``(T, dim)`` float32)
    and :attr:`dim`; fitted ones (PCA) set ``requires_fit`` and implement :meth:`fit`,
    :meth:`save_state`, :meth:`load_state`. Frames are those of the input motions."""

    kind = "features"
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True, "reference": False}
    output_kind: ClassVar[str | None] = "features"
    #: ``reference``: motions to fit on, or a features dataset whose fitted model is reused
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "motions": ("motions",),
        "reference": ("motions", "features"),
    }
    requires_fit: ClassVar[bool] = False

    @property
    def dim(self) -> int:
        raise NotImplementedError

    def fit(self, data: MotionDatabase) -> FeatureSet:
        return self

    def transform_motion(self, motion: Motion) -> np.ndarray:
        raise NotImplementedError

    def transform(self, data: Motion | MotionDatabase) -> np.ndarray:
        """Features (n_frames, dim) float32 of one clip or a database, clip by clip."""
        if isinstance(data, Motion):
            return np.asarray(self.transform_motion(data), dtype=np.float32)
        parts = [np.asarray(self.transform_motion(m), dtype=np.float32) for m in data.motions]
        return np.concatenate(parts, axis=0) if parts else np.zeros((0, self.dim), np.float32)

    def save_state(self, directory: Path) -> None:
        """Persist fitted state (only for ``requires_fit``)."""

    def load_state(self, directory: Path) -> FeatureSet:
        return self


class Index(Component):
    """A nearest-neighbour index: ``query`` returns ``(dist, ids)`` (n_queries, k), Euclidean
    float32 ascending and int64 rows, padded with ``inf`` / ``-1`` (e.g. beyond ``radius``)."""

    kind = "indexes"
    inputs: ClassVar[Mapping[str, bool]] = {"features": True}
    output_kind: ClassVar[str | None] = "index"
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {"features": ("features",)}
    #: False for indexes that answer other queries than kNN (conformance skips kNN checks).
    supports_knn: ClassVar[bool] = True
    #: keywords ``query`` accepts beyond ``x, k, radius`` (e.g. ``{"eps", "workers"}``)
    query_options: ClassVar[frozenset[str]] = frozenset()
    #: keywords ``build`` accepts beyond ``features`` (e.g. ``{"groups", "frames"}``)
    build_options: ClassVar[frozenset[str]] = frozenset()
    #: keywords ``load`` accepts beyond ``directory`` (e.g. ``{"mmap_mode"}``)
    load_options: ClassVar[frozenset[str]] = frozenset()

    def build(self, features: np.ndarray) -> Index:
        raise NotImplementedError

    def query(self, x: np.ndarray, k: int, radius: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def save(self, directory: Path) -> None:
        raise NotImplementedError

    @classmethod
    def load(cls, directory: Path) -> Index:
        raise NotImplementedError


class Matcher(Component):
    """Matches queries against a database (tables with :data:`~.schema.MATCHES` columns).

    Segment matchers implement only :meth:`match` and set :attr:`needs_index` /
    :attr:`needs_features`; the default step (:func:`.queries.run_matcher`) builds the
    space and queries, runs each through :func:`.queries.match_query` and writes ``data``
    (the match table in users' units, :func:`.matching.in_source_units`) and ``queries``.
    Matchers with other inputs override :meth:`run` (a ``data`` table starting with
    :data:`~.schema.MATCHES` at the analysis rate is converted to users' units after it).
    """

    kind = "matchers"
    inputs: ClassVar[Mapping[str, bool]] = {"database": True, "query": True, "features": False}
    output_kind: ClassVar[str | None] = "matches"
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {
        "database": ("index", "features"),
        "query": ("motions", "features"),
        "features": ("features",),
        "motions": ("motions",),
    }
    #: The default step loads the ``database`` index (``SearchSpace.index``).
    needs_index: ClassVar[bool] = True
    #: The default step loads the database features (``SearchSpace.features``).
    needs_features: ClassVar[bool] = False
    #: A matcher with a step of its own: the pipeline the conformance suite runs it in.
    test_pipeline: ClassVar[Mapping[str, Any] | None] = None

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        """Ranked matches (best first, one warping path each) of one query's features
        float32 (m, d) in ``space``, none overlapping ``space.excluded`` (the query's own
        span: pass it to :func:`.matching.select_matches` as ``excluded``; the core drops any
        overlapping match anyway); bad input raises :class:`DataError`/:class:`ConfigError`."""
        raise NotImplementedError(f"{self.key()} does not implement match(query, space)")

    def uses_features(self) -> bool:
        """Whether the default step loads the database features (default :attr:`needs_features`)."""
        return self.needs_features

    def after_match(
        self, query_id: int, query: Any, matches: QueryMatches, space: SearchSpace, ctx: StepContext
    ) -> None:
        """Called by the default step after each query (plots); default: nothing."""

    def source_fingerprint(self, base_dir: Path) -> str:
        """Query files named in ``queries`` (path, size, mtime): an edited file recomputes the step."""
        return query_files_fingerprint(getattr(self.params, "queries", ()), base_dir)


class Cleaner(Component):
    """Detects (:meth:`detect`) and repairs (:meth:`repair`) capture errors per joint and
    frame; the default step (:func:`.steps.run_cleaner`) writes ``data``
    (:data:`~.schema.DIGRESSIONS`) and ``edits`` (:data:`~.schema.EDITS`). ``context``:
    None, a Motion, a list of Motions or a MotionDatabase."""

    kind = "cleaners"
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True, "context": False}
    output_kind: ClassVar[str | None] = "table"
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {"motions": ("motions",), "context": ("motions",)}

    def detect(self, motion: Motion, context: Any = None) -> np.ndarray:
        """Digression map (T, J) in [0, 1] (> 0.5: an error; joints not analysed: 0)."""
        raise NotImplementedError(f"{self.key()} cannot detect")

    def repair(self, motion: Motion, context: Any = None) -> tuple[Motion, Any]:
        """Cleaned motion (same skeleton, frames and rate) and its edits table
        (:data:`~.schema.EDITS`, :func:`.cleaning.edits_table`)."""
        raise NotImplementedError(f"{self.key()} cannot repair")

    def detect_and_repair(
        self,
        motion: Motion,
        context: Any,
        clip_id: int,
        out_dir: Path | None = None,
        registries: Registries | None = None,
    ) -> CleanedClip:
        """One clip of the default step: tables, cleaned motion, summary (files may go to
        ``out_dir``). Override to share one analysis between detection and repair."""
        value = self.detect(motion, context)
        cleaned, edits = self.repair(motion, context)
        return clip_result(motion, value, cleaned, edits, clip_id)


class Analysis(Component):
    """A step that fits no other kind; declare ``output_kind`` (usually ``"table"``)."""

    kind = "analyses"
