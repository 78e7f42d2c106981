"""FBX read speed: mocapflow's reader against ufbx, measured in the same run.

``python benchmarks/fbx_speed.py [--frames N] [--quick]`` writes an N-frame take
(CMU 02_01 tiled, 38 joints) with mocapflow's FBX writer, then times (best of 3, wall and
CPU; ufbx in a subprocess, as it must run: ``_ufbx_ref.py``):

* mocapflow: ``read_fbx`` (curves sampled, node transforms composed, a Motion) and
  ``read_fbx`` + joint positions (forward kinematics);
* ufbx ``load_file`` alone, ``load_file`` + ``bake_anim`` (local keys baked, still inside
  ufbx's objects), and ``load_file`` + ``bake_anim`` + the baked keys copied into numpy
  arrays (what a backend would hand over; no forward kinematics);
* ufbx ``load_file`` + ``evaluate_scene`` per frame reading every joint's world position
  (the same output as mocapflow's positions; on ``--eval-frames`` frames, scaled).

Frames/s and the ratio mocapflow / ufbx are printed for each ufbx path.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

_CHILD = r"""
import json, os, sys, time
import numpy as np
import ufbx
job = json.loads(open(sys.argv[1]).read())
path, names, n_eval, rounds = job["path"], job["names"], job["eval_frames"], job["rounds"]
out = {}
keep = []  # never free a ufbx object: the 0.0.5 binding may crash doing so
def best(fn):
    w, c = [], []
    for _ in range(rounds):
        t0, p0 = time.perf_counter(), time.process_time()
        keep.append(fn())
        w.append(time.perf_counter() - t0); c.append(time.process_time() - p0)
    return min(w), min(c)
def load():
    return ufbx.load_file(path)
def bake():
    s = ufbx.load_file(path)
    return s, ufbx.bake_anim(s, s.anim_stacks[0].anim)
def bake_copy():
    s = ufbx.load_file(path)
    b = ufbx.bake_anim(s, s.anim_stacks[0].anim)
    arrs = []
    for bn in b.nodes:
        arrs.append(np.array([(k.value.x, k.value.y, k.value.z, k.value.w) for k in bn.rotation_keys]))
        arrs.append(np.array([(k.value.x, k.value.y, k.value.z) for k in bn.translation_keys]))
    return s, b, arrs
def evaluate():
    s = ufbx.load_file(path)
    anim = s.anim_stacks[0].anim
    idx = {nd.name: k for k, nd in enumerate(s.nodes)}
    cols = [idx[n] for n in names]
    pos = np.empty((n_eval, len(cols), 3))
    for f in range(n_eval):
        e = ufbx.evaluate_scene(s, anim, f / job["fps"])
        keep.append(e)
        nodes = e.nodes
        for j, k in enumerate(cols):
            c = nodes[k].node_to_world.c3
            pos[f, j] = (c.x, c.y, c.z)
    return s, pos
fn = {"load": load, "load+bake": bake, "load+bake+copy": bake_copy, "evaluate_scene": evaluate}[job["what"]]
out[job["what"]] = best(fn)
open(sys.argv[2], "w").write(json.dumps(out))
sys.stdout.flush()
os._exit(0)
"""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--eval-frames", type=int, default=500, help="frames ufbx evaluate_scene runs (then scaled)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="2,000 frames, 100 evaluated, 2 rounds")
    args = ap.parse_args(argv)
    if args.quick:
        args.frames, args.eval_frames, args.rounds = 2_000, 100, 2
    import _ufbx_ref

    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.fbx import read_fbx, write_fbx

    m = read_amc(ROOT / "examples" / "data" / "cmu" / "02" / "02_01.amc")
    idx = np.arange(args.frames) % m.n_frames
    take = m.with_arrays(rotations=m.rotations[idx], root_translation=m.root_translation[idx])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "take.fbx"
        write_fbx(take, path)

        def best(fn):
            w, c = [], []
            for _ in range(args.rounds):
                t0, p0 = time.perf_counter(), time.process_time()
                fn()
                w.append(time.perf_counter() - t0)
                c.append(time.process_time() - p0)
            return min(w), min(c)

        read_fbx(path)  # imports and first-call costs out of the timing
        ours = best(lambda: read_fbx(path))
        ours_fk = best(lambda: read_fbx(path).positions)
        n = args.frames
        print(f"{n} frames, {take.n_joints} joints, {path.stat().st_size / 1e6:.1f} MB")
        print(f"mocapflow read_fbx             {n / ours[0]:10.0f} frames/s wall {n / ours[1]:10.0f} CPU")
        print(f"mocapflow read_fbx + positions {n / ours_fk[0]:10.0f} frames/s wall {n / ours_fk[1]:10.0f} CPU")
        if not _ufbx_ref.available():
            print("ufbx not installed: no ratios")
            return 0
        names = list(read_fbx(path).skeleton.names)
        for what in ("load", "load+bake", "load+bake+copy", "evaluate_scene"):
            job, res = Path(tmp) / "job.json", Path(tmp) / "res.json"
            res.unlink(missing_ok=True)
            spec = {"path": str(path), "names": names, "eval_frames": args.eval_frames, "rounds": args.rounds}
            job.write_text(json.dumps({**spec, "fps": take.fps, "what": what}))
            r = subprocess.run([sys.executable, "-c", _CHILD, str(job), str(res)], capture_output=True, timeout=3600)
            if r.returncode != 0 or not res.exists():
                print(f"ufbx {what:25s} crashed (exit {r.returncode}): the binding's known fault")
                continue
            w, c = json.loads(res.read_text())[what]
            frames = args.eval_frames if what == "evaluate_scene" else n
            fw, fc = frames / w, frames / c
            ref = ours_fk if what == "evaluate_scene" else ours
            print(
                f"ufbx {what:25s} {fw:10.0f} frames/s wall {fc:10.0f} CPU;"
                f" mocapflow / ufbx {n / ref[0] / fw:6.2f}x wall {n / ref[1] / fc:6.2f}x CPU"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
