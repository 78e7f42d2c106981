"""Read + forward-kinematics throughput of the AMC, BVH, glTF and FBX readers, and corpus ingest time.

Compares, on the same files and in the same run:

* mocapflow: ``read_amc`` / ``read_bvh`` followed by ``Motion.positions`` (vectorised FK);
* a plain reference written here: a line-by-line parser (``str.split`` + ``float``) and
  per-frame forward kinematics with 3x3 matrices (the textbook ASF/BVH algorithm);
* pybvh (``pip install pybvh``), if installed: ``read_bvh_file`` + ``node_positions()``;
* glTF: a 100,000-frame file (20,000 with ``--quick``) written by mocapflow's glTF writer,
  against the slow per-frame twin of ``tests/naive/gltf.py``; FBX: the Blender-made test files.

Also times reading the whole AMC corpus (169 files, 110,109 frames) and, when the
pipeline runner is available, the ``formats.load`` ingest step over it (Parquet included).

Usage::

    python benchmarks/ingest.py            # full run (corpus at ../shared/data)
    python benchmarks/ingest.py --quick    # the bundled examples/data takes (BVH written from them), one repetition
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mocapflow.plugins.formats.asf_amc import read_amc, read_asf
from mocapflow.plugins.formats.bvh import read_bvh

#: Frames per file the (slow) plain reference is timed on.
REF_FRAMES = 300
DATA = Path(os.environ.get("MOCAPFLOW_DATA", Path(__file__).resolve().parent.parent.parent / "shared" / "data"))
EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "data"


# --- plain reference ------------------------------------------------------------------------


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(deg)), np.sin(np.deg2rad(deg))
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def plain_amc(amc: Path, asf: Path, max_frames: int | None = None) -> np.ndarray:
    """Line-by-line AMC parser and per-frame matrix FK; bone end positions (T, B, 3), metres."""
    sk = read_asf(asf)  # the ASF is small: reuse its parse, the benchmark is about motion data
    meta = sk.meta
    scale = meta["length_scale"]
    bones = {b["name"]: b for b in meta["bones"]}
    c_mat = {}
    for name, b in bones.items():
        r = np.eye(3)
        for a, ang in zip(b["axis_order"].lower(), b["axis"], strict=True):
            r = _rot(a, ang) @ r
        c_mat[name] = r
    children = meta["hierarchy"]
    order = []
    stack = list(reversed(children.get("root", [])))
    parent_of = {c: "root" for c in children.get("root", [])}
    while stack:
        n = stack.pop()
        order.append(n)
        for c in reversed(children.get(n, [])):
            parent_of[c] = n
            stack.append(c)
    frames: list[dict[str, list[float]]] = []
    with open(amc, encoding="latin-1") as fh:
        for line in fh:
            words = line.split()
            if not words or words[0].startswith((":", "#")):
                continue
            if words[0].isdigit():
                if max_frames is not None and len(frames) == max_frames:
                    break
                frames.append({})
            else:
                frames[-1][words[0]] = [float(w) for w in words[1:]]
    out = np.zeros((len(frames), len(order), 3))
    for t, fr in enumerate(frames):
        vals = fr["root"]
        rr = np.eye(3)
        for ch, v in zip(meta["root"]["order"], vals, strict=False):
            if ch[0] == "R":
                rr = _rot(ch[1].lower(), v) @ rr
        glob = {"root": rr}
        end = {"root": np.array(vals[:3]) * scale}
        for k, n in enumerate(order):
            b = bones[n]
            m = np.eye(3)
            for d, v in zip(b["dof"], fr.get(n, [0.0] * len(b["dof"])), strict=False):
                m = _rot(d[1], v) @ m
            g = glob[parent_of[n]] @ c_mat[n] @ m @ c_mat[n].T
            glob[n] = g
            end[n] = end[parent_of[n]] + g @ (np.asarray(b["direction"]) * b["length"] * scale)
            out[t, k] = end[n]
    return out


def plain_bvh(path: Path, max_frames: int | None = None) -> np.ndarray:
    """Line-by-line BVH parser and per-frame matrix FK; joint positions (T, J, 3), file units."""
    names, parents, offsets, channels, stack = [], [], [], [], []
    lines = Path(path).read_text(encoding="latin-1").splitlines()
    i = 0
    while not lines[i].strip().startswith("MOTION"):
        w = lines[i].split()
        if w and w[0] in ("ROOT", "JOINT", "End"):
            names.append(w[1] if w[0] != "End" else names[stack[-1]] + "_end")
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append([])
        elif w and w[0] == "{":
            stack.append(len(names) - 1)
        elif w and w[0] == "}":
            stack.pop()
        elif w and w[0] == "OFFSET":
            offsets[stack[-1]] = np.array([float(x) for x in w[1:4]])
        elif w and w[0] == "CHANNELS":
            channels[stack[-1]] = w[2:]
        i += 1
    n_frames = int(lines[i + 1].split()[-1])
    n_frames = n_frames if max_frames is None else min(n_frames, max_frames)
    data = [[float(x) for x in ln.split()] for ln in lines[i + 3 : i + 3 + n_frames]]
    out = np.zeros((n_frames, len(names), 3))
    for t, row in enumerate(data):
        c = 0
        glob, pos = [None] * len(names), [None] * len(names)
        for j in range(len(names)):
            r = np.eye(3)
            p = offsets[j].copy()
            for ch in channels[j]:
                if ch.endswith("rotation"):
                    r = r @ _rot(ch[0].lower(), row[c])
                else:
                    p["XYZ".index(ch[0])] = row[c]
                c += 1
            if parents[j] < 0:
                glob[j], pos[j] = r, p
            else:
                glob[j] = glob[parents[j]] @ r
                pos[j] = pos[parents[j]] + glob[parents[j]] @ p
            out[t, j] = pos[j]
    return out


# --- timing ---------------------------------------------------------------------------------


def best_of(fn, reps: int) -> tuple[float, float]:
    """Best wall-clock and best process CPU time (seconds) over ``reps`` runs.

    The CPU time is less sensitive to other processes on a shared machine; both are shown.
    """
    walls, cpus = [], []
    for _ in range(reps):
        w, c = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - w)
        cpus.append(time.process_time() - c)
    return min(walls), min(cpus)


def rate(frames: int, t: tuple[float, float]) -> str:
    wall, cpu = t
    return f"{frames / wall:>10,.0f} frames/s wall ({wall:.3f} s), {frames / cpu:>10,.0f} frames/s CPU"


def ratio(frames_a: int, ta: tuple[float, float], frames_b: int, tb: tuple[float, float]) -> str:
    return f"{(frames_a / ta[0]) / (frames_b / tb[0]):.1f}x wall, {(frames_a / ta[1]) / (frames_b / tb[1]):.1f}x CPU"


def bench_amc(files: list[Path], reps: int) -> None:
    frames = sum(read_amc(f).n_frames for f in files)
    ours = best_of(lambda: [read_amc(f).positions for f in files], reps)
    # the plain reference is slow: time it on the first REF_FRAMES frames of two files
    ref_files = files[:2]
    ref_frames = sum(min(REF_FRAMES, read_amc(f).n_frames) for f in ref_files)
    plain = best_of(lambda: [plain_amc(f, f.parent / f"{f.parent.name}.asf", REF_FRAMES) for f in ref_files], 1)
    # the two agree: bone ends of the reference are the joints after each bone
    m = read_amc(ref_files[0]).slice(0, REF_FRAMES)
    p = plain_amc(ref_files[0], ref_files[0].parent / f"{ref_files[0].parent.name}.asf", REF_FRAMES)
    order = [n for n in m.skeleton.names if n != "root" and not n.endswith("_end")]
    ends = []
    for n in order:
        j = m.skeleton.names.index(n)
        kids = m.skeleton.children(j)
        ends.append(kids[0])
    err = np.abs(m.positions[:, ends] - p).max()
    print(f"AMC read+FK, {len(files)} CMU files (31 bones, {m.skeleton.n_joints} joints), {frames:,} frames")
    print(f"  mocapflow           {rate(frames, ours)}")
    print(
        f"  plain reference     {rate(ref_frames, plain)}   [{len(ref_files)} x {REF_FRAMES} frames; max |diff| {err:.1e} m]"
    )
    print(f"  ratio mocapflow / plain: {ratio(frames, ours, ref_frames, plain)}")


def bench_bvh(files: list[Path], reps: int) -> None:
    frames = sum(read_bvh(f).n_frames for f in files)
    ours = best_of(lambda: [read_bvh(f).positions for f in files], reps)
    ref_files = files[:2]
    ref_frames = sum(min(REF_FRAMES, read_bvh(f).n_frames) for f in ref_files)
    plain = best_of(lambda: [plain_bvh(f, REF_FRAMES) for f in ref_files], 1)
    m = read_bvh(ref_files[0], scale=1.0).slice(0, REF_FRAMES)
    err = np.abs(m.positions - plain_bvh(ref_files[0], REF_FRAMES)).max()
    print(f"BVH read+FK, {len(files)} files (31-joint CMU conversions), {frames:,} frames")
    print(f"  mocapflow           {rate(frames, ours)}")
    print(
        f"  plain reference     {rate(ref_frames, plain)}   [{len(ref_files)} x {REF_FRAMES} frames; max |diff| {err:.1e} file units]"
    )
    print(f"  ratio mocapflow / plain: {ratio(frames, ours, ref_frames, plain)}")
    try:
        import pybvh
    except ImportError:
        print("  pybvh               not installed (pip install pybvh to compare)")
        return

    def run_pybvh() -> None:
        for f in files:
            pybvh.read_bvh_file(f, warn_on_world_up_disagreement=False).node_positions()

    t = best_of(run_pybvh, reps)
    print(f"  pybvh {getattr(pybvh, '__version__', '')}         {rate(frames, t)}")
    print(f"  ratio mocapflow / pybvh: {ratio(frames, ours, frames, t)}")


def bench_gltf(amc: Path, n_frames: int, tmp: Path, reps: int) -> None:
    """glTF/GLB read speed on an ``n_frames`` file written by mocapflow's own writer (a CMU
    take tiled), against the slow per-frame twin of tests/naive/gltf.py on 60 frames; FBX read
    speed on the Blender-made test files."""
    from mocapflow.plugins.formats.fbx import read_fbx
    from mocapflow.plugins.formats.gltf import read_gltf, write_gltf

    src = read_amc(amc)
    reps_needed = -(-n_frames // src.n_frames)
    rot = np.concatenate([src.rotations] * reps_needed)[:n_frames]
    root = np.concatenate([src.root_translation] * reps_needed)[:n_frames]
    big = src.with_arrays(rotations=rot, root_translation=root)
    print(f"glTF, {n_frames:,} frames x {src.n_joints} joints (mocapflow's writer, a CMU take tiled)")
    for ext in (".glb", ".gltf"):
        path = tmp / f"big{ext}"
        t_write = best_of(lambda p=path: write_gltf(big, p), 1)
        size = path.stat().st_size / 1e6
        t_read = best_of(lambda p=path: read_gltf(p), reps)
        t_fk = best_of(lambda p=path: read_gltf(p).positions, reps)
        err = np.abs(read_gltf(path).positions[:600] - big.positions[:600]).max()
        print(f"  read {ext:<6}         {rate(n_frames, t_read)}   [{size:.1f} MB; max |diff| {err:.1e} m]")
        print(f"  read+FK {ext:<6}      {rate(n_frames, t_fk)}")
        print(f"  write {ext:<6}        {rate(n_frames, t_write)}")
    try:
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
        from naive.gltf import naive_gltf_positions
    except ImportError:
        return
    small = tmp / "small.glb"
    write_gltf(big.slice(0, 60), small)
    times = np.arange(60) / big.fps
    plain = best_of(lambda: naive_gltf_positions(small, times), 1)
    ours = best_of(lambda: read_gltf(tmp / "big.glb").positions, 1)
    print(f"  slow twin (naive)   {rate(60, plain)}   [60 frames]")
    print(f"  ratio mocapflow / naive: {ratio(n_frames, ours, 60, plain)}")
    fbx = sorted((Path(__file__).resolve().parent.parent / "tests" / "data" / "blender").glob("*.fbx"))
    for f in fbx:
        n = read_fbx(f).n_frames
        print(f"FBX read+FK {f.name:<20} {rate(n, best_of(lambda f=f: read_fbx(f).positions, max(reps, 3)))}")


def bench_corpus(reps: int) -> None:
    files = sorted((DATA / "cmu" / "amc").glob("*/*.amc")) + sorted((DATA / "hdm05" / "amc").glob("*/*.amc"))
    frames = sum(read_amc(f).n_frames for f in files)
    t_read = best_of(lambda: [read_amc(f) for f in files], reps)
    t_fk = best_of(lambda: [read_amc(f).positions for f in files], reps)
    print(f"Whole AMC corpus: {len(files)} files, {frames:,} frames")
    print(f"  read                {rate(frames, t_read)}")
    print(f"  read+FK             {rate(frames, t_fk)}")
    try:
        from mocapflow.framework.runner import run_pipeline
    except ImportError:
        return
    with tempfile.TemporaryDirectory() as tmp:
        yaml = Path(tmp) / "ingest.yaml"
        yaml.write_text(
            "name: ingest-bench\nsteps:\n  motions:\n    uses: formats.load\n    with:\n      paths:\n"
            f"        - '{DATA}/cmu/amc/**/*.amc'\n        - '{DATA}/hdm05/amc/**/*.amc'\n"
        )
        dt = best_of(lambda: run_pipeline(yaml, workspace=Path(tmp) / "ws", jobs=1, force=True, echo=lambda s: None), 1)
    print(f"  formats.load step   {rate(frames, dt)}   [read, tables, Parquet; jobs=1]")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few files, one repetition")
    args = ap.parse_args(argv)
    if not args.quick and not DATA.exists():
        print(f"corpus not found at {DATA} (--quick runs on examples/data)", file=sys.stderr)
        return 1
    global REF_FRAMES
    if args.quick:
        REF_FRAMES = 60
    with tempfile.TemporaryDirectory() as tmp:
        if args.quick:  # the bundled takes, and BVH files written from two of them
            from mocapflow.plugins.formats.bvh import write_bvh

            amc = sorted(EXAMPLES.glob("cmu/*/*.amc"))
            bvh = [Path(tmp) / f"{f.stem}.bvh" for f in amc[:2]]
            for f, out in zip(amc, bvh, strict=False):
                write_bvh(read_amc(f), out)
        else:
            amc = sorted((DATA / "cmu" / "amc").glob("*/*.amc"))
            bvh = sorted((DATA / "bvh" / "cmu_cgspeed").glob("*.bvh")) + sorted(
                (DATA / "bvh" / "xia_style").glob("*.bvh")
            )
        reps = 1 if args.quick else 3
        _ = read_amc(amc[0]).positions, read_bvh(bvh[0]).positions  # load the numba kernels before timing
        bench_amc(amc, reps)
        bench_bvh(bvh, reps)
        bench_gltf(sorted(EXAMPLES.glob("cmu/*/*.amc"))[0], 20_000 if args.quick else 100_000, Path(tmp), reps)
        if not args.quick:
            bench_corpus(reps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
