"""Built-in executors (``executor: local``), registered through ``register_executors``."""
from __future__ import annotations

from mocapflow.framework.executors import LocalExecutor
from mocapflow.framework.plugins import hookimpl


@hookimpl
def register_executors() -> list[type]:
    return [LocalExecutor]
