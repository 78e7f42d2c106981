"""mocapflow: searchable, clean motion-capture databases.

The top-level package only holds the version (the one place it is written; the build reads
it from here). The core is :mod:`mocapflow.framework`, the built-in plugins are
:mod:`mocapflow.plugins`. Importing this package imports nothing else.

The source of this package lives in ``_mocapflow/`` and not in a ``mocapflow/`` folder: a
``mocapflow/`` folder in the repository root would be found first on ``sys.path`` when Python
runs from the root, and would hide ``mocapflow.framework`` and ``mocapflow.plugins``, which
live in ``framework/`` and ``plugins/``.
"""

__version__ = "0.1.0"

#: The Python API (:mod:`mocapflow.api`), imported on first use.
_API = ("read", "write", "features", "Database", "Matches", "clean", "registries")
__all__ = [*_API, "Motion", "Markers", "__version__"]


def __getattr__(name: str):
    if name in _API:
        from . import api

        return getattr(api, name)
    if name == "Motion":
        from mocapflow.framework.motion import Motion

        return Motion
    if name == "Markers":
        from mocapflow.framework.markers import Markers

        return Markers
    raise AttributeError(f"module 'mocapflow' has no attribute {name!r}")
