"""Run the benchmarks a maintainer reruns: one per capability.

    python benchmarks/run.py --list              # every benchmark with what it measures
    python benchmarks/run.py NAME [ARGS...]      # one, ARGS passed through (e.g. --quick)
    python benchmarks/run.py --all --quick       # every one on its tiny input (seconds each)

Each ``benchmarks/<name>.py`` runs its real measurement on ``../shared/data`` and prints
ratios against a baseline measured in the same run; with ``--quick`` it runs in about 30 s on
two cores on the bundled ``examples/data`` or synthetic motion (``tests/repo/test_benchmarks.py``
runs every one that way so none rots).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def discover(folder: Path = HERE) -> dict[str, str]:
    """name -> what it measures (the first paragraph of its docstring), for every script of
    ``folder`` that runs as a program (``if __name__ == "__main__"``): ``benchmarks/<name>.py``;
    helper modules (``_*.py``, no main block) and this runner are not benchmarks."""
    import ast

    out = {}
    for script in sorted(folder.glob("*.py")):
        if script.name.startswith("_") or script.name == Path(__file__).name:
            continue
        tree = ast.parse(script.read_text(encoding="utf-8"))
        runs = any(
            isinstance(node, ast.If) and "__main__" in ast.unparse(node.test) and "__name__" in ast.unparse(node.test)
            for node in tree.body
        )
        if runs:
            doc = " ".join((ast.get_docstring(tree) or script.stem).split("\n\n")[0].split())
            out[script.stem] = doc.rstrip(".")
    return out


#: name -> what it measures (the script is ``benchmarks/<name>.py``), discovered.
BENCHMARKS: dict[str, str] = discover()


def run(name: str, args: list[str]) -> int:
    script = HERE / f"{name}.py"
    if not script.is_file():
        print(f"no benchmark script {script}", file=sys.stderr)
        return 2
    return subprocess.run([sys.executable, str(script), *args]).returncode


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], usage="%(prog)s (--list | --all [--quick] | NAME [ARGS...])"
    )
    ap.add_argument("name", nargs="?", help="the benchmark to run")
    ap.add_argument("--list", action="store_true", help="list every benchmark with what it measures")
    ap.add_argument("--all", action="store_true", help="run every benchmark")
    ap.add_argument("--quick", action="store_true", help="pass --quick: the tiny input (about 30 s each)")
    args, rest = ap.parse_known_args(argv)
    rest = (["--quick"] if args.quick else []) + rest
    if args.list:
        for name, what in BENCHMARKS.items():
            print(f"{name:<13} {what}")
        return 0
    if args.all:
        failed = []
        for name in BENCHMARKS:
            print(f"\n=== {name} ===", flush=True)
            t0 = time.perf_counter()
            rc = run(name, rest)
            print(f"=== {name}: exit {rc} in {time.perf_counter() - t0:.1f} s ===", flush=True)
            if rc:
                failed.append(name)
        print(
            f"\n{len(BENCHMARKS) - len(failed)} of {len(BENCHMARKS)} passed" + (f"; failed: {failed}" if failed else "")
        )
        return 1 if failed else 0
    if args.name not in BENCHMARKS:
        ap.error(f"unknown benchmark {args.name!r}; known: {', '.join(BENCHMARKS)}")
    return run(args.name, rest)


if __name__ == "__main__":
    raise SystemExit(main())
