"""How ``indexes.kdtree`` with ``method: auto`` chooses between its kd-tree and the exact brute
force: work counted on sampled rows at build time, never timed, so the same data always gets the
same method (measured break-evens: docs/knn.md)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

#: ``method: auto`` keeps the kd-tree while the work a k-NN query cannot skip (bucket points
#: within the k-th neighbour distance, plus nodes) stays below this share of the rows (a tree
#: query costs 3-8 ns per counted point and dimension, a brute-force one 3-11 ns per row).
BRUTE_FROM_SHARE = 0.25
#: Batches of at least :data:`BATCH_QUERIES` queries (one GEMM serves a block of them, so a
#: scanned row costs about the same whatever ``d``) stay on the tree while ``tree_share@k x d``
#: is below this (the measured break-even).
BATCH_BRUTE_FROM_WORK = 7.0
BATCH_QUERIES = 32


class ProbeSettings(Protocol):
    """What the probe reads of :class:`.kdtree.TreeSettings` (declared here, so this module
    does not import the kd-tree that mixes it in)."""

    @property
    def probe_queries(self) -> int: ...

    @property
    def probe_k(self) -> tuple[int, ...]: ...


class CostModel:
    """The method choice of :class:`.kdtree.KDTreeIndex` (a mixin: it reads the built tree)."""

    # what the mixin reads and sets on the tree it is mixed into (KDTreeIndex.fit / load)
    params: Any
    data_: np.ndarray
    probe_: dict[str, float]
    method_: str
    brute_from_k_: int | None
    large_method_: str
    _tree_args: Callable[[], tuple[tuple[Any, ...], np.ndarray]]
    _search: Callable[..., tuple[np.ndarray, np.ndarray]]
    _max_depth: Callable[[], int]

    def _probe(self, cfg: ProbeSettings) -> str:
        """Choose the method by counting work on a sample of the indexed rows (deterministic).

        For each probed ``k``: the exact k-th neighbour distance of ``cfg.probe_queries`` sampled
        rows, then the nodes and bucket points of the tree within that distance
        (:func:`._knn_kernels.tree_work`: the work no exact tree search can skip); their
        mean share of the ``n`` rows a brute force scans is ``probe_["tree_share@k"]``. The
        kd-tree answers where that share is below :data:`BRUTE_FROM_SHARE`. The counts
        depend on the data only, never on the machine's load (the timing probe this
        replaces chose a kd-tree on a quiet machine and brute force on a busy one). If the
        tree wins at small ``k`` but not at a larger one, ``brute_from_k_`` records from which
        ``k`` on the brute force answers (the geometric mean of the two probed values).
        """
        from . import _knn_kernels as kern

        n = self.data_.shape[0]
        rng = np.random.default_rng(0)
        q = self.data_[np.sort(rng.choice(n, size=min(cfg.probe_queries, n), replace=False))]
        tree, _ = self._tree_args()
        _, _, start, end, left, right, _, _, blo, bhi = tree[:10]
        winners = []
        for k in sorted({min(k, n) for k in cfg.probe_k}):
            d2, _ = self._search(q, k, None, 0.0, None, None, None, 0, "brute")  # exact, batched
            points, nodes = kern.tree_work(
                q.astype(np.float64), d2[:, -1] * (1.0 + 1e-9), start, end, left, right, blo, bhi, self._max_depth()
            )
            share = float(points.mean() + nodes.mean()) / n
            self.probe_[f"tree_share@{k}"] = round(share, 6)
            winners.append((k, "kdtree" if share < BRUTE_FROM_SHARE else "brute"))
        first = winners[0][1]
        prev = winners[0][0]
        for k, w in winners[1:]:
            if w != first:
                self.brute_from_k_, self.large_method_ = int(round(np.sqrt(prev * k))), w
                break
            prev = k
        return first

    def method_for(self, k: int, m: int = 1) -> str:
        """The method that answers ``m`` queries for ``k`` neighbours (``"kdtree"`` or ``"brute"``).

        Single queries follow the build-time choice (``method_``, ``brute_from_k_``); batches
        of at least :data:`BATCH_QUERIES` of an ``auto`` index also switch to the brute force
        from :meth:`batch_brute_from_k` on (the same probe counts, the batched cost model;
        not for radius queries, whose tree work the unbounded probe overstates).
        """
        if self.brute_from_k_ is not None and k >= self.brute_from_k_:
            method = getattr(self, "large_method_", "brute")
        else:
            method = self.method_
        if method == "kdtree" and m >= BATCH_QUERIES:
            bk = self.batch_brute_from_k()
            if bk is not None and k >= bk:
                return "brute"
        return method

    def batch_brute_from_k(self) -> int | None:
        """From which ``k`` on a batch is answered by brute force (``None``: never).

        Derived from the probe's counts (``probe_``, saved with the index) and the dimension:
        deterministic, and indexes saved before this rule get it too. A ``k`` between two
        probed values switches at their geometric mean, as :meth:`_probe` does.
        """
        probe = getattr(self, "probe_", None) or {}
        shares = sorted((int(key.split("@")[1]), v) for key, v in probe.items() if key.startswith("tree_share@"))
        if self.params.method != "auto" or not shares:
            return None
        d = self.data_.shape[1]
        prev = None
        for k, share in shares:
            if share * d >= BATCH_BRUTE_FROM_WORK:
                return k if prev is None else int(round(np.sqrt(prev * k)))
            prev = k
        return None

    # --- querying ---------------------------------------------------------------------
