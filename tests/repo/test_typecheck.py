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


def test_plugins_type_check_without_new_errors():
    """mypy over plugins/ (tests/mypy-plugins.ini, not strict yet): no file has more errors
    than tests/mypy_plugins_baseline.json records, and a file that got better lowers it."""
    import json
    import re

    pytest.importorskip("mypy")
    cmd = [sys.executable, "-m", "mypy", "--config-file", "tests/mypy-plugins.ini", "plugins"]
    out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    found: dict[str, int] = {}
    for line in out.stdout.splitlines():
        m = re.match(r"^(plugins/[^:]+\.py):\d+: error:", line)
        if m:
            found[m[1]] = found.get(m[1], 0) + 1
    base = json.loads((ROOT / "tests" / "mypy_plugins_baseline.json").read_text())
    worse = {f: (n, base.get(f, 0)) for f, n in found.items() if n > base.get(f, 0)}
    assert not worse, "new mypy errors (file: now, baseline):\n" + "\n".join(
        [f"{f}: {a}, {b}" for f, (a, b) in sorted(worse.items())]
        + [line for line in out.stdout.splitlines() if line.split(":")[0] in worse]
    )
    better = {f: (found.get(f, 0), n) for f, n in base.items() if found.get(f, 0) < n}
    assert not better, f"fewer mypy errors than the baseline: lower tests/mypy_plugins_baseline.json: {better}"
