"""``executor: dask``: a step's per-clip, per-query and per-shard work as ``dask.distributed`` tasks.

Usage (pipeline YAML)::

    executor: dask
    executor_options: {address: "tcp://scheduler:8786"}   # or MOCAPFLOW_DASK_ADDRESS; none: a LocalCluster

or ``mocapflow run PIPELINE.yaml --executor dask`` (``--jobs N``: the LocalCluster's workers).
Needs the optional extra ``pip install "mocapflow[dask]"`` (dask + distributed).

What travels: the step's function (cloudpickle; a component with its parameters, not its
data) and small references (:class:`~mocapflow.framework.clip_refs.ClipSlice`: a dataset
path, its fingerprint and a clip range), a batch of them as contiguous chunks (about
``chunks_per_worker`` tasks per worker thread, not one task per item). Workers read clips, contexts and index shards
from the workspace's Parquet and ``.npy`` files themselves, so the workspace must be on
storage every worker sees at the same path (a shared filesystem). Results come back to
the client, where the runner writes the step's tables atomically, exactly as with
``local``: a worker never writes a table, so a worker that dies mid-step leaves no
half-written dataset. Its tasks are rescheduled on the surviving workers by the
scheduler (``allowed_failures`` deaths per task), then the step fails with a
:class:`~mocapflow.framework.errors.PipelineError` naming the task.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import multiprocessing
import os
import threading
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from pydantic import Field

from mocapflow.framework.errors import ConfigError, PipelineError
from mocapflow.framework.executors import PRELOAD
from mocapflow.framework.params import Params as BaseParams
from mocapflow.framework.progress import progress
from mocapflow.framework.threads import available_cores, threads_per_worker

ADDRESS_ENV = "MOCAPFLOW_DASK_ADDRESS"


def _require_distributed() -> Any:
    try:
        import distributed
    except ImportError:  # the optional extra
        raise ConfigError('executor "dask" needs dask.distributed: pip install "mocapflow[dask]"') from None
    return distributed


def _apply_all(fn: Callable[[Any], Any], chunk: Sequence[Any]) -> list[Any]:
    """One task: ``fn`` over a contiguous run of items, in order."""
    return [fn(x) for x in chunk]


class DaskExecutor:
    """Runs ``map`` items as tasks on a ``dask.distributed`` cluster.

    ``address``: the scheduler (``tcp://host:8786``; default ``$MOCAPFLOW_DASK_ADDRESS``;
    neither: a LocalCluster of ``jobs`` worker processes on 127.0.0.1, 0 = one per core,
    closed with the executor). ``threads``: numba/BLAS threads per task (default host cores
    / worker threads on it). ``retries``: extra attempts of a task that raised (a mocapflow
    error is raised at once, see :meth:`map`). ``allowed_failures``: LocalCluster only,
    worker deaths a task may cause before it is lost. Batches under ``min_items`` run in the
    client. ``chunks_per_worker``: tasks per worker thread a batch goes out as, each a
    contiguous run of items (a task per item, 0, costs a round trip each: 201 files read
    one task each took 22.8 s where the local pool took 8.5 s).
    """

    name = "dask"

    class Params(BaseParams):
        jobs: int = Field(0, ge=0)
        address: str | None = None
        threads: int | None = Field(None, ge=1)
        retries: int = Field(0, ge=0)
        allowed_failures: int | None = None
        min_items: int = Field(1, ge=0)
        chunks_per_worker: int = Field(4, ge=0)

    params: Params

    def __init__(
        self,
        jobs: int = 0,
        address: str | None = None,
        threads: int | None = None,
        retries: int = 0,
        allowed_failures: int | None = None,
        min_items: int = 1,
        chunks_per_worker: int = 4,
    ) -> None:
        self.jobs = int(jobs) if jobs and jobs > 0 else available_cores()
        self.address = address or os.environ.get(ADDRESS_ENV) or None
        self.threads = threads
        self.retries = int(retries)
        self.allowed_failures = allowed_failures
        self.min_items = int(min_items)
        self.chunks_per_worker = int(chunks_per_worker)
        self._client = None
        self._cluster = None
        self._starting: threading.Thread | None = None
        self._start_error: BaseException | None = None

    # --- connection ---------------------------------------------------------------------
    def start(self) -> None:
        """Begin connecting (or starting the LocalCluster) in a background thread and return
        at once: the runner calls this before it plans, so that the scheduler's and the
        workers' start-up (their interpreters, imports, numba) overlaps the client's own
        (registries, plan, fingerprints, listing inputs). The first :meth:`map` waits for it."""
        if self._client is None and self._starting is None:
            self._starting = threading.Thread(
                target=self._connect_in_background, name="mocapflow-dask-start", daemon=True
            )
            self._starting.start()

    def _connect_in_background(self) -> None:
        try:
            self._connect()
        except BaseException as exc:  # re-raised in the caller's thread by _wait_started
            self._start_error = exc

    def _wait_started(self) -> None:
        if self._starting is not None:
            self._starting.join()
            self._starting = None
            err, self._start_error = self._start_error, None
            if err is not None:
                raise err

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (connects or starts the LocalCluster on first use, or
        waits for :meth:`start`)."""
        self._wait_started()
        if self._client is None:
            self._connect()
        return self._client

    def _connect(self) -> None:
        distributed = _require_distributed()
        import dask

        if self.address:
            try:
                self._client = distributed.Client(self.address, timeout="30s")
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f"executor dask: cannot reach the scheduler at {self.address}: {exc}") from None
        else:
            cfg: dict[str, Any] = (
                {}
                if self.allowed_failures is None
                else {"distributed.scheduler.allowed-failures": self.allowed_failures}
            )
            forkserver = "forkserver" in multiprocessing.get_all_start_methods()
            if forkserver:
                # workers fork from one server that imported distributed, numpy, pyarrow, numba and
                # mocapflow once, instead of each spawning a fresh interpreter that imports them all
                cfg["distributed.worker.multiprocessing-method"] = "forkserver"
            # a cluster of our own reports through our errors, not through its INFO log lines
            logging.getLogger("distributed").setLevel(logging.WARNING)
            with dask.config.set(cfg):
                if forkserver:
                    from distributed.utils import get_mp_context

                    # distributed.utils.get_mp_context has no annotations
                    get_mp_context().set_forkserver_preload(["distributed", *PRELOAD])  # type: ignore[no-untyped-call]
                self._cluster = self._local_cluster(distributed, forkserver)
                self._client = distributed.Client(self._cluster)
        client = self._client
        assert client is not None  # set just above, or start() raised
        hosts: dict[str, int] = {}
        for w in client.scheduler_info(n_workers=-1)["workers"].values():
            hosts[w["host"]] = hosts.get(w["host"], 0) + int(w["nthreads"])
        from ._dask_worker import ThreadLimit

        client.register_plugin(ThreadLimit(self.threads, hosts), name=ThreadLimit.name)

    def _local_cluster(self, distributed: Any, forkserver: bool) -> Any:
        """The LocalCluster of ``jobs`` one-thread worker processes; a cluster that cannot
        start (a worker's nanny failing: its forkserver killed, no memory, no port) is a
        :class:`PipelineError` saying so, never an internal error."""
        try:
            return distributed.LocalCluster(
                n_workers=self.jobs,
                threads_per_worker=1,
                processes=True,
                host="127.0.0.1",
                dashboard_address="127.0.0.1:0",
                silence_logs=40,
                # every worker gets its share of the cores for numba/BLAS (set before their imports)
                env={
                    var: str(self.threads or threads_per_worker(self.jobs))
                    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
                },
            )
        except Exception as exc:
            how = "forked from a forkserver process, " if forkserver else ""
            raise PipelineError(
                f"executor dask: the local cluster of {self.jobs} worker processes ({how}one per job) "
                f"failed to start: {type(exc).__name__}: {exc}; a worker or its forkserver was killed, "
                "memory ran out or no port was free: run again, or use the local executor"
            ) from None

    @property
    def workers(self) -> int:
        """Tasks the cluster runs at once (worker threads)."""
        info = self.client.scheduler_info(n_workers=-1)["workers"]
        return max(1, sum(int(w["nthreads"]) for w in info.values()))

    # --- work ---------------------------------------------------------------------------
    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]:
        """``[fn(x) for x in items]`` as cluster tasks, results in input order.

        A task's own exception is re-raised as it is (a mocapflow error keeps its type and
        message); a task lost with its workers (``KilledWorker``) raises PipelineError.
        """
        items = list(items)
        if len(items) < self.min_items:
            return [fn(x) for x in items]
        distributed = _require_distributed()
        client = self.client
        token = uuid.uuid4().hex[:8]
        label = "".join(c if c.isalnum() or c in "-_" else "-" for c in (desc or "map"))[:40]
        n = len(items) if self.chunks_per_worker <= 0 else min(len(items), self.workers * self.chunks_per_worker)
        cuts = [len(items) * i // n for i in range(n + 1)]
        chunks = [items[a:b] for a, b in zip(cuts[:-1], cuts[1:], strict=True)]
        futures = client.map(
            functools.partial(_apply_all, fn),
            chunks,
            key=[f"{label}-{token}-{i}" for i in range(n)],
            pure=False,
            retries=self.retries,
        )
        try:
            for _ in progress(distributed.as_completed(futures), total=len(futures), desc=desc):
                pass
            return [r for part in client.gather(futures) for r in part]
        except distributed.client.FutureCancelledError as exc:
            raise PipelineError(f"dask: a task of {desc or 'a step'!r} was cancelled: {exc}") from None
        except Exception as exc:
            if type(exc).__name__ == "KilledWorker":
                raise PipelineError(
                    f"dask: the workers running a task of {desc or 'a step'!r} died "
                    f"(killed, out of memory or crashed): {exc}; the step's output was discarded"
                ) from None
            if type(exc).__module__.split(".")[0] in ("distributed", "tornado") or "Nanny" in str(exc):
                # the cluster itself failed (a nanny that cannot restart its worker, a lost
                # connection): named as the executor's failure, not the task's
                raise PipelineError(
                    f"dask: the cluster failed while running {desc or 'a step'!r}: "
                    f"{type(exc).__name__}: {exc}; the step's output was discarded"
                ) from None
            raise
        finally:
            client.cancel([f for f in futures if not f.done()])

    def close(self) -> None:
        with contextlib.suppress(Exception):  # nothing was started, or it failed: nothing to close
            self._wait_started()
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None
