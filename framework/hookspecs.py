"""Every hook of mocapflow, in one place; the docstrings are the contract.

Plugins implement hooks with ``@mocapflow.framework.hookimpl``. Built-in plugins
(:mod:`mocapflow.plugins`) use exactly the same hooks as third-party packages, which are
discovered through the entry-point group ``mocapflow``.

Registration hooks are *collecting* hooks: every plugin's result is used (pluggy returns
a list of lists; the manager flattens it). A component name registered twice in one kind
is an error naming both plugins. A plugin whose registration hook raises or returns
something other than a list of valid classes is skipped entirely and reported by name (a
warning, ``pm.failures``, ``mocapflow plugins``), so the other plugins keep working.

Lifecycle hooks are notifications: their return values are ignored, and an exception raised
by one stops the run as a ``PluginError`` naming the plugin and the hook (the original
exception is its cause).
"""

from __future__ import annotations

from typing import Any

import pluggy

hookspec = pluggy.HookspecMarker("mocapflow")


@hookspec
def register_formats() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Format` subclasses (readers/writers and
    ingest/export steps). Called once when registries are built. Each class carries its own
    ``name``; the registry key is ``formats.<name>``."""


@hookspec
def register_features() -> list[type]:
    """Return :class:`~mocapflow.framework.components.FeatureSet` subclasses. Called once when
    registries are built; keys are ``features.<name>``."""


@hookspec
def register_indexes() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Index` subclasses. Called once when
    registries are built; keys are ``indexes.<name>``."""


@hookspec
def register_matchers() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Matcher` subclasses. Called once when
    registries are built; keys are ``matchers.<name>``."""


@hookspec
def register_cleaners() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Cleaner` subclasses. Called once when
    registries are built; keys are ``cleaners.<name>``."""


@hookspec
def register_analyses() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Analysis` subclasses: steps that fit none
    of the other kinds (reconstruction, base poses, studies, evaluation). Keys are
    ``analyses.<name>``."""


@hookspec
def register_joint_maps() -> list[Any]:
    """Return skeleton naming dialects (:class:`~mocapflow.framework.joints.JointMap`
    instances): for each canonical joint, the source joint names that stand for it. Readers
    map every skeleton through the dialect that maps the most required joints
    (:func:`~mocapflow.framework.joints.canonical_map`), so a plugin adds support for a
    new skeleton naming (Mixamo, a studio's rig...) without touching the core. Dialect
    names must be unique across plugins; a plugin returning anything else is skipped and
    reported like a failed registration hook."""


@hookspec
def register_executors() -> list[type]:
    """Return executor classes: how steps fan out per-clip work. Each class has ``name``
    (the value of ``executor:`` in a pipeline), is built as ``cls(jobs=N, **executor_options)``
    and provides ``map(fn, items, desc) -> list`` (results in input order) and ``close()``.
    The runner knows nothing else about them, so a cluster executor (e.g. dask.distributed)
    plugs in without touching it. Names must be unique across plugins."""


@hookspec
def register_commands() -> list[type]:
    """Return CLI command classes added to ``mocapflow`` as sub-commands (``mocapflow search``,
    ``mocapflow clean``...). Each class has ``name`` (str), ``help`` (one line),
    ``add_arguments(parser)`` (classmethod, argparse) and ``run(args) -> int`` (classmethod,
    the exit code; raise :class:`~mocapflow.framework.errors.MocapflowError` subclasses for
    user errors, the CLI prints them without a traceback unless ``--debug``). Collected
    once when the CLI starts; a name clash with a built-in command is a ``PluginError``."""


@hookspec
def before_step(step_id: str, component: object, workspace: str) -> None:
    """Called by the runner just before a step computes (not when it is skipped as
    up to date). ``component`` is the configured component instance. If it raises, the
    step is not computed."""


@hookspec
def after_step(step_id: str, component: object, workspace: str, output_dir: str, seconds: float) -> None:
    """Called after a step's output was committed atomically to ``output_dir``;
    ``seconds`` is its wall-clock compute time. If it raises, the output stays committed."""


@hookspec
def on_step_error(step_id: str, component: object, error: BaseException) -> None:
    """Called when a step raised; the run then stops with a ``PipelineError``. Nothing of
    the failed step's output is left behind. If it raises, the ``PluginError`` also quotes
    the step's error."""
