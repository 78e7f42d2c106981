"""The core type-checks strictly: ``mypy`` with the configuration of pyproject.toml
(``[tool.mypy]``: ``framework/``, strict). Skipped only where mypy is not installed (it is
in the ``test`` extra, so CI runs it)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_framework_type_checks_strictly():
    pytest.importorskip("mypy")
    out = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout + out.stderr
