"""``indexes.hnsw``: approximate k-nearest-neighbour search (HNSW graph, the ``ann`` extra).

An optional backend (``pip install mocapflow[ann]``, which installs ``hnswlib``): a
hierarchical navigable small-world graph (Malkov & Yashunin 2018) over the feature
vectors, built with one thread from a fixed seed, so the same data and parameters give
the same graph and the same answers. Chosen by measurement (recall@k, time,
build time, size, save/load, determinism against usearch and faiss; ``docs/knn.md``).

Contract (:class:`~mocapflow.framework.Index`): ``build(features)``; ``query(x, k,
radius=None) -> (dist, ids)``, Euclidean ``dist`` float32 (m, k) ascending (ties by row),
row ids int64, padded with ``inf`` / ``-1`` (fewer than ``k`` rows, or beyond ``radius``);
``save``/``load`` (the graph file and a JSON header; nothing is rebuilt). The answers are
approximate: ``ef`` (search breadth, at least ``k``) trades time for recall. No
``exclude`` and no ``eps`` (the LNG and the matchers need neither).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import Field

from mocapflow.framework import Index
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.errors import ConfigError, DataError


def _hnswlib() -> Any:
    try:
        import hnswlib
    except ImportError as exc:
        raise ConfigError("indexes.hnsw needs the 'ann' extra: pip install 'mocapflow[ann]' (hnswlib)") from exc
    return hnswlib


class HNSWIndex(Index):
    """Approximate kNN index (HNSW via hnswlib); deterministic for a given ``seed``."""

    name: ClassVar[str] = "hnsw"
    query_options: ClassVar[frozenset[str]] = frozenset({"workers"})

    class Params(BaseParams):
        m: int = Field(16, ge=2, le=128, description="graph degree M (links per node and layer)")
        ef_construction: int = Field(200, ge=8, description="search breadth while building (quality of the graph)")
        ef: int = Field(512, ge=1, description="search breadth of a query (at least k is used); recall grows with it")
        seed: int = Field(0, description="random seed of the layer assignment (with one build thread: same graph)")
        threads: int = Field(
            1, ge=0, description="build threads (1: deterministic; 0: all cores, faster, not reproducible)"
        )

    params: Params

    def build(self, features: np.ndarray) -> HNSWIndex:
        """Index ``features`` (n, d) (converted to float32 once)."""
        hnswlib = _hnswlib()
        x = np.ascontiguousarray(features, dtype=np.float32)
        if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
            raise DataError(f"{self.key()}: features must be (n >= 1, d >= 1), got shape {x.shape}")
        if not np.isfinite(x).all():
            raise DataError(f"{self.key()}: features contain NaN or inf")
        p = self.params
        ix = hnswlib.Index(space="l2", dim=x.shape[1])
        ix.init_index(max_elements=len(x), M=p.m, ef_construction=p.ef_construction, random_seed=p.seed)
        ix.add_items(x, np.arange(len(x)), num_threads=p.threads or -1)
        self.index_, self.n_, self.dim_ = ix, len(x), x.shape[1]
        return self

    def query(
        self, x: np.ndarray, k: int, radius: float | None = None, *, workers: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """Approximate ``k`` nearest rows of each query row; see the module doc for the format."""
        if not hasattr(self, "index_"):
            raise DataError(f"{self.key()}: query before build/load")
        q = np.ascontiguousarray(np.atleast_2d(x), dtype=np.float32)
        if q.ndim != 2 or q.shape[1] != self.dim_:
            raise DataError(f"{self.key()}: queries must be (m, {self.dim_}), got {q.shape}")
        if k < 1:
            raise ConfigError(f"{self.key()}: k must be >= 1")
        kk = min(int(k), self.n_)
        self.index_.set_ef(max(self.params.ef, kk))
        ids, d2 = self.index_.knn_query(q, k=kk, num_threads=workers)
        dist = np.sqrt(np.maximum(d2, 0)).astype(np.float32)
        ids = ids.astype(np.int64)
        order = np.lexsort((ids, dist), axis=1)  # ascending distance, ties by row
        dist, ids = np.take_along_axis(dist, order, 1), np.take_along_axis(ids, order, 1)
        if radius is not None:
            far = dist > radius
            dist[far], ids[far] = np.inf, -1
        if kk < k:
            dist = np.pad(dist, ((0, 0), (0, k - kk)), constant_values=np.inf)
            ids = np.pad(ids, ((0, 0), (0, k - kk)), constant_values=-1)
        return dist, ids

    def save(self, directory: Path) -> None:
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.index_.save_index(str(d / "hnsw.bin"))
        (d / "index.json").write_text(
            json.dumps(
                {"component": self.key(), "params": self.get_params(), "rows": self.n_, "dim": self.dim_}, indent=1
            )
        )

    @classmethod
    def load(cls, directory: Path) -> HNSWIndex:
        d = Path(directory)
        if not (d / "index.json").is_file() or not (d / "hnsw.bin").is_file():
            raise DataError(f"{d} holds no saved {cls.name} index (index.json, hnsw.bin)")
        meta = json.loads((d / "index.json").read_text())
        self = cls(meta["params"])
        ix = _hnswlib().Index(space="l2", dim=int(meta["dim"]))
        ix.load_index(str(d / "hnsw.bin"), max_elements=int(meta["rows"]))
        self.index_, self.n_, self.dim_ = ix, int(meta["rows"]), int(meta["dim"])
        return self
