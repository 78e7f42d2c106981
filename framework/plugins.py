"""Building the plugin manager and the registries (never on import)."""

from __future__ import annotations

import functools
import importlib
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from importlib import metadata
from typing import Any

import pluggy

from . import hookspecs
from .errors import PluginError
from .joints import JointMap
from .registry import KINDS, Registries, Registry

PROJECT = "mocapflow"
ENTRY_POINT_GROUP = "mocapflow"
hookimpl = pluggy.HookimplMarker(PROJECT)
log = logging.getLogger("mocapflow")


def builtin_plugin_modules() -> tuple[str, ...]:
    """Module names of the built-in plugins (listed in :mod:`mocapflow.plugins`)."""
    from mocapflow.plugins import BUILTIN_PLUGINS

    return tuple(BUILTIN_PLUGINS)


#: What a plugin may raise at import or in a hook and is isolated like any error (reported by
#: its name, never ending the process with the plugin's own exit status or a silent stop).
PLUGIN_ERRORS: tuple[type[BaseException], ...] = (Exception, SystemExit, KeyboardInterrupt)


def describe(exc: BaseException) -> str:
    """``Type: message`` of a plugin's error (``SystemExit(3)``: its exit status said)."""
    if isinstance(exc, SystemExit):
        return f"SystemExit (exit status {exc.code!r})"
    return f"{type(exc).__name__}: {exc}"


@dataclass
class PluginFailure:
    """A plugin that could not be loaded; reported, never fatal to unrelated commands."""

    plugin: str
    error: str


def _record_failure(pm: pluggy.PluginManager, plugin: str, error: str) -> None:
    """Add a failure to ``pm.failures`` (once) and warn about it (once)."""
    failures = pm.__dict__.setdefault("failures", [])
    if any(f.plugin == plugin and f.error == error for f in failures):
        return
    failures.append(PluginFailure(plugin, error))
    log.warning("plugin %r skipped: %s", plugin, error)


def get_plugin_manager(
    *,
    builtins: bool = True,
    entry_points: bool = True,
    blocked: Iterable[str] = (),
    extra: Iterable[object] = (),
) -> pluggy.PluginManager:
    """A fresh plugin manager with the built-ins, the ``mocapflow`` entry points and
    ``extra`` plugin objects, none of ``blocked``. A plugin that fails to import is recorded
    in ``pm.failures`` and warned about, never raised, so unrelated commands keep working."""
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
            except PLUGIN_ERRORS as exc:  # a broken third-party plugin must not break the rest
                _record_failure(pm, ep.name, f"failed to load: {describe(exc)}")
    for obj in extra:
        pm.register(obj)
    return pm


def _provider(pm: pluggy.PluginManager, impl: Any) -> str:
    return pm.get_name(impl.plugin) or repr(impl.plugin)


def collect_classes(
    pm: pluggy.PluginManager,
    hook_name: str,
    check: Callable[[Any, str], None] | None = None,
    item: type = type,
) -> tuple[list[tuple[str, list[Any]]], dict[str, str]]:
    """Call one registration hook plugin by plugin: ``(plugin name, items)`` for each whose
    hook returned a list of ``item`` instances (classes; :class:`JointMap`) passing
    ``check(obj, plugin)``, and ``plugin name -> what went wrong`` for the others. Nothing
    is raised, so one broken plugin never stops the others."""
    results: list[tuple[str, list[Any]]] = []
    failed: dict[str, str] = {}
    what = "classes" if item is type else item.__name__
    for impl in getattr(pm.hook, hook_name).get_hookimpls():
        provider = _provider(pm, impl)
        try:
            classes = impl.function()
            if classes is None:
                continue
            if not isinstance(classes, (list, tuple)):
                raise PluginError(f"{hook_name}() must return a list of {what}, got {type(classes).__name__}")
            for cls in classes:
                if not isinstance(cls, item):
                    raise PluginError(f"{hook_name}() returned {cls!r:.80}, not a {what}")
                if check is not None:
                    check(cls, provider)
        except PluginError as exc:
            failed[provider] = f"{hook_name}(): {exc}"
        except PLUGIN_ERRORS as exc:
            failed[provider] = f"failed in {hook_name}(): {describe(exc)}"
        else:
            results.append((provider, list(classes)))
    return results, failed


def build_registries(
    pm: pluggy.PluginManager, *, strict: bool = False, kinds: Iterable[str] | None = None
) -> Registries:
    """Collect every registration hook into :class:`Registries`, each component attributed
    to its plugin. A plugin with a failing hook or an invalid class is skipped entirely,
    recorded in ``pm.failures`` and warned about (``strict``: a :class:`PluginError`); two
    plugins registering one name are always an error. ``kinds`` calls only those kinds'
    hooks (joint maps always), so a command imports only the modules it needs."""
    wanted = None if kinds is None else set(kinds)
    regs = Registries()
    pending: list[tuple[Registry, str, list[type[Any]]]] = []
    failed: dict[str, str] = {}
    for kind in KINDS:
        if wanted is not None and kind not in wanted:
            continue
        results, bad = collect_classes(pm, f"register_{kind}", regs[kind].check)
        pending += [(regs[kind], provider, classes) for provider, classes in results]
        failed.update({p: e for p, e in bad.items() if p not in failed})
    if wanted is None or "executors" in wanted:
        results, bad = collect_classes(pm, "register_executors", regs.executors.check)
        pending += [(regs.executors, provider, classes) for provider, classes in results]
        failed.update({p: e for p, e in bad.items() if p not in failed})
    maps, bad = collect_classes(pm, "register_joint_maps", item=JointMap)
    failed.update({p: e for p, e in bad.items() if p not in failed})
    for plugin, error in failed.items():
        _record_failure(pm, plugin, error)
    failures: list[PluginFailure] = getattr(pm, "failures", [])
    if strict and failures:
        f = failures[0]
        raise PluginError(f"plugin {f.plugin!r}: {f.error}")
    for registry, provider, classes in pending:
        if provider not in failed:
            for cls in classes:
                registry.add(cls, provider)
    for provider, jmaps in maps:
        if provider not in failed:
            for m in jmaps:
                if m.name in regs.joint_maps:
                    raise PluginError(
                        f"joint map {m.name!r} registered by both {regs.joint_map_providers[m.name]!r} and {provider!r}"
                    )
                regs.joint_maps[m.name] = m
                regs.joint_map_providers[m.name] = provider
    install_joint_maps(regs.joint_maps.values())
    return regs


_JOINT_MAPS: dict[str, JointMap] = {}


def install_joint_maps(maps: Iterable[JointMap]) -> None:
    """Make dialects known to :func:`registered_joint_maps` in this process."""
    for m in maps:
        _JOINT_MAPS[m.name] = m


def registered_joint_maps() -> tuple[JointMap, ...]:
    """The naming dialects registered in this process (built with the registries the first
    time, so a reader called on its own sees the plugins' dialects too)."""
    if not _JOINT_MAPS:
        default_registries()  # installs them; the same build the facade uses later
    return tuple(_JOINT_MAPS.values())


def plugin_commands(pm: pluggy.PluginManager) -> list[type[Any]]:
    """CLI command classes of ``register_commands`` (a failing plugin is recorded and skipped)."""
    results, failed = collect_classes(pm, "register_commands")
    for plugin, error in failed.items():
        _record_failure(pm, plugin, error)
    return [cls for _, classes in results for cls in classes]


def call_lifecycle(hook_relay: Any, hook_name: str, **kwargs: Any) -> None:
    """Call a lifecycle hook plugin by plugin in pluggy's order; one that raises becomes a
    :class:`PluginError` naming its plugin (with hook wrappers pluggy drives the call and
    the error names every implementing plugin)."""
    caller = getattr(hook_relay, hook_name)
    impls = caller.get_hookimpls()
    what = f"{hook_name}({', '.join(f'{k}={v!r}' for k, v in kwargs.items() if k == 'step_id')})"
    if any(i.wrapper or i.hookwrapper for i in impls):
        try:
            caller(**kwargs)
        except PLUGIN_ERRORS as exc:
            names = ", ".join(sorted({repr(i.plugin_name) for i in impls}))
            raise PluginError(f"a plugin failed in {what} (one of {names}): {describe(exc)}") from exc
        return
    for impl in reversed(impls):  # pluggy calls the last registered (and tryfirst) first
        try:
            impl.function(*[kwargs[a] for a in impl.argnames])
        except PLUGIN_ERRORS as exc:
            raise PluginError(f"plugin {impl.plugin_name!r} failed in {what}: {describe(exc)}") from exc


def load_registries(*, kinds: Iterable[str] | None = None, **kwargs: Any) -> Registries:
    """Shortcut: ``build_registries(get_plugin_manager(**kwargs), kinds=kinds)``."""
    return build_registries(get_plugin_manager(**kwargs), kinds=kinds)


@functools.lru_cache(maxsize=1)
def default_registries() -> Registries:
    """The registries of every installed plugin, built once per process."""
    return load_registries()
