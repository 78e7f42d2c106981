from __future__ import annotations

from importlib import metadata

import pytest

from mocapflow.framework import Analysis, PluginError, get_plugin_manager, hookimpl
from mocapflow.framework.plugins import build_registries
from mocapflow.framework.registry import Registries


class Dup(Analysis):
    """A component whose name clashes with a built-in."""

    name = "clip_summary"


class NoName(Analysis):
    """A component without a name."""


class DupPlugin:
    @hookimpl
    def register_analyses(self):
        return [Dup]


class BrokenPlugin:
    @hookimpl
    def register_features(self):
        raise RuntimeError("boom")


class NoNamePlugin:
    @hookimpl
    def register_analyses(self):
        return [NoName]


def test_duplicate_names_both_providers():
    pm = get_plugin_manager(entry_points=False)
    pm.register(DupPlugin(), name="dup-plugin")
    with pytest.raises(PluginError) as err:
        build_registries(pm)
    assert "dup-plugin" in str(err.value) and "mocapflow.plugins.analyses.summary" in str(err.value)


def test_plugin_raising_in_hook_is_named():
    pm = get_plugin_manager(entry_points=False)
    pm.register(BrokenPlugin(), name="broken-one")
    with pytest.raises(PluginError, match="broken-one.*register_features.*boom"):
        build_registries(pm)


def test_component_without_name_is_rejected():
    pm = get_plugin_manager(entry_points=False)
    pm.register(NoNamePlugin(), name="nameless")
    with pytest.raises(PluginError, match="nameless"):
        build_registries(pm)


def test_fresh_managers_do_not_share_state():
    a = get_plugin_manager(entry_points=False, extra=[DupPlugin()])
    b = get_plugin_manager(entry_points=False)
    assert len(a.get_plugins()) == len(b.get_plugins()) + 1
    assert isinstance(build_registries(b), Registries)


def test_blocked_builtin_is_not_loaded():
    pm = get_plugin_manager(entry_points=False, blocked=["mocapflow.plugins.analyses.summary"])
    assert "clip_summary" not in build_registries(pm)["analyses"]


def test_broken_entry_point_is_recorded_not_raised(monkeypatch):
    ep = metadata.EntryPoint(name="broken-ep", value="surely_missing_module_xyz:plugin", group="mocapflow")

    def fake(group=None, **kw):
        return [ep] if group == "mocapflow" else []

    monkeypatch.setattr(metadata, "entry_points", fake)
    pm = get_plugin_manager()
    assert [f.plugin for f in pm.failures] == ["broken-ep"]
    build_registries(pm)  # unrelated work goes on
    with pytest.raises(PluginError, match="broken-ep.*failed to load"):
        build_registries(pm, strict=True)


def test_unknown_component_suggests():
    regs = build_registries(get_plugin_manager(entry_points=False))
    with pytest.raises(Exception, match="did you mean 'analyses.clip_summary'"):
        regs.resolve("analyses.clip_sumary")


def test_hook_docs_are_in_step_with_hookspecs():
    """docs/hooks.md is exactly what docs/make_hooks_md.py renders from framework/hookspecs.py."""
    import importlib.util
    from pathlib import Path

    docs = Path(__file__).resolve().parent.parent / "docs"
    spec = importlib.util.spec_from_file_location("make_hooks_md", docs / "make_hooks_md.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert (docs / "hooks.md").read_text() == mod.render(), "run `python docs/make_hooks_md.py`"
