"""Built-in packages stay apart: no package of :mod:`mocapflow.plugins` imports a module of
another (cross-package use goes through :mod:`mocapflow.framework` or the registries), and
the core never imports a built-in package. Checked on the source with :mod:`ast`, imports
inside functions included, relative imports resolved."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _module_name(path: Path, top: str, package: str) -> tuple[str, bool]:
    rel = path.relative_to(ROOT / top).with_suffix("")
    parts = [package, *rel.parts]
    is_package = parts[-1] == "__init__"
    return ".".join(parts[:-1] if is_package else parts), is_package


def imported_modules(path: Path, module: str, is_package: bool) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in the file."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base if is_package else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                name = ".".join([*base, *([node.module] if node.module else [])])
            else:
                name = node.module or ""
            # `from pkg import mod` names modules too
            out += [(node.lineno, name)] + [(node.lineno, f"{name}.{a.name}") for a in node.names]
    return out


def _owner(name: str) -> str | None:
    """The built-in package a module name belongs to (``None`` outside the built-ins)."""
    parts = name.split(".")
    if parts[:2] != ["mocapflow", "plugins"] or len(parts) < 3:
        return None
    return parts[2]


def _violations() -> list[str]:
    bad = []
    for path in sorted((ROOT / "plugins").rglob("*.py")):
        module, is_package = _module_name(path, "plugins", "mocapflow.plugins")
        own = _owner(module)
        for line, name in imported_modules(path, module, is_package):
            other = _owner(name)
            if own is not None and other is not None and other != own and (ROOT / "plugins" / other).is_dir():
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    for path in sorted((ROOT / "framework").rglob("*.py")):
        module, is_package = _module_name(path, "framework", "mocapflow.framework")
        for line, name in imported_modules(path, module, is_package):
            # the core only reads the list of built-ins (mocapflow.plugins itself)
            if _owner(name) is not None and (ROOT / "plugins" / _owner(name)).is_dir():
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name}")
    return bad


def test_no_builtin_package_imports_another():
    assert _violations() == []


def test_the_checker_sees_relative_and_function_level_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("def f():\n    from ..formats import bvh\n    from .lng import x\n")
    names = [n for _, n in imported_modules(src, "mocapflow.plugins.similarity.m", False)]
    assert "mocapflow.plugins.formats.bvh" in names and "mocapflow.plugins.similarity.lng" in names
    assert _owner("mocapflow.plugins.formats.bvh") == "formats" and _owner("mocapflow.framework") is None


def test_every_builtin_package_registers_from_its_plugin_module():
    from mocapflow.plugins import BUILTIN_PLUGINS

    packages = sorted(p.name for p in (ROOT / "plugins").iterdir() if (p / "__init__.py").is_file())
    assert sorted(BUILTIN_PLUGINS) == [f"mocapflow.plugins.{p}.plugin" for p in packages]
    hooked = sorted(p.parent.name for p in (ROOT / "plugins").rglob("*.py") if "@hookimpl" in p.read_text())
    assert sorted(set(hooked)) == packages and all(
        "@hookimpl" not in p.read_text() for p in (ROOT / "plugins").rglob("*.py") if p.name != "plugin.py"
    )


#: Where registries may be built from the installed plugins: the CLI (and the commands plugins
#: add to it), the facades and the plugin manager. Everything else receives the run's
#: registries (a step's context, a task's arguments), so that ``--block`` holds everywhere.
REGISTRY_BUILDERS = ("load_registries", "default_registries")
MAY_BUILD = ("framework/cli.py", "framework/__init__.py", "framework/plugins.py", "framework/api.py", "_mocapflow/")


def test_registries_are_built_only_by_the_cli_the_facade_and_the_plugin_manager():
    bad = []
    for top in ("framework", "plugins", "_mocapflow"):
        for path in sorted((ROOT / top).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith(MAY_BUILD) or path.name.endswith("_command.py"):
                continue
            for node in ast.walk(ast.parse(path.read_text(), rel)):
                if isinstance(node, ast.Call):
                    f = node.func
                    name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
                    if name in REGISTRY_BUILDERS:
                        bad.append(f"{rel}:{node.lineno} calls {name}()")
    assert not bad, "registries rebuilt outside the CLI, the facade and the plugin manager:\n" + "\n".join(bad)
