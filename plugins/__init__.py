"""Built-in plugins of mocapflow.

Each module listed here is a pluggy plugin using exactly the hooks of
:mod:`mocapflow.framework.hookspecs`, as a third-party package would.
Built-ins are packaged by capability (one package per paper, plus formats, executors,
generic analyses and the report); each package registers its components from its own
``plugin`` module. To add a built-in package, add its ``plugin`` module here. A package never
imports another package's modules (``tests/repo/test_package_boundaries.py``): cross-package use
goes through :mod:`mocapflow.framework` or the registries.
"""

from __future__ import annotations

BUILTIN_PLUGINS: tuple[str, ...] = (
    "mocapflow.plugins.executors.plugin",
    "mocapflow.plugins.formats.plugin",
    "mocapflow.plugins.similarity.plugin",
    "mocapflow.plugins.relational.plugin",
    "mocapflow.plugins.selfsim.plugin",
    "mocapflow.plugins.analyses.plugin",
    "mocapflow.plugins.report.plugin",
)
