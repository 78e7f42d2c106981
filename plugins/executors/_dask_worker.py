"""Worker-side part of ``executor: dask`` (imports distributed; loaded only when a pipeline uses it)."""

from __future__ import annotations

from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from mocapflow.framework.threads import available_cores, limit_threads


class ThreadLimit(WorkerPlugin):
    """Numba/BLAS/OpenMP threads per task, so that the worker threads of one host times
    the numeric threads per task stay within the host's cores.

    ``threads``: fixed threads per task, None: host cores // worker threads on that host
    (``host_threads``: per host address, from the scheduler when the plugin is registered).
    """

    name = "mocapflow-thread-limit"

    def __init__(self, threads: int | None, host_threads: dict[str, int]) -> None:
        self.threads = threads
        self.host_threads = host_threads

    def setup(self, worker: Any) -> None:
        busy = self.host_threads.get(worker.ip, worker.state.nthreads)
        limit_threads(self.threads or max(1, available_cores() // max(1, busy)))
