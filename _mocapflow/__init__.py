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
