"""Building a large library's workspace: peak memory, bytes per frame on disk, minutes.

    python benchmarks/build_scale.py                       # 1 M frames (about 8 minutes on one core)
    python benchmarks/build_scale.py --frames 300000
    python benchmarks/build_scale.py --quick               # the bundled takes, 4 copies (seconds)

The library (:func:`make_library`, cached under ``$MOCAPFLOW_BENCH_CACHE``): the AMC takes of
../shared/data (``--quick``: examples/data) as they are, then copies of them that no two are
alike (``corpus.library_variant``) written as BVH files, until it holds ``--frames`` frames
at 30 Hz.
The pipeline a user runs on it, in a fresh interpreter (``--jobs`` workers, 1 by default:
then every step runs in that one process and its peak RSS is the run's): ``formats.load``
(30 Hz) -> ``features.end_effectors`` (F_E^15) -> ``indexes.kdtree``.

Printed: per step its time (the manifest's seconds) and its peak RSS (sampled every 20 ms
while it ran), the run's peak RSS (``ru_maxrss``), each dataset's bytes per frame and the
total, minutes; then the same pipeline rerun after one take is added (only its rows are read
and computed, the others copied; the kd-tree is rebuilt), against the full build. Per-frame figures scaled to 10 M frames are labelled as extrapolations:
they assume what the measurement shows at this size (memory bounded by the batch, disk
linear in frames), not a 10 M run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "benchmarks"))
from corpus import CACHE, DATA  # noqa: E402 - benchmarks/ joins the path first

PIPELINE = """
name: build-scale
steps:
  motions: {{uses: formats.load, with: {{paths: ["{lib}/**/*.amc", "{lib}/**/*.bvh", "{added}/*.bvh"], fps: 30}}}}
  fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
  tree: {{uses: indexes.kdtree, input: fe15}}
"""

#: the build's targets (1 M frames; the 10 M ones are checked by extrapolation only)
TARGET_RSS_1M = 1.5e9
TARGET_BYTES = 350.0


def make_library(src: Path, dst: Path, frames: int, seed: int = 0) -> int:
    """A library of at least ``frames`` frames at 30 Hz under ``dst`` (kept there and reused):
    ``copy-000/`` the AMC takes of ``src`` as they are (hard links, with their ASF), then
    ``variant-NNN/`` copies no two alike as BVH files (``corpus.library_variant``: mirrored on
    odd passes, bone lengths and time scaled, per-joint style offsets and wobble; a joint the
    source take never rotates keeps a constant rotation), so that no two takes share their
    bytes (identical copies would compress away on disk). Returns the frames."""
    from corpus import library_variant, load_takes

    from mocapflow.plugins.formats.bvh import BvhFormat

    done = dst / "frames.txt"
    if done.is_file():
        return int(done.read_text())
    amc = sorted(src.rglob("*.amc"))
    files, motions = load_takes(30.0, None, amc)
    for f in sorted(src.rglob("*.amc")) + sorted(src.rglob("*.asf")):
        to = dst / "copy-000" / f.relative_to(src)
        to.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.link(f, to)
        except OSError:  # another filesystem, or already there: a copy
            to.write_bytes(f.read_bytes())
    total, v = sum(m.n_frames for m in motions), 0
    rng, mirrored, writer = np.random.default_rng(seed), {}, BvhFormat()
    while total < frames:
        v += 1
        for f, m in zip(files, motions, strict=True):
            if total >= frames:
                break
            var = library_variant(m, v, rng, 30.0, mirrored)
            # a bone the take never rotates (no degree of freedom: hip joints, fingers of
            # CMU) keeps one rotation: its style offset, without the wobble
            still = np.ptp(m.rotations, axis=0).max(axis=-1) < 1e-9
            if still.any():
                rot = var.rotations.copy()
                rot[:, still] = rot[:1, still]
                var = var.with_arrays(rotations=rot)
            to = dst / f"variant-{v:03d}" / f.parent.name / f"{f.stem}_v{v}.bvh"
            to.parent.mkdir(parents=True, exist_ok=True)
            writer.write(var, to)
            total += var.n_frames
    done.write_text(str(total))
    return total


def child(yaml: Path, ws: Path, jobs: int, out: Path) -> None:
    """Run the pipeline in this process, sampling RSS per step; results as JSON to ``out``."""
    import threading

    from mocapflow.framework.runner import run_pipeline

    state = {"step": "(start)", "peaks": {}}
    stop = threading.Event()

    def rss() -> int:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
        return 0

    def sample() -> None:
        while not stop.is_set():
            r, s = rss(), state["step"]
            state["peaks"][s] = max(state["peaks"].get(s, 0), r)
            stop.wait(0.02)

    def echo(msg: str) -> None:
        words = msg.split()
        if len(words) >= 3 and words[-1] == "running...":
            state["step"] = words[0]
            state.setdefault("start", {})[words[0]] = rss()

    t = threading.Thread(target=sample, daemon=True)
    t.start()
    t0 = time.perf_counter()
    reports = run_pipeline(yaml, workspace=ws, jobs=jobs, echo=echo)
    wall = time.perf_counter() - t0
    stop.set()
    t.join()
    out.write_text(
        json.dumps(
            {
                "wall": wall,
                "steps": {
                    r.step_id: {"seconds": r.seconds, "rows": r.rows, "status": r.status, "summary": r.summary}
                    for r in reports
                },
                "peaks": state["peaks"],
                "start": state.get("start", {}),
                "maxrss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
            }
        )
    )


def dir_bytes(d: Path) -> int:
    return sum(p.stat().st_size for p in d.rglob("*") if p.is_file())


def measure(lib: Path, jobs: int, tmp: Path, add: bool = True) -> dict:
    ws = tmp / "ws"
    yaml = tmp / "pipeline.yaml"
    yaml.write_text(PIPELINE.format(lib=lib, added=tmp / "added"))
    out = tmp / "result.json"
    env = {**os.environ, "MOCAPFLOW_PROGRESS": "0"}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, __file__, "--child", str(yaml), str(ws), str(jobs), str(out)], check=True, env=env)
    res = json.loads(out.read_text())
    res["total_wall"] = time.perf_counter() - t0
    res["frames"] = res["steps"]["motions"]["rows"]["data"]
    res["bytes"] = {d.name: dir_bytes(d) for d in sorted(ws.iterdir()) if not d.name.startswith(".")}
    # the kd-tree step again in a fresh process (the others up to date): its own peak and
    # its growth from the moment it starts, free of what the earlier steps left allocated
    shutil.rmtree(ws / "tree")
    subprocess.run([sys.executable, __file__, "--child", str(yaml), str(ws), str(jobs), str(out)], check=True, env=env)
    alone = json.loads(out.read_text())
    res["tree_alone"] = {"peak": alone["maxrss"]}
    if not add:
        return res
    # one take added to the built library (a copy of one of its files under a new path):
    # only its rows are read and computed, the rest copied; the kd-tree is rebuilt
    added = tmp / "added"
    added.mkdir()
    take = next(iter(sorted(lib.rglob("*.bvh"))))
    shutil.copy(take, added / f"added_{take.name}")
    subprocess.run([sys.executable, __file__, "--child", str(yaml), str(ws), str(jobs), str(out)], check=True, env=env)
    res["added"] = json.loads(out.read_text())
    return res


def tree_fixed(jobs: int, tmp: Path) -> dict:
    """The kd-tree step's peak in a fresh process on the bundled takes (a few thousand rows):
    what it costs whatever the size (interpreter, imports, compiled kernels)."""
    lib = tmp / "small"
    make_library(REPO / "examples" / "data", lib, 1)
    res = measure(lib, jobs, tmp, add=False)
    return {"peak": res["tree_alone"]["peak"], "frames": res["frames"]}


def report(res: dict) -> None:
    n = max(1, res["frames"])
    print(f"\nlibrary: {n:,} frames at 30 Hz")
    print(f"{'step':<10} {'seconds':>8} {'peak RSS MB':>12} {'bytes/frame':>12}")
    for step, info in res["steps"].items():
        peak = res["peaks"].get(step, 0) / 1e6
        print(f"{step:<10} {info['seconds']:8.1f} {peak:12.0f} {res['bytes'].get(step, 0) / n:12.1f}")
    total = sum(res["bytes"].values()) / n
    rss = res["maxrss"]
    print(f"{'all':<10} {res['wall']:8.1f} {rss / 1e6:12.0f} {total:12.1f}")
    print(f"\nminutes (run, in its interpreter): {res['wall'] / 60:.2f}; with start-up: {res['total_wall'] / 60:.2f}")
    print(f"peak RSS {rss / 1e9:.2f} GB; disk {total:.0f} B/frame (target {TARGET_BYTES:.0f})")
    if n >= 900_000:
        print(f"1 M target peak RSS <= {TARGET_RSS_1M / 1e9:.1f} GB: {'met' if rss <= TARGET_RSS_1M else 'NOT met'}")
        print(f"disk <= {TARGET_BYTES:.0f} B/frame: {'met' if total <= TARGET_BYTES else 'NOT met'}")
    add = res["added"]
    print("\none take added to the built library (a rerun: only what changed is computed):")
    for step, info in add["steps"].items():
        reused = info["summary"].get("reused_clips")
        what = f", {reused} clips copied" if reused is not None else ""
        print(f"  {step:<8} {info['seconds']:6.1f} s (full build {res['steps'][step]['seconds']:.1f} s){what}")
    print(
        f"  all      {add['wall']:6.1f} s (full build {res['wall']:.1f} s): {res['wall'] / max(add['wall'], 1e-9):.1f}x"
    )
    alone, fixed = res["tree_alone"]["peak"], res["tree_fixed"]
    per_row = max(0.0, (alone - fixed["peak"]) / max(1, n - fixed["frames"]))
    print(
        f"kd-tree step alone in a fresh process: peak {alone / 1e6:.0f} MB; on the {fixed['frames']:,} frames of "
        f"the bundled takes {fixed['peak'] / 1e6:.0f} MB: {per_row:.0f} B per row between the two"
    )
    scale = 10_000_000 / n
    tree10 = fixed["peak"] + per_row * (10_000_000 - fixed["frames"])
    big = max(tree10, *(v for k, v in res["peaks"].items() if k != "tree"))
    print(
        f"extrapolated to 10 M frames (per-frame figures x {scale:.0f}; not a 10 M run): disk "
        f"{total * 1e7 / 1e9:.1f} GB, {res['wall'] * scale / 60:.0f} min on these cores; peak RSS about "
        f"{big / 1e9:.1f} GB (the kd-tree step's growth per row x 10 M; the streamed steps hold one "
        "batch whatever the size, so their peaks do not grow)"
    )


def main() -> None:
    if "--child" in sys.argv:
        i = sys.argv.index("--child")
        yaml, ws, jobs, out = sys.argv[i + 1 : i + 5]
        child(Path(yaml), Path(ws), int(jobs), Path(out))
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1_000_000, help="library size in frames at 30 Hz")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (1: every step in one process)")
    ap.add_argument("--quick", action="store_true", help="the bundled takes and 3 variants of each")
    args = ap.parse_args()
    src = REPO / "examples" / "data" if args.quick or not (DATA / "cmu").is_dir() else DATA
    if not args.quick and src != DATA:
        print(f"no corpus at {DATA}: using the bundled takes", file=sys.stderr)
    frames = 10_000 if args.quick else args.frames
    lib = CACHE / f"build-library-{frames}-{src.name}"
    t0 = time.perf_counter()
    total = make_library(src, lib, frames)
    print(f"library of {total:,} frames under {lib} ({time.perf_counter() - t0:.0f} s, cached)")
    with tempfile.TemporaryDirectory(prefix="build-scale-") as t:
        res = measure(lib, args.jobs, Path(t))
    with tempfile.TemporaryDirectory(prefix="build-scale-") as t:
        res["tree_fixed"] = tree_fixed(args.jobs, Path(t))
    report(res)


if __name__ == "__main__":
    main()
