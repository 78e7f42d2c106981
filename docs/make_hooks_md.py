"""Regenerate docs/hooks.md from framework/hookspecs.py: ``python docs/make_hooks_md.py``."""

from __future__ import annotations

import inspect
import textwrap
from pathlib import Path

from mocapflow.framework import hookspecs


def render() -> str:
    out = [
        "# Hooks",
        "",
        "Generated from `framework/hookspecs.py` by `docs/make_hooks_md.py` (its docstrings are the "
        "contract; `tests/framework/test_plugins.py` keeps this page in step).",
        "",
        textwrap.dedent(hookspecs.__doc__).strip(),
        "",
    ]
    for name, fn in inspect.getmembers(hookspecs, inspect.isfunction):
        if hasattr(fn, "mocapflow_spec"):
            out += [f"## `{name}{inspect.signature(fn)}`", "", textwrap.dedent("    " + fn.__doc__).strip(), ""]
    return "\n".join(out)


if __name__ == "__main__":
    Path(__file__).with_name("hooks.md").write_text(render())
