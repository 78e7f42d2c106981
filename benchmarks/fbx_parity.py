"""mocapflow's FBX reader against ufbx (which evaluates FBX as the FBX SDK does).

``python benchmarks/fbx_parity.py DIR_OR_FILES... [--max-frames N]``: every binary FBX
file given (or under a folder) is read with :func:`read_fbx`; ufbx (in a subprocess, see
``_ufbx_ref.py``) evaluates the same nodes at the same times; the script prints per file the
frames, rate, and the largest joint-position difference in metres, then a summary. Files
mocapflow refuses are listed with the reason (and whether ufbx has an animation in them).

The ufbx test corpus (github.com/ufbx/ufbx, folder ``data/``, MIT / public domain) is the
reference set: ``*_binary.fbx`` files there with an animation stack.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _ufbx_ref import ufbx_positions

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import ParseError
from mocapflow.plugins.formats.fbx import read_fbx


def compare(path: Path, max_frames: int = 400) -> dict:
    """One file: mocapflow vs ufbx (dict with frames, fps, err, ufbx fps/span)."""
    m = read_fbx(path)
    meta = m.metadata
    n = m.n_frames
    step = max(1, n // max_frames)
    frames = np.arange(0, n, step)
    # the frames' times as the file's own KTime ticks in seconds (what a key time is), so that
    # a sample on a key compares equal to it in both readers (a step lands on its key's side)
    ktps = meta["ktime_per_second"]
    times = (round(meta["start_time"] * ktps) + np.round(frames * (ktps / m.fps))) / ktps
    names = list(m.skeleton.names)
    ref = ufbx_positions(path, names, times)
    axes = np.asarray(meta["axes"])
    ref_pos = meta["unit_scale"] * quat.rotate(axes, ref["pos"])
    ok = ~np.isnan(ref_pos[..., 0])
    err = np.abs(m.positions[frames] - ref_pos)[ok].max(initial=0.0)
    return {
        "frames": n,
        "fps": m.fps,
        "err": float(err),
        "ufbx_fps": float(ref["fps"]),
        "ufbx_frames": int(round((float(ref["end"]) - float(ref["begin"])) * float(ref["fps"]))) + 1,
        "joints": int(ok.any(axis=0).sum()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "paths",
        nargs="*",
        type=Path,
        help="FBX files or folders (default: $MOCAPFLOW_UFBX_DATA, else the Blender-made takes of tests/data/blender)",
    )
    ap.add_argument("--max-frames", type=int, default=400, help="frames compared per file (evenly spaced)")
    ap.add_argument("--quick", action="store_true", help="20 frames per file")
    args = ap.parse_args(argv)
    if args.quick:
        args.max_frames = 20
    if not args.paths:
        import os

        env = os.environ.get("MOCAPFLOW_UFBX_DATA")
        args.paths = [Path(env)] if env else [Path(__file__).resolve().parents[1] / "tests" / "data" / "blender"]
    try:
        import ufbx  # noqa: F401 - the reference; only its presence is checked here
    except ImportError:
        print("ufbx is not installed (pip install ufbx): nothing to compare against; skipped")
        return 0
    files: list[Path] = []
    for p in args.paths:
        files.extend(sorted(p.rglob("*.fbx")) if p.is_dir() else [p])
    worst, compared, refused = 0.0, 0, []
    for f in files:
        try:
            r = compare(f, args.max_frames)
        except ParseError as e:
            refused.append((f.name, str(e)[:160]))
            continue
        except RuntimeError as e:
            print(f"{f.name:60s} ufbx failed: {str(e)[:100]}")
            continue
        compared += 1
        worst = max(worst, r["err"])
        flag = "" if r["err"] <= 1e-4 and abs(r["fps"] - r["ufbx_fps"]) < 1e-9 else "  <-- over 1e-4 m or rate differs"
        print(
            f"{f.name:60s} {r['frames']:6d} fr (ufbx stack {r['ufbx_frames']:6d}) {r['fps']:8.3f} Hz "
            f"(ufbx {r['ufbx_fps']:8.3f}) joints {r['joints']:3d} max|d| {r['err']:.2e} m{flag}"
        )
    print(f"\ncompared {compared} files, worst {worst:.2e} m; refused {len(refused)}")
    for name, why in refused:
        print(f"  refused {name}: {why}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
