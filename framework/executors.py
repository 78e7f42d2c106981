"""The local executor: a step's per-item work (clip, query, shard) in-process or on a pool.

Any executor follows :class:`~mocapflow.framework.context.Executor`. Work goes out by
reference (:mod:`.clip_refs`); each worker gets ``cores // workers`` numeric threads; the
pool forks only while that is safe, after :func:`warm_up`. Measurements: docs/scale-out.md.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import Field

from .clip_refs import clear_cache
from .errors import PipelineError
from .params import Params
from .progress import progress
from .threads import _client_threads, available_cores, limit_threads, threads_per_worker

#: Modules a forkserver imports once, so that its workers start warm.
PRELOAD = ("numpy", "pyarrow.parquet", "numba", "mocapflow.framework", "mocapflow.plugins")


def _fork_is_safe() -> bool:
    """Fork copies a GNU OpenMP runtime that numba launched, and the child aborts
    ("fork() called from a process already using GNU OpenMP"); fork only before that."""
    if sys.platform != "linux" or "fork" not in multiprocessing.get_all_start_methods():
        return False
    parallel = sys.modules.get("numba.np.ufunc.parallel")
    return parallel is None or not parallel._is_initialized


def warm_up() -> None:
    """Pay numba's and pyarrow.dataset's start-up (~0.8 s CPU) here, before the pool forks:
    a forked worker's first read 0.57 s -> 0.06 s. Serial kernels only (OpenMP makes forks unsafe)."""
    import pyarrow.dataset  # noqa: F401 - preloaded before forking: the worker's first read is then fast

    from ._fk_kernels import fk

    identity = np.zeros((2, 2, 4))
    identity[..., 0] = 1.0
    fk(np.array([-1, 0]), np.zeros((2, 3)), np.zeros((2, 3)), identity, None)


def _init_worker(threads: int, warm: bool = False) -> None:
    limit_threads(threads)
    if warm:  # forked before the parent warmed up (LocalExecutor.start): each worker pays its own
        warm_up()


def _started() -> int:
    return os.getpid()


class LocalExecutor:
    """In-process for ``jobs == 1``, else ``jobs`` workers kept for the run (the client as
    worker 0 when ``client_works``; default: for a forkserver or spawned pool, whose workers
    warm up on their own; a forked pool inherits the client's start-up, measured no faster).

    Results come back in input order; a failing batch raises its first failing item's error,
    as in-process. A worker that dies fails the step with a :class:`PipelineError`.
    """

    name: ClassVar[str] = "local"

    class Params(Params):
        jobs: int = Field(1, ge=0, description="workers, the client included (0: one per core)")
        min_items_for_pool: int = Field(4, ge=1, description="smaller batches run in-process")
        threads: int | None = Field(None, ge=1, description="numeric threads per worker (default cores // jobs)")
        start_method: Literal["fork", "forkserver", "spawn"] | None = Field(
            None, description="default: fork while it is safe, else a forkserver"
        )
        prestart: bool = Field(False, description="fork the pool before planning; workers warm up meanwhile")
        client_works: bool | None = Field(
            None, description="the client is worker 0 (default: for a forkserver or spawned pool)"
        )

    def __init__(
        self,
        jobs: int = 1,
        min_items_for_pool: int = 4,
        threads: int | None = None,
        start_method: str | None = None,
        prestart: bool = False,
        client_works: bool | None = None,
    ) -> None:
        self.jobs = max(1, int(jobs)) if jobs and jobs > 0 else available_cores()
        self.min_items_for_pool = min_items_for_pool
        self.threads = threads or threads_per_worker(self.jobs)
        self.start_method = start_method
        self.prestart = bool(prestart)
        self.client_works = client_works
        self._client = bool(client_works)  # resolved when the pool starts (see client_works)
        #: per pooled batch: CPU seconds of the client's chunks and of each pool process (scale.py)
        self.batches: list[dict[str, Any]] = []
        self._pool: ProcessPoolExecutor | None = None

    @property
    def workers(self) -> int:
        return self.jobs

    @property
    def processes(self) -> int:
        """Pool processes: ``jobs - 1`` when the client works, else ``jobs``."""
        return self.jobs - 1 if self._client else self.jobs

    def _client_works(self, method: str, warm_parent: bool) -> bool:
        if self.client_works is not None:
            return bool(self.client_works)
        return method != "fork"  # workers that import and warm up on their own (measured)

    def start(self) -> None:
        """With ``prestart``: fork every worker now; each warms itself up in the background."""
        if self.prestart and self.jobs > 1 and self._pool is None:
            pool = self._ensure_pool(warm_parent=False)
            for _ in range(self.processes):  # a process per pending task: all of them start now
                pool.submit(_started)

    def _ensure_pool(self, warm_parent: bool = True) -> ProcessPoolExecutor:
        if self._pool is None:
            method = self.start_method or ("fork" if _fork_is_safe() else "forkserver")
            mp = multiprocessing.get_context(method)
            if method == "forkserver":
                mp.set_forkserver_preload(list(PRELOAD))
            elif method == "fork" and warm_parent:
                warm_up()
            self._client = self._client_works(method, warm_parent)
            self._pool = ProcessPoolExecutor(
                max_workers=self.processes,
                mp_context=mp,
                initializer=_init_worker,
                initargs=(self.threads, method == "fork" and not warm_parent),
            )
        return self._pool

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]:
        items = list(items)
        if self.jobs == 1 or len(items) < self.min_items_for_pool:
            try:
                return [fn(x) for x in progress(items, total=len(items), desc=desc)]
            finally:
                clear_cache()  # the parent keeps no dataset between steps
        c0 = time.process_time()
        pool = self._ensure_pool()
        try:
            if self._client:
                return self._map_with_client(pool, fn, items, desc)
            return self._map_on_pool(pool, fn, items, desc)
        except BrokenProcessPool:
            self.close()
            raise PipelineError(
                f"a worker process of the local executor died during {desc or 'a step'!r} "
                "(killed, out of memory or crashed); the step's output was discarded"
            ) from None
        finally:
            if self.batches:  # the client's CPU during the whole batch (pool start-up included)
                self.batches[-1]["map_s"] = time.process_time() - c0

    def _map_on_pool(
        self, pool: ProcessPoolExecutor, fn: Callable[[Any], Any], items: list[Any], desc: str
    ) -> list[Any]:
        chunk = max(1, len(items) // (self.jobs * 4))
        out = pool.map(fn, items, chunksize=chunk)
        cpu0 = _pool_cpu(pool)  # after the submissions: a forked pool starts its processes there
        try:
            return list(progress(out, total=len(items), desc=desc))
        finally:
            self._record(desc, len(items), 0.0, cpu0, _pool_cpu(pool))

    def _map_with_client(
        self, pool: ProcessPoolExecutor, fn: Callable[[Any], Any], items: list[Any], desc: str
    ) -> list[Any]:
        """Chunks claimed in order by the client (which runs them) and by a feeder thread that
        keeps each pool process supplied (plus one queued while more than ``jobs`` remain)."""
        batch = _ClientBatch(self, pool, fn, items)
        first: dict[Future[list[Any]], int] = {}
        batch.submit(first, self.processes)  # in this thread: a forked pool starts its processes here
        cpu0 = _pool_cpu(pool)
        feeder = threading.Thread(target=batch.feed, args=(first,), name="mocapflow-feeder", daemon=True)
        feeder.start()
        try:
            for _ in progress(batch.drive(), total=len(items), desc=desc):
                pass
        finally:
            batch.stop.set()  # an error or an interrupt: nothing more is claimed nor submitted
            clear_cache()  # the client keeps no dataset between steps
            self._record(desc, len(items), batch.own, cpu0, _pool_cpu(pool))
        if batch.errors:
            raise batch.errors[min(batch.errors)]
        return [r for part in batch.results for r in part or ()]

    def _record(self, desc: str, n: int, client_s: float, cpu0: dict[int, float], cpu1: dict[int, float]) -> None:
        workers = [cpu1[p] - cpu0.get(p, 0.0) for p in cpu1]
        self.batches.append({"desc": desc, "items": n, "client_s": client_s, "workers_s": workers})

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


class _ClientBatch:
    """One batch of :meth:`LocalExecutor._map_with_client`: its chunks, claimed in order by
    the client (:meth:`drive`) and by the feeder thread for the pool (:meth:`feed`)."""

    def __init__(self, ex: LocalExecutor, pool: ProcessPoolExecutor, fn: Callable[[Any], Any], items: list[Any]):
        self.ex, self.pool, self.fn, self.items = ex, pool, fn, items
        size = max(1, len(items) // (ex.jobs * 8))  # finer than the pool alone: a chunk is the tail
        self.bounds = [(a, min(a + size, len(items))) for a in range(0, len(items), size)]
        self.todo, self.lock, self.stop = deque(range(len(self.bounds))), threading.Lock(), threading.Event()
        # (chunk, future) the pool finished, (-1, error) a broken pool; None: the feeder ended
        self.done: queue.SimpleQueue[tuple[int, Any] | None] = queue.SimpleQueue()
        self.results: list[list[Any] | None] = [None] * len(self.bounds)
        self.errors: dict[int, BaseException] = {}
        self.own = 0.0  # CPU seconds of the client's own chunks

    def chunk(self, j: int) -> list[Any]:
        return self.items[self.bounds[j][0] : self.bounds[j][1]]

    def claim(self) -> int | None:
        with self.lock:  # chunks are claimed in order: all chunks before a failing one are claimed
            return None if self.stop.is_set() or not self.todo else self.todo.popleft()

    def submit(self, inflight: dict[Future[list[Any]], int], want: int) -> None:
        while len(inflight) < want + (1 if len(self.todo) > self.ex.jobs else 0):
            j = self.claim()
            if j is None:
                return
            inflight[self.pool.submit(_apply_chunk, self.fn, self.chunk(j))] = j

    def feed(self, inflight: dict[Future[list[Any]], int]) -> None:
        """The feeder thread: keeps the pool supplied, hands finished chunks to the client."""
        try:
            while True:
                self.submit(inflight, self.ex.processes)
                if not inflight:
                    return
                finished, _ = wait(inflight, return_when=FIRST_COMPLETED)
                for f in finished:
                    if f.exception() is not None:
                        self.stop.set()  # as in-process: nothing after a failing item starts
                    self.done.put((inflight.pop(f), f))
        except BaseException as exc:  # a broken or closed pool: the client raises it
            self.stop.set()
            self.done.put((-1, exc))
        finally:
            self.done.put(None)

    def take(self, item: tuple[int, Any]) -> Iterator[int]:
        """A chunk the pool finished: its result or error; one tick per item."""
        j, f = item
        if j < 0:
            raise f
        exc = f.exception()
        if isinstance(exc, BrokenProcessPool):
            raise exc
        if exc is not None:
            self.errors[j] = exc
        else:
            self.results[j] = f.result()
        yield from range(len(self.chunk(j)))

    def run_own(self, j: int) -> Iterator[int]:
        """A chunk the client runs itself; one tick per item."""
        c0 = time.process_time()
        try:
            self.results[j] = _apply_chunk(self.fn, self.chunk(j))
        except Exception as exc:  # raised at the end in input order, like a worker's
            self.errors[j] = exc
            self.stop.set()
        finally:
            self.own += time.process_time() - c0
        yield from range(len(self.chunk(j)))

    def drive(self) -> Iterator[int]:
        """The client: its own chunks while any is left, then what the pool finishes."""
        ended = False
        with _client_threads(self.ex.threads):
            while (j := self.claim()) is not None:
                yield from self.run_own(j)
                while not ended:  # what the pool finished meanwhile: the bar moves
                    try:
                        item = self.done.get_nowait()
                    except queue.Empty:
                        break
                    ended = item is None
                    if item is not None:
                        yield from self.take(item)
        while not ended:
            try:
                item = self.done.get(timeout=0.2)  # a timeout: Ctrl-C is seen while waiting
            except queue.Empty:
                continue
            ended = item is None
            if item is not None:
                yield from self.take(item)


def _apply_chunk(fn: Callable[[Any], Any], chunk: Sequence[Any]) -> list[Any]:
    return [fn(x) for x in chunk]


def _pool_cpu(pool: ProcessPoolExecutor) -> dict[int, float]:
    """CPU seconds (user + system) of each live process of ``pool``, from ``/proc`` (Linux)."""
    out: dict[int, float] = {}
    try:
        tick = os.sysconf("SC_CLK_TCK")
        for pid in list(getattr(pool, "_processes", None) or {}):
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            out[pid] = (int(fields[11]) + int(fields[12])) / tick
    except (OSError, ValueError, IndexError):
        pass
    return out
