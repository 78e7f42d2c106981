"""The core type-checks strictly: ``mypy`` with the configuration of pyproject.toml
(``[tool.mypy]``: ``framework/``, strict); so do the built-in plugins (``--strict`` with
tests/mypy-plugins.ini, against the core's types). Skipped only where mypy is not installed
(it is in the ``test`` extra, so CI runs it)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def test_framework_type_checks_strictly():
    pytest.importorskip("mypy")
    out = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr


def _package_tree(into: Path) -> Path:
    """``into/mocapflow``: the installed package's layout (pyproject's package-dir) as symbolic
    links to the checkout, so mypy follows ``mocapflow.*`` imports into the core's own code."""
    pkg = into / "mocapflow"
    pkg.mkdir()
    for f in (ROOT / "_mocapflow").glob("*.py"):
        (pkg / f.name).symlink_to(f)
    for name in ("framework", "plugins"):
        (pkg / name).symlink_to(ROOT / name, target_is_directory=True)
    return into


def test_plugins_type_check_strictly_against_the_core(tmp_path):
    """mypy ``--strict`` over plugins/ (tests/mypy-plugins.ini: imports of the core followed, so a
    plugin's calls into it and ``self.params`` are checked) finds no error: plugins are as
    strict as the core."""
    pytest.importorskip("mypy")
    cmd = [
        sys.executable,
        "-m",
        "mypy",
        "--config-file",
        str(ROOT / "tests" / "mypy-plugins.ini"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "-p",
        "mocapflow.plugins",
    ]
    out = subprocess.run(cmd, cwd=_package_tree(tmp_path), capture_output=True, text=True, timeout=600)
    errors = [ln.removeprefix("mocapflow/") for ln in out.stdout.splitlines() if ": error:" in ln]
    assert not errors and out.returncode == 0, "mypy --strict errors in plugins/:\n" + "\n".join(
        errors or [out.stdout, out.stderr]
    )
