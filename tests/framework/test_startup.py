"""Nothing heavy happens on import: building the registries (what every CLI command does)
must not import numba, matplotlib or the slow scipy sub-packages; kernels load lazily."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("numba", "matplotlib", "scipy.signal", "scipy.stats", "scipy.optimize", "duckdb")


def test_building_registries_imports_nothing_heavy():
    code = (
        "import sys\n"
        "from mocapflow.framework import load_registries\n"
        "load_registries(entry_points=False)\n"
        f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "", f"imported at registration time: {out}"


def test_cli_help_imports_nothing_heavy():
    code = (
        "import sys, io, contextlib\n"
        "from mocapflow.framework.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()):\n"
        "    main([])\n"
        f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    out = (
        subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        .stdout.strip()
        .splitlines()[-1:]
    )
    assert out in ([], [""]), f"imported by `mocapflow`: {out}"


def _modules_after(code_lines: list[str], cwd: str | None = None) -> set[str]:
    """The top-level modules (and ``mocapflow.*`` ones) a fresh interpreter holds after ``code``."""
    code = "\n".join(
        [
            "import sys, io, contextlib",
            *code_lines,
            "print('MODULES', ' '.join(sorted(m for m in sys.modules if '.' not in m or m.startswith('mocapflow.'))))",
        ]
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=cwd).stdout
    return set(next(line for line in out.splitlines() if line.startswith("MODULES")).split()[1:])


def _cli(argv: list[str]) -> list[str]:
    return [
        "from mocapflow.framework.cli import main",
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):",
        "    try:",
        f"        main({argv!r})",
        "    except SystemExit:",
        "        pass",
    ]


def test_importing_the_framework_is_cheap_and_every_name_resolves():
    mods = _modules_after(["import mocapflow, mocapflow.framework"])
    assert not mods & {"numpy", "pyarrow", "pydantic", "scipy", "numba", "duckdb"}, mods
    import mocapflow
    import mocapflow.framework as fw

    assert sorted(fw.__all__) == sorted([*fw._EXPORTS, "__version__"])  # the literal list type checkers read
    for name in fw.__all__:  # the lazy facade gives every public name
        assert getattr(fw, name) is not None, name
    assert fw.__version__ == mocapflow.__version__
    assert fw.Motion.__module__ == "mocapflow.framework.motion"


def test_cli_help_and_version_import_no_pydantic_scipy_numba():
    for argv in (["--help"], [], ["--version"], ["run", "--help"]):
        mods = _modules_after(_cli(argv))
        assert not mods & {"numpy", "pyarrow", "pydantic", "scipy", "numba", "duckdb", "matplotlib", "yaml"}, (
            argv,
            mods,
        )


def test_sql_loads_no_plugin(tmp_path):
    mods = _modules_after(_cli(["sql", str(tmp_path / "missing"), "SELECT 1"]))
    assert not any(m.startswith("mocapflow.plugins.") for m in mods), sorted(mods)


def test_commands_run_with_one_context_that_honours_block(tmp_path, capsys):
    """Commands come from the register_commands hook of every plugin that is not blocked, and
    run with the context the CLI built: a blocked plugin's command and formats are gone."""
    from mocapflow.framework.cli import main
    from mocapflow.framework.commands import CommandContext

    ctx = CommandContext.from_switches(entry_points=False)
    names = {c.name for c in ctx.plugin_manager.hook.register_commands() for c in c}
    assert {"search", "export", "reconstruct", "clean", "report"} <= names
    blocked = CommandContext.from_switches(entry_points=False, blocked=["mocapflow.plugins.formats.plugin"])
    assert "export" not in {c.name for cs in blocked.plugin_manager.hook.register_commands() for c in cs}
    keys = blocked.registries(["formats"]).keys()
    assert "formats.bvh" not in keys
    assert blocked.registries(["formats"]) is blocked.registries(["formats"])  # built once
    # reconstruct reads its input with the context's formats: none when formats are blocked
    take = tmp_path / "take.bvh"
    take.write_text("HIERARCHY\n")
    argv = ["--block", "mocapflow.plugins.formats.plugin", "reconstruct", str(take), "--prior", str(tmp_path)]
    assert main([*argv, "-o", str(tmp_path / "out.bvh")]) == 2
    assert "no registered reader" in capsys.readouterr().err
