"""Every hook of mocapflow, in one place; the docstrings are the contract.

Plugins implement them with ``@mocapflow.framework.hookimpl``; built-ins use the same hooks
as third-party packages (entry-point group ``mocapflow``). Registration hooks collect every
plugin's result; a name registered twice in one kind is an error naming both plugins; a
plugin whose hook raises or returns invalid classes is skipped and reported by name.
Lifecycle hooks are notifications; one that raises stops the run with a ``PluginError``.
"""

from __future__ import annotations

from typing import Any

import pluggy

hookspec = pluggy.HookspecMarker("mocapflow")


@hookspec
def register_formats() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Format` subclasses (keys ``formats.<name>``)."""


@hookspec
def register_features() -> list[type]:
    """Return :class:`~mocapflow.framework.components.FeatureSet` subclasses (``features.<name>``)."""


@hookspec
def register_indexes() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Index` subclasses (``indexes.<name>``)."""


@hookspec
def register_matchers() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Matcher` subclasses (``matchers.<name>``)."""


@hookspec
def register_cleaners() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Cleaner` subclasses (``cleaners.<name>``)."""


@hookspec
def register_analyses() -> list[type]:
    """Return :class:`~mocapflow.framework.components.Analysis` subclasses (``analyses.<name>``)."""


@hookspec
def register_joint_maps() -> list[Any]:
    """Return skeleton naming dialects (:class:`~mocapflow.framework.joints.JointMap`), unique
    by name; readers map each skeleton through the dialect mapping the most required joints."""


@hookspec
def register_executors() -> list[type]:
    """Return executor classes: ``name`` (``executor:`` in a pipeline), built as
    ``cls(jobs=N, **executor_options)``, with ``map(fn, items, desc) -> list`` (input order)
    and ``close()``."""


@hookspec
def register_commands() -> list[type]:
    """Return CLI sub-command classes: ``name``, ``help`` (one line), classmethods
    ``add_arguments(parser)`` and ``run(args, ctx) -> int``, where ``ctx`` is the
    :class:`~mocapflow.framework.commands.CommandContext` the CLI built (plugin manager and
    registries honouring ``--block`` and ``--no-entry-points``); raise ``MocapflowError`` for
    user errors (printed without a traceback). ``run(args)`` still works for one release, with
    a ``DeprecationWarning``. Clashing with a built-in is a ``PluginError``. The module
    implementing this hook is imported for ``mocapflow --help``: keep its imports light."""


@hookspec
def before_step(step_id: str, component: object, workspace: str) -> None:
    """Called just before a step computes (not when up to date); if it raises, the step is not computed."""


@hookspec
def after_step(step_id: str, component: object, workspace: str, output_dir: str, seconds: float) -> None:
    """Called after a step's output was committed atomically to ``output_dir``;
    ``seconds`` is its wall-clock compute time. If it raises, the output stays committed."""


@hookspec
def on_step_error(step_id: str, component: object, error: BaseException) -> None:
    """Called when a step raised; the run then stops with a ``PipelineError``."""
