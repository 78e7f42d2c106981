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
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1:]
    assert out in ([], [""]), f"imported by `mocapflow`: {out}"
