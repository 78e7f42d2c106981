"""The repository as CI and a new user see it: the README's test command is what CI runs
(inside a fresh virtual environment), and no build artefacts are committed."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
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


def _header_commands(pipeline: Path) -> list[list[str]]:
    """The ``mocapflow ...`` commands of a pipeline's header comment (run from the repo root)."""
    import shlex

    cmds = []
    for line in pipeline.read_text().splitlines():
        if not line.startswith("#"):
            break
        text = line.lstrip("#").strip()
        if text.startswith("mocapflow "):
            try:
                cmds.append(shlex.split(text))
            except ValueError:  # a SQL string continued on the next comment line
                cmds.append(shlex.split(text + '"'))
    return cmds


@pytest.mark.parametrize("pipeline", sorted((REPO / "pipelines").glob("*.yaml")), ids=lambda p: p.name)
def test_pipeline_header_commands_name_real_paths(pipeline):
    """What a pipeline's header tells a user to type works from the repository root:
    files exist, and `sql`/`search --db` name the pipeline's workspace."""
    import yaml

    spec = yaml.safe_load(pipeline.read_text())
    ws = (pipeline.parent / spec["workspace"]).resolve().relative_to(REPO).as_posix()
    for cmd in _header_commands(pipeline):
        if cmd[1] == "run":
            assert (REPO / cmd[2]).is_file(), cmd
        elif cmd[1] == "sql":
            assert cmd[2] == ws, cmd
        elif cmd[1] == "search":
            assert cmd[cmd.index("--db") + 1] == ws, cmd
            query = cmd[cmd.index("--query") + 1].rsplit(":", 1)[0]
            assert "/" not in query or (REPO / query).is_file(), f"{query} does not exist from the repository root"


def test_readme_set_example_recomputes_what_it_says():
    """README: `--set STEP.KEY=VALUE` recomputes exactly the steps it names."""
    import re

    from mocapflow.framework import load_registries
    from mocapflow.framework.runner import plan_pipeline

    readme = " ".join((REPO / "README.md").read_text().split())
    m = re.search(
        r"`mocapflow run (\S+) --set (\S+)` recomputes exactly the steps downstream of the change \(([^)]*)\)", readme
    )
    assert m, "README's --set example"
    pipeline, override, named = REPO / m.group(1), m.group(2), {s.strip(" `") for s in m.group(3).split(",")}
    regs = load_registries(entry_points=False)
    before = plan_pipeline(pipeline, [], registries=regs).fingerprints()
    after = plan_pipeline(pipeline, [override], registries=regs).fingerprints()
    assert {s for s in before if before[s] != after[s]} == named


def test_every_benchmark_script_has_quick():
    """README: benchmarks (`benchmarks/*.py`) each have --quick; modules without a main
    (the shared corpus module) are not scripts."""
    import ast

    for script in sorted((REPO / "benchmarks").glob("*.py")):
        tree = ast.parse(script.read_text())
        is_script = any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test) for n in tree.body)
        options = {
            a.value
            for n in ast.walk(tree)
            if isinstance(n, ast.Call) and getattr(n.func, "attr", "") == "add_argument"
            for a in n.args
            if isinstance(a, ast.Constant)
        }
        if is_script:
            assert "--quick" in options, f"{script.name} has no --quick"
