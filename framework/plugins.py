"""Building the plugin manager and the registries (never on import)."""
from __future__ import annotations

import importlib
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import metadata

import pluggy

from . import hookspecs
from .errors import PluginError
from .registry import KINDS, Registries

PROJECT = "mocapflow"
ENTRY_POINT_GROUP = "mocapflow"
hookimpl = pluggy.HookimplMarker(PROJECT)


def builtin_plugin_modules() -> tuple[str, ...]:
    """Module names of the built-in plugins (listed in :mod:`mocapflow.plugins`)."""
    from mocapflow.plugins import BUILTIN_PLUGINS

    return BUILTIN_PLUGINS


@dataclass
class PluginFailure:
    """A plugin that could not be loaded; reported, never fatal to unrelated commands."""

    plugin: str
    error: str


def get_plugin_manager(
    *,
    builtins: bool = True,
    entry_points: bool = True,
    blocked: Iterable[str] = (),
    extra: Iterable[object] = (),
) -> pluggy.PluginManager:
    """A fresh plugin manager.

    Parameters
    ----------
    builtins : bool
        Register the built-in plugins of :mod:`mocapflow.plugins`.
    entry_points : bool
        Load third-party plugins from the ``mocapflow`` entry-point group.
    blocked : iterable of str
        Plugin names (module or entry-point names) not to load.
    extra : iterable of objects
        Plugin objects (modules or instances with hookimpls) to register too; handy in tests.

    A third-party plugin that fails to import is recorded in ``pm.failures`` (a list of
    :class:`PluginFailure`) rather than raised, so unrelated commands keep working; the
    registries built from the manager report it.
    """
    pm = pluggy.PluginManager(PROJECT)
    pm.add_hookspecs(hookspecs)
    pm.failures = []  # type: ignore[attr-defined]
    blocked = set(blocked)
    for name in blocked:
        pm.set_blocked(name)
    if builtins:
        for modname in builtin_plugin_modules():
            if modname in blocked:
                continue
            pm.register(importlib.import_module(modname), name=modname)
    if entry_points:
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            if ep.name in blocked or pm.is_blocked(ep.name) or pm.has_plugin(ep.name):
                continue
            try:
                plugin = ep.load()
                pm.register(plugin, name=ep.name)
            except Exception as exc:  # a broken third-party plugin must not break the rest
                pm.failures.append(PluginFailure(ep.name, f"{type(exc).__name__}: {exc}"))  # type: ignore[attr-defined]
    for obj in extra:
        pm.register(obj)
    return pm


def build_registries(pm: pluggy.PluginManager, *, strict: bool = False) -> Registries:
    """Collect every registration hook into :class:`Registries`.

    Each hook implementation is called separately so that a component is attributed to
    the plugin that provided it, and a plugin whose hook raises is named in the error.
    With ``strict`` a plugin that failed to load is an error too.
    """
    if strict and getattr(pm, "failures", None):
        f = pm.failures[0]
        raise PluginError(f"plugin {f.plugin!r} failed to load: {f.error}")
    regs = Registries()
    for kind in KINDS:
        hook = getattr(pm.hook, f"register_{kind}")
        for impl in hook.get_hookimpls():
            provider = pm.get_name(impl.plugin) or repr(impl.plugin)
            try:
                classes = impl.function()
            except Exception as exc:
                raise PluginError(f"plugin {provider!r} failed in register_{kind}(): {type(exc).__name__}: {exc}") from exc
            if classes is None:
                continue
            if not isinstance(classes, (list, tuple)):
                raise PluginError(f"plugin {provider!r}: register_{kind}() must return a list of classes, got {type(classes).__name__}")
            for cls in classes:
                if not isinstance(cls, type):
                    raise PluginError(f"plugin {provider!r}: register_{kind}() returned {cls!r}, not a class")
                regs[kind].add(cls, provider)
    return regs


def load_registries(**kwargs) -> Registries:
    """Shortcut: ``build_registries(get_plugin_manager(**kwargs))``."""
    return build_registries(get_plugin_manager(**kwargs))
