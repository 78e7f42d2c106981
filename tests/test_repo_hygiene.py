"""The repository as CI and a new user see it: the README's test command is what CI runs
(inside a fresh virtual environment), and no build artefacts are committed."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README_TEST_COMMAND = 'python -m pip install -e ".[test]" && python -m pytest -q'


def test_ci_runs_the_readme_test_command_in_a_fresh_venv():
    readme = (REPO / "README.md").read_text()
    ci = (REPO / ".ci" / "run").read_text()
    assert README_TEST_COMMAND in readme.splitlines()
    lines = ci.splitlines()
    assert README_TEST_COMMAND in lines
    venv_at = next(i for i, line in enumerate(lines) if "python3 -m venv" in line)
    activate_at = next(i for i, line in enumerate(lines) if line.startswith(". ") and "bin/activate" in line)
    assert venv_at < activate_at < lines.index(README_TEST_COMMAND)
    assert "export MOCAPFLOW_PROGRESS=0" in lines


def _git(*args: str) -> str:
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, check=False).stdout


def test_no_wheels_committed_and_build_outputs_ignored():
    assert _git("ls-files", "*.whl") == ""
    ignored = _git("check-ignore", "--no-index", "x-1.0-py3-none-any.whl", "dist/x.tar.gz").split()
    assert ignored == ["x-1.0-py3-none-any.whl", "dist/x.tar.gz"]
