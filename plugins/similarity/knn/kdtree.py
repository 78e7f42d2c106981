"""``indexes.kdtree``: exact (or ε-approximate) k-nearest-neighbour search over feature vectors.

The kNN index of Krüger et al. 2010 §3.3 (they used ANN): a float32 kd-tree of our own
(:mod:`._knn_kernels`, :mod:`._tree_kernels`), saved and loaded as plain arrays without a
rebuild, and an exact BLAS brute force (:mod:`._brute`) where a tree loses (high intrinsic
dimension, large batches). ``method: auto`` chooses by a deterministic cost model counted at
build time (:mod:`.cost_model`; docs/knn.md). Both methods
are exact, ties ordered by row id. Consecutive queries (the graph's query frames) seed each
other's pruning bound with the k-th distance to the previous query's neighbours.
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

from .cost_model import CostModel
from .kdtree_store import ARRAYS, INDEX_LAYOUT, TREE_ARRAYS, read_meta, rows_from_dataset, sqnorms

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework import Dataset, StepContext, StepOutput


@dataclass(frozen=True)
class TreeSettings:
    """How a kd-tree is built and how ``method: auto`` probes (measured defaults, docs/knn.md).

    ``leafsize``: maximum points per bucket (64, not ANN's usual 16: with per-node bounding
    boxes a far bucket is skipped on one box test and a scanned one is a tight loop; measured
    15-40 % faster single queries than 16 at 27 k and 380 k rows, and 128 no faster).
    ``probe_queries`` rows sampled to count the methods' work, for each of ``probe_k``
    neighbour counts (Table 1: 16 and 256); below ``min_probe_rows`` rows auto uses the
    kd-tree without a probe.
    """

    leafsize: int = 64
    probe_queries: int = 64
    probe_k: tuple[int, ...] = (16, 256)
    min_probe_rows: int = 20000


TREE = TreeSettings()


def _ro(a: np.ndarray) -> np.ndarray:
    """A read-only view (no copy): the kernels read features read-only, whether they come from
    Arrow (read-only) or NumPy (writable), so one variant compiles, not two."""
    v: np.ndarray = a.view()
    v.flags.writeable = False
    return v


_ZEROS = np.zeros(4, np.int64)  # query clip/frame ids of interactive queries (never written)


class KDTreeIndex(CostModel, Index):
    """Exact k-nearest-neighbour index (kd-tree, or BLAS brute force where that is faster).

    Contract (:class:`~mocapflow.framework.Index`): ``build(features)``;
    ``query(x, k, radius=None) -> (dist, ids)`` with Euclidean ``dist`` float32 of shape
    (m, k) ascending and row ids int64, padded with ``inf`` / ``-1``; ``save``/``load``.
    Ties are ordered by row id, so results are deterministic and equal a sorted brute force.

    Extensions (keyword-only, :attr:`query_options`, :attr:`build_options`): ``build(...,
    groups=, frames=)`` clip id and frame per row (for ``exclude``); ``query(..., eps=)``
    ε-approximate (kd-tree only); ``radius=r`` fixed-radius capped at ``k``; ``exclude=N,
    query_groups=, query_frames=`` skip the query's own clip within ±N frames;
    ``workers`` threads for batches (1 for interactive queries); ``query_rows(rows, k, ...)``
    queries with indexed rows themselves.

    Attributes
    ----------
    method_ : {"kdtree", "brute"}
        The search method in use (chosen by the probe when ``method: auto``).
    brute_from_k_ : int or None
        From this many neighbours on, the probe's cost model chose ``large_method_``, and it answers
        those queries (:meth:`method_for`). ε-approximate queries (``eps > 0``) always use the
        kd-tree.
    large_method_ : str
        The method for ``k >= brute_from_k_`` (default ``"brute"``).
    probe_ : dict
        Probe counts: ``tree_share@<k>``, the kd-tree's unavoidable work per query as a share
        of the rows (:meth:`_probe`); empty if no probe ran.
    data_ : ndarray of shape (n, d), float32
        The features, stored once in tree order (row ``t`` is input row ``perm_[t]``).
    """

    name: ClassVar[str] = "kdtree"
    query_options: ClassVar[frozenset[str]] = frozenset({"eps", "exclude", "query_groups", "query_frames", "workers"})
    build_options: ClassVar[frozenset[str]] = frozenset({"groups", "frames"})

    # caches filled on first use, None until then (reset by fit and load)
    _inv: np.ndarray | None
    _depth: int | None
    _raw_bound: Any
    _boxes: tuple[np.ndarray, np.ndarray] | None
    _targs: tuple[tuple[Any, ...], np.ndarray] | None
    #: the rows in dataset order (features, clip id, frame) when loaded beside their dataset
    _rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    #: the folder the index was loaded from (None: built in memory)
    _dir: Path | None

    class Params(BaseParams):
        method: Literal["auto", "kdtree", "brute"] = Field(
            "auto",
            description=(
                "search method; auto counts the kd-tree's unavoidable work on sampled rows at build time and keeps "
                "it unless that reaches a quarter of the rows (deterministic; both methods exact)"
            ),
        )
        workers: int = Field(0, ge=0, description="threads for batched queries, 0 = all cores")

    params: Params

    # --- building ---------------------------------------------------------------------
    def build(
        self,
        features: np.ndarray,
        *,
        groups: np.ndarray | None = None,
        frames: np.ndarray | None = None,
        tree: TreeSettings | None = None,
    ) -> KDTreeIndex:
        """Index ``features`` (n, d); float32 is stored as is (tree order), others converted once.

        Parameters
        ----------
        features : ndarray of shape (n, d)
        groups, frames : ndarray of shape (n,), int, optional
            Clip id and frame per row (for ``exclude``).
        tree : TreeSettings, optional
            Bucket size and probe (default :data:`TREE`).
        """
        from . import _tree_kernels as tk

        cfg = tree or TREE
        x = np.asarray(features)
        if x.ndim != 2 or x.shape[1] < 1:
            raise DataError(f"{self.key()}: features must be (n, d) with d >= 1, got shape {x.shape}")
        if x.dtype != np.float32:
            x = x.astype(np.float32)
        if not np.isfinite(x).all():
            raise DataError(
                f"{self.key()}: features contain NaN or inf (rows {np.flatnonzero(~np.isfinite(x).all(1))[:5].tolist()}...)"
            )
        n = x.shape[0]
        # int32 like the clip_id/frame columns: 8 bytes per row beside the 4 d of the features
        g = np.zeros(n, np.int32) if groups is None else np.asarray(groups).astype(np.int32)
        f = np.arange(n, dtype=np.int32) if frames is None else np.asarray(frames).astype(np.int32)
        if g.shape != (n,) or f.shape != (n,):
            raise DataError(f"{self.key()}: groups/frames must have shape ({n},)")
        x = np.ascontiguousarray(x)
        perm, start, end, left, right, sdim, sval = (
            tk.build_tree(_ro(x), cfg.leafsize)
            if n
            else (
                np.zeros(0, np.int64),
                *(np.zeros(1, np.int64),) * 2,
                *(np.full(1, -1, np.int64),) * 2,
                np.zeros(1, np.int32),
                np.zeros(1, np.float32),
            )
        )
        self._inv = self._depth = self._raw_bound = self._boxes = self._targs = None
        self.data_ = x[perm]
        self.perm_, self.groups_, self.frames_ = perm, g[perm], f[perm]
        self.start_, self.end_, self.left_, self.right_, self.sdim_, self.sval_ = start, end, left, right, sdim, sval
        self.mean_ = self.data_.mean(0, dtype=np.float64).astype(np.float32) if n else np.zeros(x.shape[1], np.float32)
        self.sqnorms_ = sqnorms(self.data_, self.mean_)
        self._rows = None
        self.probe_ = {}
        self.method_, self.brute_from_k_, self.large_method_ = self.params.method, None, "brute"
        if self.method_ == "auto":
            self.method_ = self._probe(cfg) if n >= max(cfg.min_probe_rows, 1) else "kdtree"
        return self

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
        workers: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest indexed rows of each query (see the class docstring).

        Parameters
        ----------
        x : ndarray of shape (m, d) or (d,)
        k : int
        radius : float, optional
            Only neighbours within this Euclidean distance (padding fills the rest).

        Returns
        -------
        dist : ndarray of shape (m, k), float32, ascending
        ids : ndarray of shape (m, k), int64, rows of the indexed features (-1 = none)
        """
        fast = self._interactive(x, k, radius, eps, exclude)
        if fast is not None:
            return fast
        self._check_built()
        q = np.asarray(x, dtype=np.float32)
        if q.ndim == 1:
            q = q[None, :]
        if q.ndim != 2 or q.shape[1] != self.data_.shape[1]:
            raise DataError(f"{self.key()}: queries must be (m, {self.data_.shape[1]}), got shape {np.shape(x)}")
        if int(k) < 1:
            raise ConfigError(f"{self.key()}: k must be >= 1, got {k}")
        if eps < 0 or (radius is not None and radius < 0):
            raise ConfigError(f"{self.key()}: eps and radius must be >= 0")
        if exclude is not None:
            if exclude < 0 or query_groups is None or query_frames is None:
                raise ConfigError(f"{self.key()}: exclude=N needs N >= 0 and query_groups/query_frames")
            query_groups = np.broadcast_to(np.asarray(query_groups, np.int64), (len(q),))
            query_frames = np.broadcast_to(np.asarray(query_frames, np.int64), (len(q),))
        w = self.params.workers if workers is None else workers
        d2, ids = self._search(
            np.ascontiguousarray(q),
            int(k),
            radius,
            float(eps),
            exclude,
            query_groups,
            query_frames,
            w,
            "kdtree" if eps > 0 else self.method_for(int(k), len(q) if radius is None else 1),
        )
        return np.sqrt(d2).astype(np.float32), ids

    def _interactive(
        self, x: np.ndarray, k: int, radius: float | None, eps: float, exclude: int | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The common interactive call (one float32 query row, plain exact kNN on the kd-tree
        path) with no per-call numpy work: a 16-NN query in 8-d takes ~20 microseconds, so
        the checks and conversions of the general path would add a third. None: not that call."""
        if (
            radius is not None
            or eps != 0.0
            or exclude is not None
            or type(x) is not np.ndarray
            or x.dtype != np.float32
            or type(k) is not int
            or k < 1
        ):
            return None
        targs = getattr(self, "_targs", None)
        if (
            targs is None
            or x.ndim != 2
            or x.shape[0] != 1
            or x.shape[1] != self.data_.shape[1]
            or not x.flags.c_contiguous
            or self.method_for(k) != "kdtree"
        ):
            return None
        from . import _knn_kernels as kern

        tree, no_seed = targs
        assert self._depth is not None  # set with _targs (_tree_args)
        d2, ids = kern.query_tree(_ro(x), k, 0.0, np.inf, tree, _ZEROS[:1], _ZEROS[:1], -1, self._depth, 1, no_seed)
        return np.sqrt(d2).astype(np.float32), ids

    def query_rows(
        self,
        rows: np.ndarray,
        k: int,
        radius: float | None = None,
        *,
        eps: float = 0.0,
        exclude: int | None = None,
        workers: int | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Query with indexed rows (input row ids), excluding their own clip within ±``exclude`` frames."""
        self._check_built()
        rows = np.asarray(rows, np.int64)
        inv = self._inverse_perm()
        t = inv[rows]
        return self.query(
            self.data_[t],
            k,
            radius,
            eps=eps,
            exclude=exclude,
            query_groups=self.groups_[t],
            query_frames=self.frames_[t],
            workers=workers,
        )

    def _inverse_perm(self) -> np.ndarray:
        inv = getattr(self, "_inv", None)
        if inv is None:
            inv = np.empty_like(self.perm_)
            inv[self.perm_] = np.arange(len(self.perm_))
            self._inv = inv
        return inv

    def _search(
        self,
        q: np.ndarray,
        k: int,
        radius: float | None,
        eps: float,
        exclude: int | None,
        qg: np.ndarray | None,
        qf: np.ndarray | None,
        workers: int | None,
        method: str,
    ) -> tuple[np.ndarray, np.ndarray]:
        from . import _knn_kernels as kern

        m, n = len(q), self.data_.shape[0]
        if m == 0 or n == 0:
            return np.full((m, k), np.inf), np.full((m, k), -1, np.int64)
        r2 = np.inf if radius is None else float(radius) ** 2
        excl = -1 if exclude is None else int(exclude)
        if qg is None:
            qg = qf = _ZEROS[:m] if m <= len(_ZEROS) else np.zeros(m, np.int64)
        # writable int64: a read-only (Arrow) array would compile a second kernel variant
        qg, qf = np.require(qg, np.int64, ("C", "W")), np.require(qf, np.int64, ("C", "W"))
        if method == "brute" and getattr(self, "_raw_bound", None) is None:
            from ._brute import raw_sqnorm_bound

            self._raw_bound = raw_sqnorm_bound(self.data_)
            self._sqnorm_max = float(self.sqnorms_.max())
        # interactive queries (m <= 2) run on the calling thread: no thread-pool set-up per call
        prev = kern.set_threads(workers) if m > 2 else None
        try:
            if method == "brute":
                from ._brute import brute_knn

                return brute_knn(
                    q,
                    self.data_,
                    self.mean_,
                    self.sqnorms_,
                    k,
                    r2,
                    self.groups_,
                    self.frames_,
                    qg,
                    qf,
                    excl,
                    ids=self.perm_,
                    raw_bound=self._raw_bound,
                    sqnorm_max=self._sqnorm_max,
                )
            # consecutive queries seed each other's bound (see the module doc): contiguous chunks,
            # one per thread, keep most queries seeded
            chunks = 1 if m < 4 or kern.threads() == 1 else min(m, 4 * kern.threads())
            seeded = eps == 0.0 and m > 1
            tree, no_seed = self._tree_args()
            assert self._depth is not None  # set by _tree_args
            return kern.query_tree(
                _ro(q),
                k,
                eps,
                r2,
                tree,
                qg,
                qf,
                excl,
                self._depth,
                min(chunks, kern.threads()) if seeded else chunks,
                self._inverse_perm() if seeded else no_seed,
            )
        finally:
            if prev is not None:
                kern.set_threads(prev)

    def _tree_args(self) -> tuple[tuple[Any, ...], np.ndarray]:
        """The tree's arrays in :func:`._knn_kernels.query_tree` order (cached: a single query
        is a few tens of microseconds, so per-call attribute work shows)."""
        args = getattr(self, "_targs", None)
        if args is None:
            self._max_depth()
            args = self._targs = (
                (
                    self.data_,
                    self.perm_,
                    self.start_,
                    self.end_,
                    self.left_,
                    self.right_,
                    self.sdim_,
                    self.sval_,
                    *self._node_boxes(),
                    self.groups_,
                    self.frames_,
                ),
                self.perm_[:0],
            )
        return args

    def _node_boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-node bounding boxes ``(lo, hi)`` (n_nodes, d) the search prunes on.

        Not saved: they are derived from the stored points and node ranges in one O(n d)
        pass on first use (30 ms and 10 MB at 380k rows, d = 15), so the on-disk format is
        unchanged and indexes saved before boxes existed load as they are.
        """
        from . import _tree_kernels as tk

        boxes = getattr(self, "_boxes", None)
        if boxes is None:
            boxes = self._boxes = tk.node_boxes(self.data_, self.start_, self.end_, self.left_, self.right_)
        return boxes

    def _max_depth(self) -> int:
        from . import _tree_kernels as tk

        depth = getattr(self, "_depth", None)
        if depth is None:
            depth = self._depth = int(tk.tree_depth(self.left_, self.right_))
        return depth

    def _check_built(self) -> None:
        if not hasattr(self, "data_"):
            raise DataError(f"{self.key()}: index not built (call build() or load())")

    # --- persistence ------------------------------------------------------------------
    def save(self, directory: Path, rows_from: Dataset | None = None) -> None:
        """Write the index arrays (``.npy``) and ``index.json``; :meth:`load` does not rebuild.

        ``rows_from``: the finished features dataset the index was built over, in the same
        workspace (the pipeline step passes its input). Then the features are not copied: the
        index keeps the tree (nodes and the row permutation, ~5 bytes a row) and :meth:`load`
        reads the rows from that dataset. Without it (an index saved by hand, a shard) every
        array is written, the rows also in dataset order (``rows_*.npy``) for :meth:`rows`.
        """
        self._check_built()
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        own = TREE_ARRAYS if rows_from is not None else ARRAYS
        for a in own:
            arr = getattr(self, a)
            if a == "perm_" and rows_from is not None and len(arr) < 2**31:
                arr = arr.astype(np.int32)  # 4 bytes a row on disk; int64 again once loaded
            np.save(d / f"{a.rstrip('_')}.npy", arr)
        if rows_from is None:
            # the rows in dataset order (features, clip id, frame) beside the tree: `mocapflow
            # search` memory-maps them instead of decoding the features Parquet
            inv = self._inverse_perm()
            for name, rows in (
                ("rows_features", self.data_),
                ("rows_clip_id", self.groups_),
                ("rows_frame", self.frames_),
            ):
                np.save(d / f"{name}.npy", rows[inv])
        meta = {
            "component": self.key(),
            "params": self.get_params(),
            "layout": INDEX_LAYOUT,
            "method": self.method_,
            "brute_from_k": self.brute_from_k_,
            "large_method": getattr(self, "large_method_", "brute"),
            "probe": self.probe_,
        }
        if rows_from is not None:
            meta["rows_from"] = {"step": rows_from.step, "fingerprint": rows_from.fingerprint}
        (d / "index.json").write_text(json.dumps(meta, indent=1))

    def rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """``(features, clip_id, frame)`` of the indexed rows in dataset order: read from the
        features dataset for an index that references it (read once, at load), else
        memory-mapped (copy-on-write) from the sidecar files :meth:`save` writes (``None`` for
        an index saved before them, or one never saved): what a search space needs.

        Returns
        -------
        tuple of ndarray (n, d) float32, (n,) int32, (n,) int32, or None
        """
        own = getattr(self, "_rows", None)
        if own is not None:
            return cast("tuple[np.ndarray, np.ndarray, np.ndarray] | None", own)
        d = getattr(self, "_dir", None)
        if d is None or not all((d / f"rows_{n}.npy").is_file() for n in ("features", "clip_id", "frame")):
            return None
        # copy-on-write like the tree arrays: writable ndarrays (the kernels' one signature), never written
        return tuple(
            np.load(d / f"rows_{n}.npy", mmap_mode="c").view(np.ndarray) for n in ("features", "clip_id", "frame")
        )

    @classmethod
    def load(cls, directory: Path) -> KDTreeIndex:
        d = Path(directory)
        meta, arrays = read_meta(d, cls.name)
        ref = meta.get("rows_from")
        # parameters that became build settings (leafsize, probe_*) are ignored in older indexes
        self = cls({k: v for k, v in meta["params"].items() if k in cls.Params.model_fields})
        self._inv = self._depth = self._raw_bound = self._boxes = self._targs = None
        for a in arrays:
            # memory-mapped copy-on-write: nothing is read before a query touches it, and the
            # arrays stay writable ndarrays (the kernels' one signature)
            arr = np.load(d / f"{a.rstrip('_')}.npy", mmap_mode="c")
            setattr(self, a, arr.view(np.ndarray) if isinstance(arr, np.memmap) else arr)
        if ref:
            self._attach_rows(d, ref)
        self.method_, self.probe_, self.brute_from_k_ = meta["method"], meta["probe"], meta.get("brute_from_k")
        self.large_method_ = meta.get("large_method", "brute")
        self._dir = d
        return self

    def _attach_rows(self, d: Path, ref: dict[str, Any]) -> None:
        """The rows of an index saved with ``rows_from`` (:func:`.kdtree_store.rows_from_dataset`)."""
        perm, self._rows = rows_from_dataset(d, ref, self.perm_)
        x, groups, frames = self._rows
        self.perm_ = perm
        self.data_ = x[perm]
        self.groups_, self.frames_ = groups[perm], frames[perm]
        self.sqnorms_ = sqnorms(self.data_, self.mean_)

    # --- pipeline step ----------------------------------------------------------------
    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput, frame_id_table

        feats = inputs["features"].features()
        self.build(feats.x, groups=feats.clip_id, frames=feats.frame)
        self.save(ctx.out_dir / "index", rows_from=inputs["features"])
        summary = {
            "method": self.method_,
            "brute_from_k": self.brute_from_k_,
            "large_method": self.large_method_,
            "rows": int(feats.x.shape[0]),
            "dim": int(feats.x.shape[1]),
            **self.probe_,
        }
        ctx.log.info(
            "%s: %d x %d, method %s (%s from k=%s) %s",
            self.key(),
            *feats.x.shape,
            self.method_,
            self.large_method_,
            self.brute_from_k_,
            self.probe_,
        )
        return StepOutput({"data": frame_id_table(feats.clip_id, feats.frame)}, summary=summary)
