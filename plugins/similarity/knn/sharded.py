"""``indexes.sharded``: an exact kNN index split by clip ranges into shards, queried exactly.

Rows are cut at clip boundaries into ``shards`` ranges (or as many as ``max_rows`` needs);
each is an ordinary index (``indexes.kdtree`` by default), saved as ``index/shard-000/`` ....
A query merges every shard's ``k`` best; ties break as in the unsharded kd-tree (squared
float64 distance in its summation order, then row id), so the result equals one index.
With an executor of several workers a batch fans out by ``fan_out`` (measured:
docs/knn.md, docs/scale-out.md): ``queries`` sends blocks of queries to workers that each
hold the whole index (loaded once per process, memory-mapped); ``shards`` sends each shard
all queries (for shards larger than one worker's memory).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal, cast

import numpy as np
from pydantic import Field

from mocapflow.framework import Index
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.errors import ConfigError, DataError

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework import Dataset, StepContext, StepOutput

_META = "shards.json"


def shard_bounds(groups: np.ndarray, n_shards: int, max_rows: int | None = None) -> np.ndarray:
    """Row offsets ``(S + 1,)`` of contiguous shards cut only where ``groups`` (clip ids) change.

    ``n_shards`` ranges of about equal rows (each cut at the clip start nearest to its ideal
    place); with ``max_rows``, shards are filled clip by clip up to ``max_rows`` rows (a clip
    longer than that is a shard of its own), if that gives more shards. Empty shards are dropped.
    """
    n = len(groups)
    if n == 0:
        return np.zeros(1, np.int64)
    starts = np.concatenate([[0], np.flatnonzero(np.diff(groups)) + 1, [n]]).astype(np.int64)
    s = max(1, int(n_shards))
    want = n * np.arange(1, s) / s
    right = np.clip(np.searchsorted(starts, want, side="left"), 1, len(starts) - 1)
    nearest = np.where(starts[right] - want <= want - starts[right - 1], starts[right], starts[right - 1])
    even = np.unique(np.concatenate([[0], nearest, [n]])).astype(np.int64)
    if not max_rows:
        return even
    cuts, first = [0], 0
    for c in starts[1:]:
        if c - first > max_rows and c != starts[np.searchsorted(starts, first) + 1]:
            first = int(starts[np.searchsorted(starts, c) - 1])
            cuts.append(first)
    filled = np.unique(np.concatenate([cuts, [n]])).astype(np.int64)
    return filled if len(filled) > len(even) else even


def _registries(registries: Any) -> Any:
    """``registries``, or outside a run (an index built or loaded from Python) the facade's."""
    if registries is not None:
        return registries
    import mocapflow

    return mocapflow.registries()


def _import_class(path: str) -> type:
    """The class saved as ``module:qualname`` (the shard index of a saved sharded index)."""
    import importlib

    module, _, name = path.partition(":")
    return cast("type", getattr(importlib.import_module(module), name))


def _load_shard(cls: Any, directory: Path) -> Index:
    """``cls.load`` memory-mapped where the index supports it (``mmap_mode``)."""
    if "mmap_mode" in getattr(cls, "load_options", ()):
        return cast("Index", cls.load(directory, mmap_mode="r"))
    return cast("Index", cls.load(directory))


def _exact_sqdist(q: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Squared distances ``(m, c)`` of queries ``(m, d)`` to their candidates ``(m, c, d)``,
    float64, summed dimension by dimension like the kd-tree's kernel (bit-identical sums)."""
    acc = np.zeros(y.shape[:2])
    for j in range(q.shape[1]):
        diff = y[:, :, j].astype(np.float64) - q[:, None, j].astype(np.float64)
        acc += diff * diff
    return acc


@dataclass(frozen=True)
class _ShardQuery:
    """One shard's answer to a batch of queries, on a worker (the shard loaded once there)."""

    directory: str
    index_cls: type[Index]
    stamp: str
    k: int
    radius: float | None
    kwargs: dict[str, Any]

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        from mocapflow.framework.clip_refs import cached

        def load() -> Index:
            return _load_shard(self.index_cls, Path(self.directory))

        shard = cached(("index-shard", self.directory, self.stamp), load)
        return shard.query(q, self.k, self.radius, **self.kwargs)


class ShardedIndex(Index):
    """Exact kNN over clip-range shards, each an ordinary index (see the module doc).

    Contract (:class:`~mocapflow.framework.Index`) as ``indexes.kdtree``: ``build(features,
    *, groups=None, frames=None)``, ``query(x, k, radius=None, *, eps=0.0, exclude=None,
    query_groups=None, query_frames=None, executor=None)``, ``query_rows``, ``save``/``load``.

    Attributes
    ----------
    offsets_ : ndarray of int64, shape (n_shards + 1,)
        First row of each shard; shard ``s`` holds rows ``offsets_[s]:offsets_[s+1]``.
    shards_ : list of Index
    method_ : str
        The shards' methods, e.g. ``"sharded: kdtree, kdtree"``.
    """

    name: ClassVar[str] = "sharded"
    query_options: ClassVar[frozenset[str]] = frozenset({"eps", "exclude", "query_groups", "query_frames", "executor"})
    build_options: ClassVar[frozenset[str]] = frozenset({"groups", "frames"})

    class Params(BaseParams):
        shards: int = Field(2, ge=1, description="number of shards (clip ranges of about equal rows)")
        max_rows: int | None = Field(
            None, ge=1, description="at most this many rows per shard (memory budget): more shards if needed"
        )
        index: str = Field("kdtree", description="the index each shard is (registry name in `indexes`)")
        index_params: dict[str, Any] = Field(default_factory=dict, description="parameters of the shard index")
        fan_out: Literal["queries", "shards"] = Field(
            "queries",
            description="with an executor of several workers: split a batch of queries between workers "
            "(each worker asks every shard, loaded once per process) or send each shard all the queries",
        )

    params: Params

    # --- building ---------------------------------------------------------------------
    def _shard_class(self, registries: Any = None) -> type:
        key = self.params.index if "." in self.params.index else f"indexes.{self.params.index}"
        if key == self.key():
            raise ConfigError(f"{self.key()}: a shard cannot itself be sharded")
        return cast("type", _registries(registries).resolve(key))

    def build(
        self,
        features: np.ndarray,
        *,
        groups: np.ndarray | None = None,
        frames: np.ndarray | None = None,
        registries: Any = None,
    ) -> ShardedIndex:
        """Index ``features`` (n, d) in shards; ``groups`` (clip ids) decide where shards may be cut."""
        x = np.asarray(features)
        if x.ndim != 2:
            raise DataError(f"{self.key()}: features must be (n, d), got shape {x.shape}")
        n = x.shape[0]
        g = np.zeros(n, np.int32) if groups is None else np.asarray(groups)
        f = np.arange(n, dtype=np.int32) if frames is None else np.asarray(frames)
        cls = self._shard_class(registries)
        self.offsets_ = shard_bounds(
            g if groups is not None else np.arange(n), self.params.shards, self.params.max_rows
        )
        self.shards_ = [
            self._build_one(cls, x[a:b], g[a:b], f[a:b])
            for a, b in zip(self.offsets_[:-1], self.offsets_[1:], strict=True)
        ]
        self._finish(cls, x.shape[1])
        return self

    def _build_one(self, cls: Any, x: np.ndarray, g: np.ndarray, f: np.ndarray) -> Index:
        shard = cls(self.params.index_params)
        if "groups" in shard.build_options:
            return cast("Index", shard.build(x, groups=g, frames=f))
        return cast("Index", shard.build(x))

    #: the saved index's modification stamp (set by load): a process answering from the folder
    #: checks it reads the same index
    _stamp: str

    def _finish(self, cls: type[Index], dim: int) -> None:
        self.shard_key_ = cls.key()
        self.shard_cls_ = cls
        self.dim_ = int(dim)
        self.method_ = "sharded: " + ", ".join(str(getattr(s, "method_", cls.name)) for s in self.shards_)
        self.directory_: Path | None = None
        self._executor = None
        self._inv: dict[int, np.ndarray] = {}

    def attach(self, executor: Any) -> ShardedIndex:
        """Answer batched queries shard by shard on ``executor`` (needs a saved or loaded index)."""
        self._executor = executor
        return self

    # --- querying ---------------------------------------------------------------------
    def _check_built(self) -> None:
        if not hasattr(self, "shards_"):
            raise DataError(f"{self.key()}: index not built (call build() or load())")

    def query(
        self,
        x: np.ndarray,
        k: int,
        radius: float | None = None,
        *,
        eps: float = 0.0,
        exclude: int | None = None,
        query_groups: np.ndarray | None = None,
        query_frames: np.ndarray | None = None,
        executor: Any = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest rows over all shards (see :meth:`.KDTreeIndex.query`).

        Returns
        -------
        dist : ndarray of shape (m, k), float32, ascending
        ids : ndarray of shape (m, k), int64, global rows (-1 = none)
        """
        self._check_built()
        q = np.asarray(x, dtype=np.float32)
        q = q[None, :] if q.ndim == 1 else q
        if q.ndim != 2 or q.shape[1] != self.dim_:
            raise DataError(f"{self.key()}: queries must be (m, {self.dim_}), got shape {np.shape(x)}")
        if int(k) < 1:
            raise ConfigError(f"{self.key()}: k must be >= 1, got {k}")
        q = np.ascontiguousarray(q)
        kw: dict[str, Any] = {}
        if eps:
            kw["eps"] = float(eps)
        if exclude is not None:
            if query_groups is None or query_frames is None:
                raise ConfigError(f"{self.key()}: exclude=N needs query_groups and query_frames")
            kw.update(
                exclude=int(exclude),
                query_groups=np.broadcast_to(np.asarray(query_groups, np.int64), (len(q),)),
                query_frames=np.broadcast_to(np.asarray(query_frames, np.int64), (len(q),)),
            )
        ex = executor if executor is not None else self._executor
        workers = int(getattr(ex, "workers", 1)) if ex is not None else 1
        if workers > 1 and self.directory_ is not None and self.params.fan_out == "queries" and len(q) > 1:
            return self._query_blocks(ex, workers, q, int(k), radius, kw)
        if ex is not None and workers > 1 and self.directory_ is not None and len(self.shards_) > 1:
            tasks = [
                _ShardQuery(str(self.directory_ / f"shard-{s:03d}"), self.shard_cls_, self._stamp, int(k), radius, kw)
                for s in range(len(self.shards_))
            ]
            answers = ex.map(_Apply(q), tasks, desc=f"{self.key()}: shards")
        else:
            answers = [s.query(q, int(k), radius, **kw) for s in self.shards_]
        return self._merge(q, int(k), answers)

    def _query_blocks(
        self, ex: Any, workers: int, q: np.ndarray, k: int, radius: float | None, kw: dict[str, Any]
    ) -> tuple[np.ndarray, np.ndarray]:
        """``fan_out: queries``: contiguous blocks of the queries (2 per worker, so that a
        slow block does not finish alone), each answered by every shard and merged on the
        worker that holds the whole sharded index (loaded once per process)."""
        n_blocks = min(len(q), 2 * workers)
        cuts = np.linspace(0, len(q), n_blocks + 1).astype(np.int64)
        blocks = []
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            part = {key: (v[a:b] if isinstance(v, np.ndarray) else v) for key, v in kw.items()}
            blocks.append(_BlockQuery(str(self.directory_), self._stamp, k, radius, q[a:b], part))
        answers = ex.map(_answer_block, blocks, desc=f"{self.key()}: query blocks")
        return np.concatenate([d for d, _ in answers]), np.concatenate([i for _, i in answers])

    def _merge(
        self, q: np.ndarray, k: int, answers: list[tuple[np.ndarray, np.ndarray]]
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` best of the shards' answers, by blocks of queries (bounded memory)."""
        width = sum(np.shape(i)[1] for _, i in answers)
        step = max(1, (1 << 22) // max(1, width * self.dim_))
        parts = [
            self._merge_block(q[a : a + step], k, [(d[a : a + step], i[a : a + step]) for d, i in answers])
            for a in range(0, len(q), step)
        ]
        if not parts:
            return np.full((0, k), np.inf, np.float32), np.full((0, k), -1, np.int64)
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    def _merge_block(
        self, q: np.ndarray, k: int, answers: list[tuple[np.ndarray, np.ndarray]]
    ) -> tuple[np.ndarray, np.ndarray]:
        dist = np.concatenate([np.asarray(d, np.float32) for d, _ in answers], axis=1)
        ids = np.concatenate(
            [
                np.where(np.asarray(i) >= 0, np.asarray(i, np.int64) + off, -1)
                for (_, i), off in zip(answers, self.offsets_[:-1], strict=True)
            ],
            axis=1,
        )
        valid = ids >= 0
        key = np.where(valid, dist.astype(np.float64), np.inf)
        rows = self._rows(np.maximum(ids, 0))
        if rows is not None:  # the kd-tree's own order: squared float64 distance, then row id
            key = np.where(valid, _exact_sqdist(q, rows), np.inf)
        order = np.lexsort((np.where(valid, ids, np.iinfo(np.int64).max), key), axis=1)[:, :k]
        d = np.take_along_axis(dist, order, 1)
        i = np.take_along_axis(ids, order, 1)
        d[i < 0] = np.inf
        if d.shape[1] < k:  # fewer candidates than k over all shards
            pad = k - d.shape[1]
            d = np.pad(d, ((0, 0), (0, pad)), constant_values=np.inf)
            i = np.pad(i, ((0, 0), (0, pad)), constant_values=-1)
        return d, i

    def _locate(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = np.searchsorted(self.offsets_, rows, side="right") - 1
        return s, rows - self.offsets_[s]

    def _rows(self, ids: np.ndarray) -> np.ndarray | None:
        """Feature vectors of global rows ``ids`` (any shape) from the shards' stored
        points (``data_`` in tree order, ``perm_``), or None for indexes without them."""
        if not all(hasattr(s, "data_") and hasattr(s, "perm_") for s in self.shards_):
            return None
        flat = ids.reshape(-1)
        out = np.empty((len(flat), self.dim_), np.float32)
        s, local = self._locate(flat)
        for j in np.unique(s):
            sel = s == j
            out[sel] = self.shards_[j].data_[self._inverse(j)[local[sel]]]
        return out.reshape(ids.shape + (self.dim_,))

    def _inverse(self, j: int) -> np.ndarray:
        inv = self._inv.get(j)
        if inv is None:
            shard: Any = self.shards_[j]  # a kd-tree shard (checked above)
            perm = shard.perm_
            inv = np.empty_like(perm)
            inv[perm] = np.arange(len(perm))
            self._inv[j] = inv
        return inv

    def query_rows(
        self, rows: np.ndarray, k: int, radius: float | None = None, *, eps: float = 0.0, exclude: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Query with indexed rows (global ids), excluding their own clip within ±``exclude`` frames."""
        self._check_built()
        rows = np.asarray(rows, np.int64)
        x = self._rows(rows)
        if x is None:
            raise ConfigError(f"{self.key()}: shards of {self.shard_key_} do not expose their rows")
        s, local = self._locate(rows)
        g = np.empty(len(rows), np.int64)
        f = np.empty(len(rows), np.int64)
        for j in np.unique(s):
            sel = s == j
            t = self._inverse(j)[local[sel]]
            g[sel], f[sel] = self.shards_[j].groups_[t], self.shards_[j].frames_[t]
        return self.query(x, k, radius, eps=eps, exclude=exclude, query_groups=g, query_frames=f)

    # --- persistence ------------------------------------------------------------------
    def save(self, directory: Path) -> None:
        """``shards.json`` and one saved shard index per ``shard-NNN/`` folder."""
        self._check_built()
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        for s, shard in enumerate(self.shards_):
            shard.save(d / f"shard-{s:03d}")
        self._write_meta(d)

    def _write_meta(self, d: Path) -> None:
        meta = {
            "component": self.key(),
            "params": self.get_params(),
            "shard_index": self.shard_key_,
            "shard_class": f"{self.shard_cls_.__module__}:{self.shard_cls_.__qualname__}",
            "offsets": self.offsets_.tolist(),
            "dim": self.dim_,
            "method": self.method_,
        }
        (d / _META).write_text(json.dumps(meta, indent=1))

    @classmethod
    def load(cls, directory: Path) -> ShardedIndex:
        d = Path(directory)
        if not (d / _META).is_file():
            raise DataError(f"{d} holds no saved {cls.name} index (no {_META})")
        meta = json.loads((d / _META).read_text())
        self = cls(meta["params"])
        shard_cls = (
            _import_class(meta["shard_class"])
            if "shard_class" in meta
            else _registries(None).resolve(meta["shard_index"])
        )
        self.offsets_ = np.asarray(meta["offsets"], np.int64)
        self.shards_ = [_load_shard(shard_cls, d / f"shard-{s:03d}") for s in range(len(self.offsets_) - 1)]
        self._finish(shard_cls, meta["dim"])
        self.directory_ = d.resolve()
        self._stamp = str((d / _META).stat().st_mtime_ns)
        return self

    # --- pipeline step ----------------------------------------------------------------
    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.clip_refs import DatasetRef
        from mocapflow.framework.datasets import StepOutput, frame_id_table

        clip_id, frame = inputs["features"].frame_ids()
        cls = self._shard_class(ctx.registries)
        self.offsets_ = shard_bounds(clip_id, self.params.shards, self.params.max_rows)
        out = ctx.out_dir / "index"
        ref = DatasetRef.of(inputs["features"])
        # each shard is built and saved by a worker, which reads only its rows of the features
        tasks = [
            _ShardBuild(ref, int(a), int(b), cls, self.params.index_params, str(out / f"shard-{s:03d}"))
            for s, (a, b) in enumerate(zip(self.offsets_[:-1], self.offsets_[1:], strict=True))
        ]
        built = (
            ctx.executor.map(_build_task, tasks, desc=f"{ctx.step_id}: shards")
            if len(tasks) > 1
            else [_build_task(t) for t in tasks]
        )
        self.shards_ = [_load_shard(cls, Path(t.directory)) for t in tasks]
        self._finish(cls, int(built[0]["dim"]) if built else 0)
        self._write_meta(out)
        summary = {
            "shards": len(tasks),
            "rows": int(len(clip_id)),
            "method": self.method_,
            "shard_rows": [b["rows"] for b in built],
        }
        return StepOutput({"data": frame_id_table(clip_id, frame)}, summary=summary)


@dataclass(frozen=True)
class _ShardBuild:
    features: Any  # DatasetRef
    start: int
    stop: int
    index_cls: type[Index]
    index_params: dict[str, Any]
    directory: str


def _build_task(t: _ShardBuild) -> dict[str, Any]:
    """Read rows ``[start, stop)`` of a features dataset, build one shard, save it."""
    import pyarrow.parquet as pq

    from mocapflow.framework.schema import fixed_list_to_numpy

    f = pq.ParquetFile(f"{t.features.path}/data.parquet", memory_map=True)
    sizes = [f.metadata.row_group(i).num_rows for i in range(f.metadata.num_row_groups)]
    starts = np.concatenate([[0], np.cumsum(sizes)])
    g0 = int(np.searchsorted(starts, t.start, side="right") - 1)
    g1 = int(np.searchsorted(starts, t.stop, side="left"))
    table = f.read_row_groups(list(range(g0, g1))).slice(t.start - int(starts[g0]), t.stop - t.start)
    x = fixed_list_to_numpy(table["features"])
    shard = t.index_cls(t.index_params)
    kw = (
        {"groups": table["clip_id"].to_numpy(), "frames": table["frame"].to_numpy()}
        if "groups" in shard.build_options
        else {}
    )
    shard.build(x, **kw)
    shard.save(Path(t.directory))
    return {"rows": int(len(x)), "dim": int(x.shape[1])}


@dataclass(frozen=True)
class _BlockQuery:
    """A block of queries for the whole sharded index saved at ``directory`` (``stamp``: its
    ``shards.json`` modification time, so that a rebuilt index is loaded again)."""

    directory: str
    stamp: str
    k: int
    radius: float | None
    q: np.ndarray
    kwargs: dict[str, Any]


def _answer_block(task: _BlockQuery) -> tuple[np.ndarray, np.ndarray]:
    """Every shard's answer to one block, merged here (exact), on the worker; the sharded
    index is loaded once per process (memory-mapped shards: the page cache is shared)."""
    from mocapflow.framework.clip_refs import cached

    index = cached(("sharded-index", task.directory, task.stamp), lambda: ShardedIndex.load(Path(task.directory)))
    return index.query(task.q, task.k, task.radius, **task.kwargs)


@dataclass(frozen=True)
class _Apply:
    """``task(q)`` for each shard task (the queries travel once per shard)."""

    q: np.ndarray

    def __call__(self, task: _ShardQuery) -> tuple[np.ndarray, np.ndarray]:
        return task(self.q)
