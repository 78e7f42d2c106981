"""What a component is: the base classes of every registry kind.

A component follows scikit-learn's estimator contract, validated by pydantic:

* ``name`` (class attribute, snake_case) is its key in its kind's registry;
* parameters are declared once, in a nested frozen pydantic model ``Params`` (unknown
  keys rejected); ``__init__`` only validates and stores them (no other logic);
* fitted state lives in attributes ending in ``_``;
* a pipeline step receives finished upstream :class:`~mocapflow.framework.datasets.Dataset`
  objects keyed by input slot and returns a :class:`~mocapflow.framework.datasets.StepOutput`
  (tables plus files written into ``ctx.out_dir``); ``inputs`` (class attribute) declares the
  slots, slot -> required. Feature sets, indexes, matchers and cleaners get the default step
  of their kind (:mod:`.steps`) from the methods below; a component overrides ``run`` for a
  step of its own.

What is checked when a pipeline is planned, beyond ``Params``:

* dataset kinds: a step declares the kind of dataset it writes (``output_kind``: one of
  :data:`DATASET_KINDS` or a plugin's own word) and, per input slot, the kinds it accepts
  (``input_kinds``); an index over a summary table is refused before anything runs. The
  kind bases declare the usual ones; a kind left undeclared (``None`` / slot not listed)
  is not checked.
* nested parameters: a ``dict`` parameter annotated ``Annotated[dict[str, Any],
  ParamsOf("kind.name")]`` holds another component's parameters and is validated against
  that component's ``Params`` (errors name the nested key, with "did you mean").
* :meth:`Component.check_plan`: anything else a component can tell from its parameters
  and the pipeline's folder (a glob that matches no file is a warning).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .cleaning import CleanedClip, clip_result
from .context import StepContext
from .database import MotionDatabase
from .datasets import Dataset, StepOutput
from .errors import ConfigError
from .matching import QueryMatches, SearchSpace, query_files_fingerprint
from .motion import Motion
from .params import Params as Params  # re-exported: components declare Params here
from .params import ParamsOf as ParamsOf
from .registry import Registries
from .workspace import atomic_path

#: The base of every ``Params`` (a name that the class attribute ``Component.Params`` does not hide).
ParamsModel = Params

#: Dataset kinds the built-in kind bases declare (``output_kind`` / ``input_kinds``).
DATASET_KINDS: tuple[str, ...] = ("motions", "markers", "features", "index", "matches", "table")


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
    #: Kind of dataset the step writes (``"motions"``, ``"features"``, ``"index"``...; see
    #: :data:`DATASET_KINDS`); ``None``: not declared, consumers do not check it.
    output_kind: ClassVar[str | None] = None
    #: Input slot -> dataset kinds it accepts; a slot not listed accepts any dataset.
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {}
    Params: ClassVar[type[Params]] = Params
    #: Parameters the conformance suite builds an instance with (for required ones).
    test_params: ClassVar[Mapping[str, Any] | None] = None

    def __init__(self, params: ParamsModel | Mapping[str, Any] | None = None, **kwargs: Any) -> None:
        if params is None:
            params = self.Params(**kwargs)
        elif isinstance(params, Mapping):
            params = self.Params(**{**params, **kwargs})
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

    def clone(self, **changes: Any) -> Component:
        """An unfitted copy with some parameters changed."""
        return type(self)(self.params.model_copy(update=changes) if changes else self.params)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        """A step of the component's own: its output from finished input datasets. Not
        overridden: the default step of its kind runs (:func:`.steps.run_step`)."""
        raise NotImplementedError(f"{self.key()} cannot run as a pipeline step")

    def check_plan(self, base_dir: Path) -> list[str]:
        """Plan-time checks beyond ``Params`` (called once per step when a pipeline is planned).

        Raise :class:`ConfigError` for what cannot run; return warnings (one line each,
        e.g. a glob that matches no file) that the plan reports at the step's line. Must be
        cheap and must not write anything. Default: nothing to check.
        """
        return []

    def source_fingerprint(self, base_dir: Path) -> str:
        """Digest of external inputs the step reads (files named in its parameters).

        Part of the step fingerprint: a step that reads files returns something that
        changes when they change (e.g. paths, sizes and modification times), so that an
        edited file recomputes the step. Default: no external inputs.
        """
        return ""

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


class Format(Component):
    """A file format (reader and/or writer), or an ingest/export step.

    Readers set ``extensions`` and implement :meth:`read`; writers implement
    :meth:`write`. Readers raise :class:`~mocapflow.framework.errors.ParseError` naming the
    file, line and what was expected.
    """

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
        """:meth:`write` through a temporary file renamed into place
        (:func:`~.workspace.atomic_path`): never half a file at ``path``, and a failed write
        leaves the previous one intact. Writers implement :meth:`write`; callers that write
        outside a step's output folder (which is committed atomically anyway) use this."""
        with atomic_path(path) as tmp:
            self.write(obj, tmp)

    @classmethod
    def can_write(cls) -> bool:
        return cls.write is not Format.write


class FeatureSet(Component):
    """Per-frame feature vectors of motions.

    Subclasses implement :meth:`transform_motion` (one clip -> ``(T, dim)`` float32) and
    :attr:`dim`. Feature sets that must be fitted (PCA) set ``requires_fit`` and implement
    :meth:`fit`, :meth:`save_state` and :meth:`load_state`. Frame ids of the output refer to
    the frames of the input motions dataset (resample at ingest, ``formats.load`` ``fps``).
    """

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
        """Features of one clip or of every frame of a database, shape (n_frames, dim), float32.

        Computed clip by clip, so windows never straddle two clips.
        """
        if isinstance(data, Motion):
            return np.asarray(self.transform_motion(data), dtype=np.float32)
        parts = [np.asarray(self.transform_motion(m), dtype=np.float32) for m in data.motions]
        return np.concatenate(parts, axis=0) if parts else np.zeros((0, self.dim), np.float32)

    def save_state(self, directory: Path) -> None:
        """Persist fitted state (only for ``requires_fit``)."""

    def load_state(self, directory: Path) -> FeatureSet:
        return self


class Index(Component):
    """A nearest-neighbour index over feature vectors.

    ``query`` returns ``(dist, ids)``, each of shape (n_queries, k): Euclidean distances
    (float32, ascending) and row ids into the indexed feature matrix (int64), padded with
    ``inf`` / ``-1`` where fewer than ``k`` neighbours exist (e.g. within ``radius``).
    """

    kind = "indexes"
    inputs: ClassVar[Mapping[str, bool]] = {"features": True}
    output_kind: ClassVar[str | None] = "index"
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {"features": ("features",)}
    #: False for indexes that answer other queries than numeric kNN (inverted lists);
    #: the conformance suite then skips the kNN checks.
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
    """Matches queries against a database; writes tables with :data:`~.schema.MATCHES` columns.

    A matcher that aligns whole query segments implements only :meth:`match` (one query's
    features against a :class:`~.matching.SearchSpace`, returning ranked
    :class:`~.matching.QueryMatches`) and sets :attr:`needs_index` / :attr:`needs_features`;
    the default step (:func:`.queries.run_matcher`) does the rest: the search space
    from ``database`` (an index dataset, or features when no index is needed), the queries
    from ``query`` and the ``queries`` parameter (:class:`~.matching.MatchParams`), the
    ``data`` table (:data:`~.schema.MATCH_TABLE`) and the ``queries`` table
    (:data:`~.schema.QUERIES`). Matchers with other inputs (inverted lists, templates)
    override :meth:`run` and write :data:`~.schema.MATCHES` plus their own columns.
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
    #: A matcher with a step of its own: the pipeline the conformance suite runs it in
    #: (:func:`~.conformance.check_matcher_pipeline`).
    test_pipeline: ClassVar[Mapping[str, Any] | None] = None

    def match(self, query: np.ndarray, space: SearchSpace) -> QueryMatches:
        """Ranked matches of one query.

        Parameters
        ----------
        query : ndarray of float32, shape (m, d)
            Query features, in the database's feature space (``m >= 1``).
        space : SearchSpace
            The searched rows (:class:`~.matching.SearchSpace`).

        Returns
        -------
        QueryMatches
            Best first, rows ``[start, end)`` of ``space``, one warping path per match.
            Bad input (wrong dimension, NaN, no index where one is needed) raises a
            :class:`~.errors.DataError` or :class:`~.errors.ConfigError`.
        """
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
    """Detects (:meth:`detect`) and repairs (:meth:`repair`) capture errors per joint and frame.

    A cleaner implements :meth:`detect` and :meth:`repair`; the default step
    (:func:`.steps.run_cleaner`) cleans every clip of ``motions`` against the optional
    ``context`` clips through :meth:`detect_and_repair` and writes ``data``
    (:data:`~.schema.DIGRESSIONS`) and ``edits`` (:data:`~.schema.EDITS`). A cleaner whose
    detection and repair share one analysis overrides :meth:`detect_and_repair` to run it once.
    ``context`` is None, a Motion, a list of Motions or a MotionDatabase.
    """

    kind = "cleaners"
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True, "context": False}
    output_kind: ClassVar[str | None] = "table"
    input_kinds: ClassVar[Mapping[str, tuple[str, ...]]] = {"motions": ("motions",), "context": ("motions",)}

    def detect(self, motion: Motion, context: Any = None) -> np.ndarray:
        """Digression map at the input frames, shape (T, J) in [0, 1] (> 0.5: an error).

        ``J`` is the skeleton's joint count; joints the cleaner does not analyse are 0.
        Bad input (a context of the wrong type, a clip too short) raises
        :class:`~.errors.DataError`.
        """
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
        """One clip of the default step (:func:`.steps.run_cleaner`): its tables, cleaned
        motion and JSON summary. Files may be written into ``out_dir`` (other components,
        e.g. a format, resolved through ``registries``: the run's). Default: :meth:`detect`,
        then :meth:`repair` (:func:`.cleaning.clip_result`)."""
        value = self.detect(motion, context)
        cleaned, edits = self.repair(motion, context)
        return clip_result(motion, value, cleaned, edits, clip_id)


class Analysis(Component):
    """A step that fits none of the other kinds (studies, reconstruction, evaluation).

    Analyses are too varied for a default ``output_kind``: declare it (usually
    ``"table"``; ``"motions"`` for a step that writes clips) so that consumers are checked.
    """

    kind = "analyses"
