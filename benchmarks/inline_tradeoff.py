"""First-run compile time against run time of numba IR inlining in the relational kernels.

``_relational_kernels.feature_bits`` is the single slowest kernel to compile in the
quickstart (about 20 s of a cold run on a loaded 2-core machine) because its helpers are
``inline="always"``: numba inlines them into it at the IR level. This script compiles
copies of that module (``cache=False``, so every variant really compiles) with inlining as
shipped and with it removed from some helpers, on the same real input (the relational
features of CMU clips), and prints compile seconds, best-of-5 run time and whether the
outputs are identical, as ratios against the shipped module in the same run.

    python benchmarks/inline_tradeoff.py            # 30 clips
    python benchmarks/inline_tradeoff.py --quick    # 8 clips, two variants

Needs ../shared/data (the CMU AMC clips).
"""
from __future__ import annotations

import argparse
import sys
import time
import types
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu" / "amc"
VARIANTS = {
    "as shipped": (),
    "no inline anywhere": ("*",),
    "no inline: _value": ("_value",),
    "no inline: _segseg": ("_segseg",),
}


def _kernel_args(n_clips: int) -> tuple:
    """The exact arguments the relational feature set passes to ``feature_bits``."""
    import mocapflow.plugins.relational._feature_kernels as kern
    from mocapflow.framework import MotionDatabase
    from mocapflow.plugins.relational.features import RelationalFeatures
    from mocapflow.plugins.formats.asf_amc import read_amc

    captured: dict[str, tuple] = {}
    real = kern.feature_bits
    kern.feature_bits = lambda *a: captured.setdefault("args", a)
    try:
        files = sorted(DATA.glob("*/*.amc"))[:n_clips]
        RelationalFeatures().transform(MotionDatabase([read_amc(f) for f in files]))
    finally:
        kern.feature_bits = real
    return captured["args"]


def _module(without: tuple[str, ...]) -> types.ModuleType:
    import mocapflow.plugins.relational._feature_kernels as kern

    lines = Path(kern.__file__).read_text().replace("cache=True", "cache=False").splitlines(True)
    for i, line in enumerate(lines):
        if line.startswith("def ") and ("*" in without or line[4:].split("(")[0] in without):
            lines[i - 1] = lines[i - 1].replace('inline="always", ', "")
    mod = types.ModuleType("relational_kernels_variant")
    exec(compile("".join(lines), "relational_kernels_variant.py", "exec"), mod.__dict__)
    return mod


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 clips, shipped vs no inlining only")
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"needs the CMU clips at {DATA}", file=sys.stderr)
        return 2
    kargs = _kernel_args(8 if args.quick else 30)
    variants = dict(list(VARIANTS.items())[:2]) if args.quick else VARIANTS
    print(f"feature_bits on {kargs[0].shape[0]:,} frames x {kargs[3].shape[0]} features")
    results = {}
    for name, without in variants.items():
        mod = _module(without)
        a = [x.copy() if isinstance(x, np.ndarray) else x for x in kargs]
        t0 = time.perf_counter()
        mod.feature_bits(*a)
        compile_s = time.perf_counter() - t0
        runs = []
        for _ in range(5):
            t0 = time.perf_counter()
            mod.feature_bits(*a)
            runs.append(time.perf_counter() - t0)
        results[name] = (compile_s, min(runs), a[-2].copy(), a[-1].copy())
    c0, r0, o0, n0 = results["as shipped"]
    print(f"  {'variant':<22} {'compile s':>9} {'run ms':>8} {'compile':>9} {'run':>7}  identical")
    for name, (c, r, o, n) in results.items():
        same = np.array_equal(o, o0) and np.array_equal(n, n0)
        print(f"  {name:<22} {c:9.2f} {r * 1e3:8.1f} {c0 / c:8.2f}x {r / r0:6.2f}x  {same}")
    print("(compile: x faster than shipped; run: x slower than shipped)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
