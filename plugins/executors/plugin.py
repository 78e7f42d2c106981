"""Built-in executors, registered through ``register_executors``: ``executor: local`` (in-process
or a process pool) and ``executor: dask`` (a dask.distributed cluster; the optional extra
``mocapflow[dask]``, imported only when a pipeline uses it)."""

from __future__ import annotations

from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_executors() -> list[type]:
    from mocapflow.framework.executors import LocalExecutor

    from .dask_cluster import DaskExecutor

    return [LocalExecutor, DaskExecutor]
