"""``ruff check`` and ``ruff format --check`` pass over the repository with the settings of
pyproject.toml; every noqa comment says why."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _ruff() -> list[str] | None:
    exe = shutil.which("ruff") or (
        str(Path(sys.executable).with_name("ruff")) if Path(sys.executable).with_name("ruff").exists() else None
    )
    return [exe] if exe else None


def test_ruff_check_passes():
    cmd = _ruff()
    if cmd is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]' installs it)")
    out = subprocess.run([*cmd, "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_ruff_format_is_applied():
    cmd = _ruff()
    if cmd is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]' installs it)")
    out = subprocess.run([*cmd, "format", "--check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, "run `ruff format .`\n" + out.stdout + out.stderr


def test_every_noqa_says_why():
    """Every noqa comment names its codes and is followed by its reason (``- why``)."""
    import re

    bare = []
    for path in sorted(ROOT.rglob("*.py")):
        if {"runs", ".git"} & set(path.relative_to(ROOT).parts) or "egg-info" in str(path):
            continue
        for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            m = re.search(r"#\s*noqa\b(.*)$", line)
            if m and not re.match(r":\s*[A-Z]+[0-9]+(?:,\s*[A-Z]+[0-9]+)*\s+[-—–(:]?\s*\w", m.group(1)):
                bare.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert not bare, "\n".join(bare)
