"""CLI commands: what a command is, and the one context every command runs with.

A command is a class declared by a plugin's ``register_commands`` hook (built-ins exactly as
third parties): ``name``, ``help``, classmethods ``add_arguments(parser)`` and
``run(args, ctx)``. The CLI builds one :class:`CommandContext` per invocation (as pytest
passes ``config`` to its hooks) from the global switches ``--block`` and
``--no-entry-points``, and every command takes its plugin manager and registries from it,
so a blocked plugin's formats or a third party's readers are seen alike by ``run``,
``search``, ``export``, ``reconstruct`` and ``clean``.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import argparse

    import pluggy

    from .registry import Registries


@dataclass
class CommandContext:
    """What a command runs with: the plugin manager the CLI built (honouring ``--block`` and
    ``--no-entry-points``, kept in ``blocked`` and ``entry_points`` for a command that builds
    its own, e.g. in a server process) and the registries built from it, once per set of
    kinds (:meth:`registries`)."""

    plugin_manager: pluggy.PluginManager
    entry_points: bool = True
    blocked: tuple[str, ...] = ()
    _registries: dict[tuple[str, ...] | None, Registries] = field(default_factory=dict, repr=False)

    @classmethod
    def from_switches(cls, *, entry_points: bool = True, blocked: Iterable[str] = ()) -> CommandContext:
        """The context of ``mocapflow [--no-entry-points] [--block P]...`` (every built-in
        plugin that is not blocked, entry points unless switched off)."""
        from .plugins import get_plugin_manager

        blocked = tuple(blocked)
        return cls(get_plugin_manager(entry_points=entry_points, blocked=list(blocked)), entry_points, blocked)

    def registries(self, kinds: Iterable[str] | None = None) -> Registries:
        """The registries of the plugins (only ``kinds`` when given: a command that needs
        formats alone does not import every matcher), built once per set of kinds."""
        from .plugins import build_registries

        key = tuple(sorted(kinds)) if kinds is not None else None
        if key not in self._registries:
            self._registries[key] = build_registries(self.plugin_manager, kinds=key)
        return self._registries[key]


def context_of(args: argparse.Namespace) -> CommandContext:
    """The context the CLI left on ``args`` (``args.command_context``), or one built from its
    switches (a command class called directly, as in tests)."""
    ctx = getattr(args, "command_context", None)
    if isinstance(ctx, CommandContext):
        return ctx
    pm = getattr(args, "plugin_manager", None)
    entry_points = not getattr(args, "no_entry_points", False)
    blocked = tuple(getattr(args, "block", None) or ())
    if pm is not None:
        return CommandContext(pm, entry_points, blocked)
    return CommandContext.from_switches(entry_points=entry_points, blocked=blocked)


def run_command(cls: type[Any], args: argparse.Namespace, ctx: CommandContext) -> int:
    """``cls.run(args, ctx)``; a command whose ``run`` takes only ``args`` (the form before
    the context) still runs, with a ``DeprecationWarning``, and finds the plugin manager as
    ``args.plugin_manager``."""
    args.command_context, args.plugin_manager = ctx, ctx.plugin_manager
    try:
        n = len(inspect.signature(cls.run).parameters)
    except (TypeError, ValueError):
        n = 2
    if n >= 2:
        code: int = cls.run(args, ctx)
        return code
    warnings.warn(
        f"command {getattr(cls, 'name', cls.__name__)!r}: run(args) is deprecated; declare run(args, ctx) "
        "and take the plugin manager and registries from ctx (mocapflow.framework.commands.CommandContext)",
        DeprecationWarning,
        stacklevel=2,
    )
    code = cls.run(args)
    return code
