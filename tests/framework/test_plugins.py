from __future__ import annotations

from importlib import metadata
from pathlib import Path

import pytest

from mocapflow.framework import Analysis, ConfigError, PluginError, get_plugin_manager, hookimpl
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
    assert "dup-plugin" in str(err.value) and "mocapflow.plugins.analyses.plugin" in str(err.value)


def test_plugin_raising_in_hook_is_named_skipped_and_the_rest_goes_on(caplog):
    pm = get_plugin_manager(entry_points=False)
    pm.register(BrokenPlugin(), name="broken-one")
    regs = build_registries(pm)  # no raise: the others are usable
    assert "end_effectors" in regs["features"] and "local" in regs.executors
    assert [(f.plugin, "register_features" in f.error and "boom" in f.error) for f in pm.failures] == [
        ("broken-one", True)
    ]
    assert "plugin 'broken-one' skipped" in caplog.text and "boom" in caplog.text
    build_registries(pm)
    assert len(pm.failures) == 1 and caplog.text.count("skipped") == 1  # reported once
    with pytest.raises(PluginError, match="broken-one.*register_features.*boom"):
        build_registries(pm, strict=True)


class HalfBrokenPlugin:
    """Registers a good analysis but fails in another hook: none of it is used."""

    @hookimpl
    def register_analyses(self):
        return [Good]

    @hookimpl
    def register_indexes(self):
        return "not a list"


class Good(Analysis):
    """A fine component of a broken plugin."""

    name = "good_one"


def test_a_broken_plugin_is_skipped_entirely():
    pm = get_plugin_manager(entry_points=False, extra=[HalfBrokenPlugin()])
    regs = build_registries(pm)
    assert "good_one" not in regs["analyses"] and "clip_summary" in regs["analyses"]
    assert "must return a list of classes" in pm.failures[0].error


def test_component_without_name_is_rejected():
    pm = get_plugin_manager(entry_points=False)
    pm.register(NoNamePlugin(), name="nameless")
    regs = build_registries(pm)
    assert [f.plugin for f in pm.failures] == ["nameless"] and "snake_case" in pm.failures[0].error
    assert "clip_summary" in regs["analyses"]
    with pytest.raises(PluginError, match="nameless"):
        build_registries(pm, strict=True)


def test_cli_plugins_plan_run_survive_a_plugin_whose_hooks_raise(monkeypatch, tmp_path, capsys, caplog):
    """A third-party plugin raising in every registration hook (components, executors,
    commands) is reported by name and skipped; plugins, plan and run work for everyone."""
    import shutil
    import textwrap

    from mocapflow.framework.cli import main

    ep = metadata.EntryPoint(name="raising-ep", value="toy_components:RAISING", group="mocapflow")
    real = metadata.entry_points

    def fake(group=None, **kw):
        return [ep] if group == "mocapflow" else real(group=group, **kw)

    monkeypatch.setattr(metadata, "entry_points", fake)
    assert main(["plugins"]) == 0
    cap = capsys.readouterr()
    assert "BROKEN plugin 'raising-ep'" in cap.out and "formats.load" in cap.out
    src = next((Path(__file__).resolve().parents[2] / "examples" / "data" / "cmu").rglob("*.bvh"), None)
    if src is None:
        src = next((Path(__file__).resolve().parents[2] / "examples" / "data" / "cmu").rglob("*.amc"))
        for f in src.parent.glob("*.asf"):
            shutil.copy(f, tmp_path)
    shutil.copy(src, tmp_path)
    p = tmp_path / "p.yaml"
    p.write_text(
        textwrap.dedent(f"""
        name: survive
        workspace: ws
        steps:
          motions: {{uses: formats.load, with: {{paths: ["*{src.suffix}"]}}}}
          summary: {{uses: analyses.clip_summary, input: motions}}
    """)
    )
    assert main(["plan", str(p)]) == 0
    assert main(["run", str(p)]) == 0
    cap = capsys.readouterr()
    assert "computed" in cap.out
    assert "plugin 'raising-ep' skipped: failed in register_analyses(): RuntimeError: analyses exploded" in caplog.text
    assert (tmp_path / "ws" / "summary" / "_manifest.json").is_file()


def test_fresh_managers_do_not_share_state():
    a = get_plugin_manager(entry_points=False, extra=[DupPlugin()])
    b = get_plugin_manager(entry_points=False)
    assert len(a.get_plugins()) == len(b.get_plugins()) + 1
    assert isinstance(build_registries(b), Registries)


def test_blocked_builtin_is_not_loaded():
    pm = get_plugin_manager(entry_points=False, blocked=["mocapflow.plugins.analyses.plugin"])
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
    with pytest.raises(ConfigError, match="did you mean 'analyses.clip_summary'"):
        regs.resolve("analyses.clip_sumary")


def test_hook_docs_are_in_step_with_hookspecs():
    """docs/hooks.md is exactly what docs/make_hooks_md.py renders from framework/hookspecs.py."""
    import importlib.util
    from pathlib import Path

    docs = Path(__file__).resolve().parents[2] / "docs"
    spec = importlib.util.spec_from_file_location("make_hooks_md", docs / "make_hooks_md.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert (docs / "hooks.md").read_text() == mod.render(), "run `python docs/make_hooks_md.py`"


@pytest.mark.parametrize(
    "hook, step, committed",
    [
        ("before_step", "plus", False),
        ("after_step", "plus", True),
        ("on_step_error", "boom", False),
    ],
)
def test_lifecycle_hook_errors_are_plugin_errors_naming_the_plugin(tmp_path, hook, step, committed):
    import textwrap

    from toy_components import HookFailures, ToyPlugin

    from mocapflow.framework.runner import run_pipeline

    p = tmp_path / "p.yaml"
    p.write_text(
        textwrap.dedent("""
        name: hooks
        workspace: ws
        steps:
          src: {uses: analyses.toy_source}
          plus: {uses: analyses.toy_add, input: src}
          boom: {uses: analyses.toy_fail, input: plus}
    """)
    )
    pm = get_plugin_manager(entry_points=False, extra=[ToyPlugin()])
    hooks = HookFailures(**{hook: (step,)})
    pm.register(hooks, name="hooky")
    with pytest.raises(PluginError) as err:
        run_pipeline(p, pm=pm)
    msg = str(err.value)
    assert f"plugin 'hooky' failed in {hook}(step_id='{step}'): RuntimeError: {hook} hook broke on {step}" in msg, msg
    if hook == "on_step_error":
        assert "toy failure on purpose" in msg  # the step's own error is not lost
    assert isinstance(err.value.__cause__, RuntimeError) or "toy failure" in str(err.value.__cause__)
    assert (tmp_path / "ws" / step / "_manifest.json").is_file() == committed
    assert not any((tmp_path / "ws" / ".mocapflow").glob("tmp/*"))
