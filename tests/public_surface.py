"""The public surface of mocapflow, and its committed snapshot (the deprecation policy,
docs/pipelines.md "Deprecation policy"; ``tests/repo/test_public_surface.py`` enforces it).

    python tests/public_surface.py            # what was removed or added since the snapshot
    python tests/public_surface.py --write    # record the current surface (after adding names)

Three sections, each a sorted list of names:

* ``facade``: the names of ``mocapflow`` and ``mocapflow.framework`` (their ``__all__``), each
  callable's parameters (``mocapflow.read(path)``) and each class's public members and their
  parameters (``mocapflow.Motion.slice(start)``);
* ``cli``: every command and option of ``mocapflow`` (built-in plugins, no entry points),
  ``mocapflow search --db``; positionals by their name;
* ``components``: every registered component's parameters, ``matchers.lng.k``; a parameter
  removed with a shim (``Params.removed``) still counts.
"""

from __future__ import annotations

import argparse
import inspect
import json
import sys
from pathlib import Path
from typing import Any

SNAPSHOT = Path(__file__).resolve().parents[1] / "tests" / "data" / "public_surface.json"


def _params(obj: Any) -> list[str]:
    try:
        sig = inspect.signature(obj)
    except (TypeError, ValueError):
        return []
    return [p for p in sig.parameters if p not in ("self", "cls") and not p.startswith("_")]


def facade() -> list[str]:
    import importlib

    out: set[str] = set()
    for modname in ("mocapflow", "mocapflow.framework"):
        mod = importlib.import_module(modname)
        for name in getattr(mod, "__all__", []):
            if name.startswith("_"):
                continue
            obj = getattr(mod, name)
            full = f"{modname}.{name}"
            out.add(full)
            if inspect.isclass(obj):
                for member, value in inspect.getmembers(obj):
                    if member.startswith("_") or member in ("model_config", "model_fields", "model_computed_fields"):
                        continue
                    if _pydantic_internal(obj, member):
                        continue
                    out.add(f"{full}.{member}")
                    if callable(value) and not inspect.isclass(value):
                        out.update(f"{full}.{member}({p})" for p in _params(value))
                if "__init__" in vars(obj) or _is_dataclass(obj):
                    out.update(f"{full}({p})" for p in _params(obj))
            elif callable(obj):
                out.update(f"{full}({p})" for p in _params(obj))
    return sorted(out)


def _is_dataclass(cls: type) -> bool:
    import dataclasses

    return dataclasses.is_dataclass(cls)


def _pydantic_internal(cls: type, member: str) -> bool:
    """Members every pydantic model has (``model_dump``...): pydantic's surface, not ours."""
    try:
        from pydantic import BaseModel
    except ImportError:  # pragma: no cover
        return False
    return isinstance(cls, type) and issubclass(cls, BaseModel) and hasattr(BaseModel, member)


def cli() -> list[str]:
    from mocapflow.framework.cli import _plugin_commands, build_parser
    from mocapflow.framework.plugins import get_plugin_manager

    parser = build_parser(_plugin_commands(get_plugin_manager(entry_points=False)))
    out: set[str] = set()

    def options(prefix: str, p: argparse.ArgumentParser) -> None:
        for action in p._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    out.add(f"{prefix} {name}")
                    options(f"{prefix} {name}", sub)
            elif isinstance(action, argparse._HelpAction):
                continue
            elif action.option_strings:
                out.update(f"{prefix} {o}" for o in action.option_strings)
            else:
                out.add(f"{prefix} <{action.dest}>")

    options("mocapflow", parser)
    return sorted(out)


def components() -> list[str]:
    from mocapflow.framework.plugins import build_registries, get_plugin_manager

    regs = build_registries(get_plugin_manager(entry_points=False))
    out: set[str] = set()
    for kind, registry in regs.by_kind.items():
        for name, cls in registry:
            key = f"{kind}.{name}"
            out.add(key)
            params = getattr(cls, "Params", None)
            if params is None or not hasattr(params, "model_fields"):
                continue
            out.update(f"{key}.{p}" for p in params.model_fields)
            out.update(f"{key}.{p}" for p in getattr(params, "removed", {}) or {})
    return sorted(out)


def surface() -> dict[str, list[str]]:
    return {"facade": facade(), "cli": cli(), "components": components()}


def diff(old: dict[str, list[str]], new: dict[str, list[str]]) -> tuple[dict[str, list[str]], dict[str, list[str]]]:
    """``(removed, added)`` per section."""
    removed = {s: sorted(set(old.get(s, [])) - set(new.get(s, []))) for s in new}
    added = {s: sorted(set(new.get(s, [])) - set(old.get(s, []))) for s in new}
    return removed, added


def write(path: Path = SNAPSHOT) -> None:
    import os
    import tempfile

    text = json.dumps(surface(), indent=1, sort_keys=True) + "\n"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"record the current surface in {SNAPSHOT}")
    args = ap.parse_args(argv)
    if args.write:
        write()
        print(f"wrote {SNAPSHOT}")
        return 0
    removed, added = diff(json.loads(SNAPSHOT.read_text()), surface())
    for what, d in (("removed", removed), ("added", added)):
        for section, names in d.items():
            for n in names:
                print(f"{what:8} {section:11} {n}")
    return 1 if any(removed.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
