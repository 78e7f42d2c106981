"""Executors: how a step fans out per-item work (per clip, per query).

An executor is anything with ``map(fn, items, desc) -> list`` and ``close()``. The runner
never looks inside: ``local`` runs in-process or on a process pool; a cluster executor
(e.g. ``dask.distributed``) implements the same two methods and is registered through the
``register_executors`` hook (or passed to :func:`~mocapflow.framework.runner.run_pipeline`).
``fn`` must be picklable (a module-level function or a bound method of a picklable
component) when work leaves the process.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Protocol

from .progress import progress


class Executor(Protocol):
    name: str

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]: ...

    def close(self) -> None: ...


class LocalExecutor:
    """In-process for ``jobs == 1``, else a lazily started process pool of ``jobs`` workers.

    Results come back in input order. Small batches stay in-process (a pool costs more
    than it saves for a handful of items).
    """

    name = "local"

    def __init__(self, jobs: int = 1, min_items_for_pool: int = 4) -> None:
        self.jobs = max(1, int(jobs)) if jobs and jobs > 0 else (os.cpu_count() or 1)
        self.min_items_for_pool = min_items_for_pool
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]:
        items = list(items)
        if self.jobs == 1 or len(items) < self.min_items_for_pool:
            return [fn(x) for x in progress(items, total=len(items), desc=desc)]
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=self.jobs)
        chunk = max(1, len(items) // (self.jobs * 4))
        return list(progress(self._pool.map(fn, items, chunksize=chunk), total=len(items), desc=desc))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

