"""The core type-checks strictly: ``mypy`` with the configuration of pyproject.toml
(``[tool.mypy]``: ``framework/``, strict). Skipped only where mypy is not installed (it is
in the ``test`` extra, so CI runs it)."""

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


def test_plugins_type_check_against_the_core_and_untyped_defs_only_go_down(tmp_path):
    """mypy over plugins/ (tests/mypy-plugins.ini: imports of the core followed, so a plugin's
    calls into it and ``self.params`` are checked; bodies of unannotated functions too) finds no
    error, and with ``--disallow-untyped-defs`` no file has more functions without annotations
    than tests/mypy_plugins_untyped.json records (a file that got better lowers it: the way to
    ``strict``)."""
    import json
    import re

    pytest.importorskip("mypy")
    cmd = [
        sys.executable,
        "-m",
        "mypy",
        "--config-file",
        str(ROOT / "tests" / "mypy-plugins.ini"),
        "--cache-dir",
        str(tmp_path / "cache"),
        "--disallow-untyped-defs",
        "-p",
        "mocapflow.plugins",
    ]
    out = subprocess.run(cmd, cwd=_package_tree(tmp_path), capture_output=True, text=True, timeout=600)
    errors = [ln.removeprefix("mocapflow/") for ln in out.stdout.splitlines() if ": error:" in ln]
    wrong = [ln for ln in errors if not ln.endswith("[no-untyped-def]")]
    assert not wrong and out.returncode in (0, 1), "mypy errors in plugins/:\n" + "\n".join(
        wrong or [out.stdout, out.stderr]
    )
    found: dict[str, int] = {}
    for line in errors:
        m = re.match(r"^(plugins/[^:]+\.py):\d+: error:", line)
        assert m, line
        found[m[1]] = found.get(m[1], 0) + 1
    base = json.loads((ROOT / "tests" / "mypy_plugins_untyped.json").read_text())
    worse = {f: (n, base.get(f, 0)) for f, n in found.items() if n > base.get(f, 0)}
    assert not worse, "functions without annotations (file: now, recorded):\n" + "\n".join(
        [f"{f}: {a}, {b}" for f, (a, b) in sorted(worse.items())]
        + [line for line in errors if line.split(":")[0] in worse]
    )
    better = {f: (found.get(f, 0), n) for f, n in base.items() if found.get(f, 0) < n}
    assert not better, f"fewer unannotated functions than recorded: lower tests/mypy_plugins_untyped.json: {better}"
