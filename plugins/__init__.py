"""Built-in plugins of mocapflow.

Each module listed here is a pluggy plugin using exactly the hooks of
:mod:`mocapflow.framework.hookspecs`, as a third-party package would.
To add a built-in, add its module name to this tuple (one line per module).
"""
from __future__ import annotations

BUILTIN_PLUGINS: tuple[str, ...] = (
    "mocapflow.plugins.executors",
    "mocapflow.plugins.formats",
    "mocapflow.plugins.features.relational_plugin",
    "mocapflow.plugins.indexes.kdtree",
    "mocapflow.plugins.indexes.sharded",
    "mocapflow.plugins.features.krueger",
    "mocapflow.plugins.analyses.correlation",
    "mocapflow.plugins.analyses.knn_query",
    "mocapflow.plugins.matchers.matching_plugin",
    "mocapflow.plugins.formats.steps",
    "mocapflow.plugins.analyses.summary",
    "mocapflow.plugins.analyses.krueger_apps_plugin",
    "mocapflow.plugins.cleaners.plugin",
    "mocapflow.plugins.report.plugin",
)
