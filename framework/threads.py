"""Numeric threads per process: workers x threads <= cores.

Each worker (and the client while it works a batch) gets ``cores // workers`` threads.
OpenBLAS is sized before NumPy loads (:func:`size_blas_for_workers`): limited only later
by threadpoolctl, ingest readers spent ~12 % more CPU per worker (docs/scale-out.md).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: Environment variables that size the thread pools of OpenMP, OpenBLAS, MKL, numba, numexpr.
THREAD_ENV = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMBA_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def available_cores() -> int:
    """Cores this process may run on (the affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def threads_per_worker(workers: int, cores: int | None = None) -> int:
    """Compute threads per worker so that ``workers x threads <= cores`` (at least 1)."""
    return max(1, (cores or available_cores()) // max(1, workers))


def _numba_pool_running() -> bool:
    """Whether numba's threading layer has started in this process (its size is fixed then)."""
    if "numba" not in sys.modules:
        return False
    from numba.np.ufunc import parallel

    return bool(parallel._is_initialized)


def _set_thread_env(n: int) -> None:
    """:data:`THREAD_ENV` to ``n`` for the pools that load later. Not numba's variable once its
    pool runs: numba re-reads it at every compile and raises when it differs from the running
    pool's size (``set_num_threads`` limits a running pool instead)."""
    running = _numba_pool_running()
    for var in THREAD_ENV:
        if not (running and var == "NUMBA_NUM_THREADS"):
            os.environ[var] = str(n)


def limit_threads(n: int) -> int:
    """Size every numeric thread pool of this process to ``n`` threads (environment for
    later loads, threadpoolctl, numba); returns ``n``. Each worker calls it first."""
    n = max(1, int(n))
    _set_thread_env(n)
    if "numba" in sys.modules:
        import numba

        if not _numba_pool_running():
            numba.config.reload_config()  # what numba.config.NUMBA_NUM_THREADS (and kd-trees) read
        # numba's pool was sized at import; limit the threads this (task-running) thread uses
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    from threadpoolctl import threadpool_limits

    threadpool_limits(n)
    return n


#: The variables OpenBLAS, MKL and Accelerate read once, when they load.
BLAS_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")


def size_blas_for_workers(jobs: int, cores: int | None = None) -> bool:
    """Before NumPy loads, size BLAS to ``cores // jobs`` when ``jobs > 1`` local workers
    will fork; whether it did (not after NumPy loaded, nor over a user's :data:`BLAS_ENV`)."""
    jobs = int(jobs or 0)
    if jobs == 0:
        jobs = available_cores()
    if jobs <= 1 or "numpy" in sys.modules or any(v in os.environ for v in BLAS_ENV):
        return False
    n = str(threads_per_worker(jobs, cores))
    for var in BLAS_ENV:
        os.environ[var] = n
    return True


def workers_on_this_host(pipeline: str, jobs: int | None) -> int:
    """Worker processes a run starts on this host (``jobs``, else the pipeline's, for a local
    executor or a dask LocalCluster; else 1), read with PyYAML alone (no NumPy yet)."""
    try:
        import yaml

        if not os.path.isfile(pipeline):  # a FIFO would block here; the loader says what is wrong
            return 1
        with open(pipeline, encoding="utf-8") as f:
            doc = yaml.safe_load(f)
        doc = doc if isinstance(doc, dict) else {}
        executor, options = doc.get("executor", "local"), doc.get("executor_options") or {}
        remote = executor == "dask" and (
            not isinstance(options, dict) or options.get("address") or os.environ.get("MOCAPFLOW_DASK_ADDRESS")
        )
        if executor not in ("local", "dask") or remote:
            return 1
        n = jobs if jobs is not None else doc.get("jobs", 1)
        return int(n) if isinstance(n, int) and not isinstance(n, bool) else 1
    except (OSError, ValueError, yaml.YAMLError):  # the runner reports a bad file properly
        return 1


@contextmanager
def _client_threads(n: int) -> Iterator[None]:
    """The client's numeric threads at a worker's share while it works chunks, restored
    afterwards. Launches numba's threading layer: call only after the pool has forked."""
    import numba

    env = {var: os.environ.get(var) for var in THREAD_ENV}
    before = numba.get_num_threads()
    from threadpoolctl import threadpool_limits

    limiter = threadpool_limits(n)
    try:
        _set_thread_env(n)  # the pool runs (get_num_threads above started it): numba's is kept
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
        yield
    finally:
        limiter.restore_original_limits()
        numba.set_num_threads(before)
        for var, value in env.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
