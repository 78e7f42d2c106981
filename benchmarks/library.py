"""A search library of any size grown from ../shared/data, streamed to disk as F_E^15 rows.

Stable API (``benchmarks/search_scale.py`` uses it)::

    from library import build_library, open_library
    lib = open_library(build_library(10_000_000, fold=0))   # memory-mapped features

The performers are the CMU subjects and HDM05 actors of ``../shared/data`` (one folder each,
20 in all). Fold ``k`` holds out every subject whose sorted position is ``k`` modulo 4: their
clips are *never* in the library, and the held-out clips (as recorded, resampled to 30 Hz)
are the query source. The library is the other subjects' clips, pass after pass, each pass a
new copy of every clip that no other copy equals:

* pass 0: the clip itself; every later pass, all of:
* mirrored left/right on odd passes (:func:`corpus.mirror_motion`);
* bone lengths scaled: one body factor in [0.9, 1.1] times a factor per bone in [0.95, 1.05];
* time scaled by a factor in [0.8, 1.25] (played faster or slower, resampled with slerp);
* per-joint rotation offsets of about 2 degrees plus a slow 1-degree wobble (a performer's
  style, as :mod:`corpus`), and Gaussian noise of 5 mm on every feature coordinate.

Rows go straight into a memory-mapped ``features.npy`` (float32 (n, 15)), a clip at a time, so
no table of the whole library is ever held; ``clips.npz`` lists each clip's first row, length,
source clip and subject. Deterministic for a (size, fold, seed); cached under
``$MOCAPFLOW_BENCH_CACHE`` (60 bytes a row: 600 MB at 10 M rows).
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from corpus import CACHE, DATA, corpus_files, mirror_motion, mirror_skeleton

_VERSION = 1
NOISE_M = 0.005


def subjects_of(files: list[Path]) -> list[str]:
    """The performer of each file: its folder (CMU subject number, HDM05 actor initials)."""
    return [f.parent.name for f in files]


def held_out(subjects: list[str], fold: int) -> set[str]:
    names = sorted(set(subjects))
    return {s for i, s in enumerate(names) if i % 4 == fold % 4}


def _scaled_skeleton(sk, rng):
    from mocapflow.framework import Skeleton

    f = rng.uniform(0.9, 1.1) * rng.uniform(0.95, 1.05, size=(sk.n_joints, 1))
    return Skeleton(
        sk.names,
        sk.parents,
        sk.offsets * f,
        canonical=dict(sk.canonical),
        rotation_orders=sk.rotation_orders,
        axes=sk.axes,
        channels=sk.channels,
        name=sk.name,
        meta=dict(sk.meta),
    )


def variant(m, v: int, rng: np.random.Generator, fps: float, mirrored: dict):
    """Copy ``v`` of clip ``m`` (``v`` 0: the clip itself), see the module doc."""
    from mocapflow.framework import quaternions as quat
    from mocapflow.framework.normalize import resample

    if v == 0:
        return m
    if v % 2 == 1:
        key = m.skeleton.fingerprint()
        if key not in mirrored:
            mirrored[key] = mirror_skeleton(m.skeleton)
        m = mirror_motion(m, mirrored[key])
    m = m.with_arrays(skeleton=_scaled_skeleton(m.skeleton, rng))
    scale = rng.uniform(0.8, 1.25)
    if m.n_frames > 1:
        m = resample(m.with_arrays(fps=fps * scale), fps)
    t = np.arange(m.n_frames) / fps
    j = m.n_joints
    axis = rng.normal(size=(j, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.radians(rng.normal(0.0, 2.0, size=j))[None, :] + np.radians(1.0) * np.sin(
        2 * np.pi * rng.uniform(0.1, 0.5, size=j)[None, :] * t[:, None] + rng.uniform(0, 2 * np.pi, size=j)
    )
    angle[:, 0] = 0.0
    delta = quat.from_axis_angle(np.broadcast_to(axis, (m.n_frames, j, 3)), angle)
    return m.with_arrays(rotations=quat.mul(m.rotations, delta), name=f"{m.name}_v{v}")


def _base(fps: float, data: Path | None, files: list[Path] | None = None):
    """The AMC takes of ``data`` (or ``files``) resampled to ``fps``: (files, motions)."""
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc

    files = corpus_files(Path(data)) if files is None else files
    if not files:
        raise FileNotFoundError(f"no AMC files under {data}/cmu/amc or {data}/hdm05/amc")
    return files, [resample(read_amc(f), fps) for f in files]


def build_library(
    n_rows: int, fold: int = 0, seed: int = 0, fps: float = 30.0, data: Path = DATA, cache: Path = CACHE, base=None
) -> Path:
    """The folder of a library of exactly ``n_rows`` rows (built unless cached); ``base``: (files, motions) to grow from."""
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    files, motions = base if base is not None else _base(fps, data)
    subj = subjects_of(files)
    hide = held_out(subj, fold)
    tag = hashlib.sha1(json.dumps([_VERSION, n_rows, fold, seed, fps, [str(f.name) for f in files]]).encode())
    path = Path(cache) / f"library_{n_rows}_f{fold}_s{seed}_{tag.hexdigest()[:10]}"
    if (path / "done").is_file():
        return path
    path.mkdir(parents=True, exist_ok=True)
    fe = EndEffectorFeatures(joints=5)
    lib = [c for c in range(len(files)) if subj[c] not in hide]
    x = np.lib.format.open_memmap(path / "features.npy", mode="w+", dtype=np.float32, shape=(n_rows, 15))
    starts, lengths, source = [], [], []
    total, i, mirrored, t0 = 0, 0, {}, time.perf_counter()
    while total < n_rows:
        v, k = divmod(i, len(lib))
        c = lib[k]
        rng = np.random.default_rng([seed, fold, i])
        f = fe.transform_motion(variant(motions[c], v, rng, fps, mirrored))
        if v > 0:
            f = f + rng.normal(0.0, NOISE_M, f.shape).astype(np.float32)
        f = f[: n_rows - total]
        x[total : total + len(f)] = f
        starts.append(total)
        lengths.append(len(f))
        source.append(c)
        total += len(f)
        i += 1
        if i % 2000 == 0:
            print(f"  library: {total:,} / {n_rows:,} rows, {time.perf_counter() - t0:.0f} s", flush=True)
    x.flush()
    del x
    np.savez(
        path / "clips.npz",
        start=np.asarray(starts, np.int64),
        length=np.asarray(lengths, np.int64),
        source=np.asarray(source, np.int32),
    )
    (path / "meta.json").write_text(json.dumps({"files": [str(f) for f in files], "subjects": subj, "fold": fold}))
    (path / "done").write_text(f"{time.perf_counter() - t0:.1f} s")
    return path


@dataclass
class Library:
    features: np.ndarray  # float32 (n, 15), memory-mapped
    clip_id: np.ndarray  # int32 (n,)
    frame: np.ndarray  # int32 (n,)
    source: np.ndarray  # int32 (clips,): index of the source file
    files: list[str]
    subjects: list[str]
    fold: int


def open_library(path: Path) -> Library:
    meta = json.loads((path / "meta.json").read_text())
    c = np.load(path / "clips.npz")
    x = np.load(path / "features.npy", mmap_mode="r")
    clip_id = np.repeat(np.arange(len(c["length"]), dtype=np.int32), c["length"])
    frame = (np.arange(len(x), dtype=np.int64) - np.repeat(c["start"], c["length"])).astype(np.int32)
    return Library(x, clip_id, frame, c["source"], meta["files"], meta["subjects"], meta["fold"])
