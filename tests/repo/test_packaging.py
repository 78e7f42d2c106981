"""Build the wheel, install it with the template plugin in a fresh virtual environment,
and use it as a new user would (``mocapflow --help``, ``plugins``, a pipeline)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TEMPLATE = REPO / "examples" / "template-plugin"


def _run(cmd: list[str], **kw) -> subprocess.CompletedProcess:
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    env.pop("PYTHONPATH", None)
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600, **kw)
    assert res.returncode == 0, (
        f"{' '.join(cmd)} failed ({res.returncode}):\n{res.stdout[-3000:]}\n{res.stderr[-3000:]}"
    )
    return res


def _site_dirs() -> list[str]:
    """The directories this interpreter imports third-party packages from (its
    site-packages/purelib/platlib, and the user site when enabled), in its own order.

    Taken from the *running* interpreter, whatever it is: a plain install, a venv (whose
    base interpreter's site-packages lack its packages) or a conda env.
    """
    import site
    import sysconfig

    cands = [*site.getsitepackages(), sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    if site.ENABLE_USER_SITE:
        cands.append(site.getusersitepackages())
    # sys.path also holds the base interpreter's site-packages of a --system-site-packages venv
    cands += [p for p in sys.path if Path(p).name in ("site-packages", "dist-packages")]
    out: list[str] = []
    for c in cands:
        c = str(Path(c).resolve())
        if Path(c).is_dir() and c not in out:
            out.append(c)
    return out


@pytest.fixture(scope="module")
def venv(tmp_path_factory):
    """A fresh venv that gets mocapflow from the freshly built wheel and the template plugin
    from its own pyproject, and finds this interpreter's third-party packages (numpy,
    scipy... so that the test stays offline) through a ``.pth`` file.

    The venv has no system site packages: a ``.pth`` line only appends its directory to
    ``sys.path`` (the ``.pth`` files *inside* it, e.g. this checkout's editable install,
    are not run), and the venv's own site-packages comes first, so ``mocapflow`` is the
    wheel's whether pytest runs from a plain interpreter, a venv or a conda env.
    """
    root = tmp_path_factory.mktemp("venv")
    build = root / "src"
    # build from a copy, so the build leaves nothing behind in the repository
    shutil.copytree(
        REPO,
        build,
        ignore=shutil.ignore_patterns(
            ".git", "runs", "build", "dist", "*.egg-info", "__pycache__", ".pytest_cache", "*.whl"
        ),
    )
    wheels = root / "wheels"
    # wheels are built by this interpreter (its setuptools); the venv only installs them
    for project in (build, build / "examples" / "template-plugin"):
        _run(
            [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(project)]
        )
    env_dir = root / "env"
    # this interpreter's pip installs into the venv (pip >= 22.3 `--python`; else the venv's
    # own pip), before the .pth exists: the venv then holds nothing else, so nothing outside
    # it is touched
    from importlib.metadata import version

    pip_python = tuple(int(x) for x in version("pip").split(".")[:2] if x.isdigit()) >= (22, 3)
    _run([sys.executable, "-m", "venv", *(["--without-pip"] if pip_python else []), str(env_dir)])
    py = env_dir / "bin" / "python"
    pip = [sys.executable, "-m", "pip", "--python", str(py)] if pip_python else [str(py), "-m", "pip"]
    _run([*pip, "install", "--no-deps", "--no-index", *map(str, sorted(wheels.glob("*.whl")))])
    purelib = _run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip()
    (Path(purelib) / "_host_site_packages.pth").write_text("".join(f"{d}\n" for d in _site_dirs()))
    return env_dir


def test_wheel_contents_import_from_the_venv(venv):
    py = venv / "bin" / "python"
    out = _run(
        [
            str(py),
            "-c",
            "import mocapflow, mocapflow.framework as f, mocapflow.plugins as p; "
            "print(mocapflow.__file__); print(f.__file__); print(p.__file__)",
        ]
    ).stdout
    assert len(out.split()) == 3 and all(str(venv) in line for line in out.split()), out


def test_cli_help_and_plugins_from_wheel(venv):
    exe = venv / "bin" / "mocapflow"
    assert "run" in _run([str(exe), "--help"]).stdout
    version = _run(
        [str(venv / "bin" / "python"), "-c", "import mocapflow; print(mocapflow.__version__)"]
    ).stdout.strip()
    assert _run([str(exe), "--version"]).stdout.strip() == f"mocapflow {version}"
    out = _run([str(exe), "plugins"]).stdout
    assert "template" in out and "features.joint_speed" in out and "matchers.sliding_window" in out


def test_template_plugin_runs_in_a_pipeline(venv, tmp_path):
    exe = venv / "bin" / "mocapflow"
    ws = tmp_path / "ws"
    out = _run([str(exe), "run", str(TEMPLATE / "pipeline.yaml"), "--workspace", str(ws)]).stdout
    assert "done: 3 computed" in out
    res = _run(
        [str(exe), "sql", str(ws), "SELECT rank, clip_id, cost FROM matches ORDER BY rank", "--format", "csv"]
    ).stdout
    rows = res.split()[1:]
    first = _run([str(exe), "sql", str(ws), "SELECT clip_id FROM speeds LIMIT 1", "--format", "csv"]).stdout.split()[1]
    rank, clip, cost = rows[0].split(",")
    assert len(rows) == 3 and (rank, clip, float(cost)) == ("1", first, 0.0)  # the query clip matches itself first


def test_template_conformance_suite(venv):
    py = venv / "bin" / "python"
    _run([str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", str(TEMPLATE / "tests")], cwd=str(TEMPLATE))
