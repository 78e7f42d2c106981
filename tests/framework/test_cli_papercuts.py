"""Paper cuts a new user hits in the CLI: --version, the choices of Literal parameters, rejected files, the first run's compilation,
``sql --output`` into a new folder."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import typing
from importlib import metadata
from pathlib import Path

import pytest

from mocapflow.framework.cli import format_annotation, main
from mocapflow.framework.progress import COMPILING_MESSAGE, announce_compilation

REPO = Path(__file__).resolve().parents[2]
CMU = REPO / "examples" / "data" / "cmu" / "35"


def test_version_is_single_sourced(capsys):
    import tomllib

    import mocapflow
    import mocapflow.framework

    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"mocapflow {mocapflow.__version__}"
    assert mocapflow.framework.__version__ == mocapflow.__version__ == metadata.version("mocapflow")
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert "version" not in project and "version" in project["dynamic"]  # written once, in the package


def test_plugins_prints_the_choices_of_literal_and_union_parameters(capsys):
    assert format_annotation(typing.Literal["record", "fail"]) == "'record' | 'fail'"
    assert format_annotation(typing.Optional[typing.Literal["a", "b"]]) == "'a' | 'b' | None"  # noqa: UP045 - the typing spelling is what is formatted here
    assert format_annotation(int | None) == "int | None"
    assert format_annotation(typing.Union[int, str]) == "int | str"  # noqa: UP007 - the typing spelling is what is formatted here
    assert format_annotation(tuple[typing.Literal["x", "y"], ...]) == "tuple['x' | 'y', ...]"
    assert format_annotation(dict[str, float]) == "dict[str, float]"
    assert main(["--no-entry-points", "plugins"]) == 0
    out = capsys.readouterr().out
    assert "on_error: 'record' | 'fail' (default 'record')" in out  # formats.load


@pytest.fixture(scope="module")
def rejecting_pipeline(tmp_path_factory) -> Path:
    """One good AMC take and two files that cannot be read (words for numbers; binary)."""
    root = tmp_path_factory.mktemp("rejects")
    data = root / "data"
    data.mkdir()
    shutil.copy(CMU / "35.asf", data)
    shutil.copy(CMU / "35_01.amc", data)
    (data / "35_66.amc").write_text(":FULLY-SPECIFIED\n:DEGREES\n1\nroot one two three 0 0 0\n")
    (data / "35_77.amc").write_bytes(b"\x00\x01 not a motion file \xff\n")
    (root / "p.yaml").write_text(
        "name: rejects\nworkspace: ws\nsteps:\n  motions:\n    uses: formats.load\n"
        '    with:\n      paths: ["data/*.amc"]\n'
    )
    return root / "p.yaml"


def _run_cli(args: list[str], **env: str) -> subprocess.CompletedProcess:
    full_env = {**os.environ, "MOCAPFLOW_PROGRESS": "0", **env}
    return subprocess.run(
        [sys.executable, "-m", "mocapflow.framework.cli", *args],
        capture_output=True,
        text=True,
        env=full_env,
        timeout=600,
    )


def test_a_run_with_rejects_warns_and_the_first_run_says_it_compiles(rejecting_pipeline, tmp_path):
    cache = str(tmp_path / "numba-cache")  # a cold numba cache: kernels compile in this run
    first = _run_cli(["--no-entry-points", "run", str(rejecting_pipeline)], NUMBA_CACHE_DIR=cache)
    assert first.returncode == 0, first.stderr
    assert "mocapflow: warning: motions: 2 of 3 files rejected: see the rejects view" in first.stderr
    assert first.stdout.count(COMPILING_MESSAGE) == 1, first.stdout
    again = _run_cli(["--no-entry-points", "run", "--force", str(rejecting_pipeline)], NUMBA_CACHE_DIR=cache)
    assert again.returncode == 0, again.stderr
    assert COMPILING_MESSAGE not in again.stdout  # loaded from the cache: nothing to announce
    assert "2 of 3 files rejected" in again.stderr


def test_announce_compilation_says_it_once_and_only_on_compilation():
    numba = pytest.importorskip("numba")

    @numba.njit(cache=False)
    def plus_one(x):
        return x + 1

    said: list[str] = []
    with announce_compilation(said.append):
        plus_one(1)
        plus_one(2.5)  # a second compilation: still one message
    assert said == [COMPILING_MESSAGE]
    with announce_compilation(said.append):
        plus_one(3)  # compiled already
    assert said == [COMPILING_MESSAGE]


def test_announce_compilation_attaches_when_numba_is_imported_later():
    code = (
        "import sys\n"
        "from mocapflow.framework.progress import announce_compilation\n"
        "said = []\n"
        "with announce_compilation(said.append, 'compiling'):\n"
        "    assert 'numba' not in sys.modules\n"
        "    import numba\n"
        "    numba.njit(lambda x: x * 2)(3)\n"
        "print(said)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['compiling']"


def test_sql_output_into_a_new_folder(rejecting_pipeline, capsys):
    ws = rejecting_pipeline.parent / "ws"
    if not (ws / "motions").is_dir():
        assert main(["--no-entry-points", "run", str(rejecting_pipeline)]) == 0
    out = rejecting_pipeline.parent / "new" / "folder" / "rejects.csv"
    assert main(["sql", str(ws), "SELECT path FROM rejects ORDER BY path", "--output", str(out)]) == 0
    assert out.read_text().count("\n") == 3  # header + the two rejected files
    capsys.readouterr()
    # a folder given as the output file is refused before any work
    assert main(["sql", str(ws), "SELECT 1", "--output", str(out.parent)]) == 2
    assert "is a directory" in capsys.readouterr().err


def test_every_command_announces_compilation_on_stderr(monkeypatch, capsys):
    """A plugin command (`mocapflow search`...) whose first call compiles kernels says so,
    on stderr: its stdout is its result."""
    numba = pytest.importorskip("numba")
    import mocapflow.framework.cli as cli

    class Compiles:
        name, help = "compiles", "compiles a kernel"

        @classmethod
        def add_arguments(cls, parser):
            pass

        @classmethod
        def run(cls, args):
            print(numba.njit(cache=False)(lambda x: x + 1)(41))
            return 0

    monkeypatch.setattr(cli, "_plugin_commands", lambda pm: [Compiles])
    assert main(["--no-entry-points", "compiles"]) == 0
    out = capsys.readouterr()
    assert out.out == "42\n" and COMPILING_MESSAGE in out.err


def test_sql_into_a_pipe_closed_early_ends_quietly(rejecting_pipeline):
    """`mocapflow sql WS "..." | head -1`: the reader closes the pipe; no internal error, the
    shell's status of a tool stopped by a closed pipe (141). The closed pipe is simulated (a
    real one races with the reader: small outputs often fit in its buffer)."""
    ws = rejecting_pipeline.parent / "ws"
    if not (ws / "motions").is_dir():
        assert main(["--no-entry-points", "run", str(rejecting_pipeline)]) == 0
    script = (
        "import sys\n"
        "from mocapflow.framework.cli import main\n"
        "class Closed:\n"
        "    def write(self, s): raise BrokenPipeError(32, 'Broken pipe')\n"
        "    def flush(self): pass\n"
        "    def fileno(self): return sys.__stdout__.fileno()\n"
        "sys.stdout = Closed()\n"
        f"rc = main(['sql', {str(ws)!r}, 'SELECT * FROM range(10)'])\n"
        "sys.stdout = sys.__stdout__\n"
        "print('rc', rc, file=sys.stderr)\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=dict(os.environ, MOCAPFLOW_PROGRESS="0")
    )
    assert "rc 141" in r.stderr, r.stderr
    assert "error" not in r.stderr, r.stderr
