"""Every runnable script of examples/ runs and exits 0 (so none rots); each takes an output
folder as its only argument."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.parametrize("script", sorted(EXAMPLES.glob("*.py")), ids=lambda p: p.name)
def test_example_script_runs(script, tmp_path):
    res = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "out")], capture_output=True, text=True, cwd=tmp_path, timeout=300
    )
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert res.stdout.strip()


def test_there_is_a_runnable_example():
    assert list(EXAMPLES.glob("*.py"))
