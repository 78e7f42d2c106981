"""The Python API of ``mocapflow`` (``read``, ``write``, ``features``, ``Database``,
``Matches``, ``clean``, ``registries``). Its code lives in :mod:`mocapflow.framework.api`,
type-checked with the core; this module re-exports it."""

from mocapflow.framework.api import (
    RENAMED_COLUMNS,
    Database,
    Matches,
    clean,
    features,
    read,
    registries,
    write,
)

__all__ = ["RENAMED_COLUMNS", "Database", "Matches", "clean", "features", "read", "registries", "write"]
