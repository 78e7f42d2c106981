"""Numeric threads per process: workers x threads <= cores.

Each worker of a pool gets ``cores // workers`` threads for numba, OpenBLAS and OpenMP
(:func:`limit_threads`, before its first task); the client, while it works through a
batch's chunks, a worker's share too (:func:`_client_threads`).

OpenBLAS is best sized when it loads (:func:`size_blas_for_workers`, which the CLI calls
before NumPy is imported when a run will fork workers): limited only afterwards (in each
forked worker, by threadpoolctl) to fewer threads than it loaded with, the ingest's readers
spent about 12 % more CPU per worker, and the client's imports about 0.2 s more CPU (its
thread server busy on the other core), measured in
docs/scale-out.md.
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


def limit_threads(n: int) -> int:
    """Size every numeric thread pool of this process to ``n`` threads; returns ``n``.

    Sets the environment (for libraries loaded later), limits already loaded BLAS/OpenMP
    pools with threadpoolctl and numba's pool (its width if not yet launched, else the
    threads it uses). Called in each worker before its first task.
    """
    n = max(1, int(n))
    for var in THREAD_ENV:
        os.environ[var] = str(n)
    if "numba" in sys.modules:
        import numba
        from numba.np.ufunc import parallel

        if not parallel._is_initialized:
            numba.config.reload_config()  # what numba.config.NUMBA_NUM_THREADS (and kd-trees) read
        # numba's pool was sized at import; limit the threads this (task-running) thread uses
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency; env vars still cover later loads
        pass
    else:
        threadpool_limits(n)
    return n


#: The variables OpenBLAS, MKL and Accelerate read once, when they load.
BLAS_ENV = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")


def size_blas_for_workers(jobs: int, cores: int | None = None) -> bool:
    """Before NumPy loads: size the BLAS libraries to a worker's share of the cores
    (``cores // jobs``) when this process will fork ``jobs`` local workers.

    Returns whether it did: not when NumPy is already imported (the library has read its
    variables), when the user set any of :data:`BLAS_ENV`, or when ``jobs <= 1`` (a
    one-process run keeps BLAS as wide as the machine). The client's own BLAS calls then
    run at that width too; its heavy kernels are numba's, whose pool keeps its width.
    """
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
    """The worker processes a run will start on this host: ``jobs`` (``--jobs``), else the
    pipeline's ``jobs:``, with ``executor: local`` or ``executor: dask`` without a scheduler
    address (a LocalCluster beside the client); 1 when unknown, for a remote cluster or
    another executor. Reads the YAML with PyYAML alone: NumPy is not imported yet."""
    try:
        import yaml

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
    """The client's numeric threads at a worker's share (``n``) while it works through
    chunks, restored afterwards (its own kernels between batches use the whole machine).

    Unlike :func:`limit_threads`, numba's pool keeps its width (only the threads this thread
    uses change); called after the pool's processes exist: it launches numba's threading
    layer, after which forking is unsafe (:func:`_fork_is_safe`).
    """
    import numba

    env = {var: os.environ.get(var) for var in THREAD_ENV}
    before = numba.get_num_threads()
    limiter = None
    try:
        for var in THREAD_ENV:
            os.environ[var] = str(n)
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:  # pragma: no cover - a dependency
            pass
        else:
            limiter = threadpool_limits(n)
        yield
    finally:
        if limiter is not None:
            limiter.restore_original_limits()
        numba.set_num_threads(before)
        for var, value in env.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
