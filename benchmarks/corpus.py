"""The benchmark corpus: the real CMU + HDM05 AMC clips, and larger databases grown from them.

Stable API (other benchmarks import this module)::

    import sys; sys.path.insert(0, "<repo>/benchmarks")      # or run from the repo root:
    from corpus import load_corpus, augmented_database        #   python -m benchmarks.<name>

    db = load_corpus(fps=30)                       # MotionDatabase, every AMC of ../shared/data
    big = augmented_database(1_038_388, fps=30)    # MotionDatabase of exactly that many frames
    lib = open_library(build_library(10_000_000, fold=0))   # held-out performers, memory-mapped F_E^15

* :func:`load_corpus` reads every ``cmu/amc/*/*.amc`` and ``hdm05/amc/*/*.amc`` under the
  shared data folder (``MOCAPFLOW_DATA`` overrides it) with
  :func:`mocapflow.plugins.formats.asf_amc.read_amc` and resamples to ``fps`` with
  :func:`mocapflow.framework.normalize.resample` (slerp). At 30 Hz it holds 27,596 frames
  (169 clips, about 15 minutes).
* :func:`augmented_database` grows that corpus to ``n_frames`` (Krüger et al. 2010 Table 1
  uses 380,813 = HDM05 and 1,038,388 = CMU at 30 Hz) by *realistic* augmentation, so that
  the intrinsic dimension of the features stays that of human motion (iid noise on
  features would not): pass ``v = 0`` is the corpus itself; later passes over the clips
  are, alternately, left/right mirrored (:func:`mirror_motion`), time-scaled by a factor in
  [0.85, 1.15] (played faster or slower, resampled with slerp) and given small per-joint
  rotation offsets (about 2 degrees, constant over the clip, as a different performer's
  style) plus a slow 1-degree wobble. The last clip is cut so that the total is exact.
  Deterministic for a given ``seed``; cached on disk as float32 arrays in
  ``$MOCAPFLOW_BENCH_CACHE`` (default ``~/.cache/mocapflow-bench``), about 600 MB for
  1 M frames.
* :func:`build_library` / :func:`open_library`: a search library of any size, streamed to
  disk as F_E^15 rows. The performers are the CMU subjects and HDM05 actors of
  ``../shared/data`` (one folder each, 20 in all). Fold ``k`` holds out every subject whose
  sorted position is ``k`` modulo 4: their clips are *never* in the library, and the held-
  out clips (as recorded, resampled to 30 Hz) are the query source. The library is the other
  subjects' clips, pass after pass, each pass a new copy of every clip that no other copy
  equals: pass 0 the clip itself; every later pass mirrored left/right on odd passes, bone
  lengths scaled (one body factor in [0.9, 1.1] times a factor per bone in [0.95, 1.05]),
  time scaled by a factor in [0.8, 1.25], the per-joint style offsets above, and Gaussian
  noise of 5 mm on every feature coordinate. Rows go straight into a memory-mapped
  ``features.npy`` (float32 (n, 15)), a clip at a time, so no table of the whole library is
  ever held; ``clips.npz`` lists each clip's first row, length, source clip and subject.
  Deterministic for a (size, fold, seed); cached under ``$MOCAPFLOW_BENCH_CACHE`` (60 bytes
  a row: 600 MB at 10 M rows).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapflow.framework import Motion, MotionDatabase, Skeleton
from mocapflow.framework import quaternions as quat
from mocapflow.framework.normalize import resample

REPO = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("MOCAPFLOW_DATA", REPO.parent / "shared" / "data"))
CACHE = Path(os.environ.get("MOCAPFLOW_BENCH_CACHE", Path.home() / ".cache" / "mocapflow-bench"))
PAPER_SIZES = {"hdm05": 380_813, "cmu": 1_038_388}
_VERSION = 1  # bump when the augmentation changes (invalidates the cache)


def corpus_files(data: Path = DATA) -> list[Path]:
    """Every CMU and HDM05 AMC file, sorted."""
    return sorted(data.glob("cmu/amc/*/*.amc")) + sorted(data.glob("hdm05/amc/*/*.amc"))


def load_corpus(fps: float = 30.0, data: Path = DATA) -> MotionDatabase:
    """All CMU + HDM05 AMC clips resampled to ``fps`` (see module doc)."""
    from mocapflow.plugins.formats.asf_amc import read_amc

    files = corpus_files(Path(data))
    if not files:
        raise FileNotFoundError(f"no AMC files under {data}/cmu/amc or {data}/hdm05/amc")
    return MotionDatabase([resample(read_amc(f), fps) for f in files])


# --- mirroring ----------------------------------------------------------------------------

_PAIRS = (("l", "r"), ("Left", "Right"), ("left", "right"), ("L_", "R_"))
_SUFFIX_PAIRS = (("_L", "_R"), ("_l", "_r"), (".L", ".R"))


def mirror_partners(names: tuple[str, ...]) -> np.ndarray:
    """Index of each joint's left/right counterpart (itself for joints on the mid-line)."""
    index = {n: i for i, n in enumerate(names)}
    out = np.arange(len(names))
    for i, n in enumerate(names):
        for a, b in _PAIRS:
            for x, y in ((a, b), (b, a)):
                if n.startswith(x) and y + n[len(x) :] in index:
                    out[i] = index[y + n[len(x) :]]
        for a, b in _SUFFIX_PAIRS:
            for x, y in ((a, b), (b, a)):
                if n.endswith(x) and n[: -len(x)] + y in index:
                    out[i] = index[n[: -len(x)] + y]
    return out


def _reflect_q(q: np.ndarray) -> np.ndarray:
    # conjugating a rotation by the mirror x -> -x: (w, x, y, z) -> (w, x, -y, -z)
    out = np.array(q, copy=True)
    out[..., 2:] *= -1.0
    return out


def mirror_skeleton(sk: Skeleton) -> Skeleton:
    """The skeleton reflected across the x = 0 plane, left and right joints swapped."""
    p = mirror_partners(sk.names)
    flip = np.array([-1.0, 1.0, 1.0])
    axes = None if sk.axes is None else _reflect_q(sk.axes[p])
    return Skeleton(
        sk.names,
        sk.parents,
        sk.offsets[p] * flip,
        canonical=dict(sk.canonical),
        rotation_orders=sk.rotation_orders,
        axes=axes,
        channels=sk.channels,
        name=sk.name + "_mirrored",
        meta=dict(sk.meta),
    )


def mirror_motion(m: Motion, skeleton: Skeleton | None = None) -> Motion:
    """Left/right mirror image of a clip: ``positions[:, j] = M @ original[:, partner(j)]``, M = diag(-1, 1, 1).

    Exact for any skeleton whose left/right joints have mirrored parents (true of ASF/BVH
    humanoids); the skeleton is mirrored too, so asymmetric bone lengths swap sides.
    """
    p = mirror_partners(m.skeleton.names)
    if np.any(m.skeleton.parents[p][1:] != p[m.skeleton.parents[1:]]):
        raise ValueError(f"skeleton {m.skeleton.name!r} is not left/right symmetric in topology")
    sk = skeleton if skeleton is not None else mirror_skeleton(m.skeleton)
    root = m.root_translation * np.array([-1.0, 1.0, 1.0])
    lt = None if m.local_translations is None else m.local_translations[:, p] * np.array([-1.0, 1.0, 1.0])
    return m.with_arrays(
        skeleton=sk,
        rotations=_reflect_q(m.rotations[:, p]),
        root_translation=root,
        local_translations=lt,
        name=m.name + "_mirrored",
    )


# --- augmentation -------------------------------------------------------------------------


def _variant(m: Motion, v: int, rng: np.random.Generator, fps: float, mirrored: dict) -> Motion:
    if v == 0:
        return m
    if v % 2 == 1:
        key = m.skeleton.fingerprint()
        if key not in mirrored:
            mirrored[key] = mirror_skeleton(m.skeleton)
        m = mirror_motion(m, mirrored[key])
    scale = rng.uniform(0.85, 1.15)
    if m.n_frames > 1:
        m = resample(m.with_arrays(fps=fps * scale), fps)  # played `scale` times faster
    t = np.arange(m.n_frames) / fps
    j = m.n_joints
    axis = rng.normal(size=(j, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.radians(rng.normal(0.0, 2.0, size=j))[None, :] + np.radians(1.0) * np.sin(
        2 * np.pi * rng.uniform(0.1, 0.5, size=j)[None, :] * t[:, None] + rng.uniform(0, 2 * np.pi, size=j)
    )
    angle[:, 0] = 0.0  # keep the root's heading and tilt: those are normalised away anyway
    delta = quat.from_axis_angle(np.broadcast_to(axis, (m.n_frames, j, 3)), angle)
    return m.with_arrays(rotations=quat.mul(m.rotations, delta), name=f"{m.name}_v{v}")


def _build_augmented(base: MotionDatabase, n_frames: int, fps: float, seed: int) -> list[Motion]:
    out, total, i, mirrored = [], 0, 0, {}
    while total < n_frames:
        v, c = divmod(i, base.n_clips)
        rng = np.random.default_rng([seed, i])
        m = _variant(base.motions[c], v, rng, fps, mirrored)
        if total + m.n_frames > n_frames:
            m = m.slice(0, n_frames - total)
        out.append(m)
        total += m.n_frames
        i += 1
    return out


def cache_path(n_frames: int, fps: float, seed: int, cache: Path) -> Path:
    """Cache folder of one augmented database; ``fps`` 30 and 30.0 name the same one."""
    fps, n_frames, seed = float(fps), int(n_frames), int(seed)
    key = int(fps) if fps.is_integer() else fps  # 30 and 30.0 hash alike (as 30: the caches made so far)
    files = corpus_files()
    tag = hashlib.sha1(json.dumps([_VERSION, n_frames, key, seed, [f.name for f in files]]).encode()).hexdigest()[:12]
    return Path(cache) / f"augmented_{n_frames}_{fps:g}hz_seed{seed}_{tag}"


def augmented_database(n_frames: int, fps: float = 30.0, seed: int = 0, cache: Path | None = CACHE) -> MotionDatabase:
    """A database of exactly ``n_frames`` frames grown from :func:`load_corpus` (see module doc)."""
    fps = float(fps)
    path = None if cache is None else cache_path(n_frames, fps, seed, cache)
    if path is not None and (path / "done").is_file():
        return _load(path)
    motions = _build_augmented(load_corpus(fps), n_frames, fps, seed)
    if path is not None:
        _save(motions, path)
    return MotionDatabase(motions)


def _save(motions: list[Motion], path: Path) -> None:
    path.mkdir(parents=True, exist_ok=True)
    skels: dict[str, int] = {}
    sk_list, sk_of = [], []
    for m in motions:
        key = m.skeleton.fingerprint()
        if key not in skels:
            skels[key] = len(sk_list)
            sk_list.append(m.skeleton.to_dict())
        sk_of.append(skels[key])
    np.save(
        path / "rotations.npy",
        np.concatenate([m.rotations.reshape(m.n_frames, -1) for m in motions]).astype(np.float32),
    )
    np.save(path / "root.npy", np.concatenate([m.root_translation for m in motions]).astype(np.float32))
    meta = {"skeletons": sk_list, "clips": [[m.name, sk_of[i], m.n_frames, m.fps] for i, m in enumerate(motions)]}
    (path / "meta.json").write_text(json.dumps(meta))
    (path / "done").write_text("ok")


def _load(path: Path) -> MotionDatabase:
    meta = json.loads((path / "meta.json").read_text())
    sks = [Skeleton.from_dict(d) for d in meta["skeletons"]]
    rot = np.load(path / "rotations.npy", mmap_mode="r")
    root = np.load(path / "root.npy", mmap_mode="r")
    motions, at = [], 0
    for name, s, n, fps in meta["clips"]:
        sk = sks[s]
        r = quat.normalize(np.asarray(rot[at : at + n], np.float64).reshape(n, sk.n_joints, 4))
        motions.append(Motion(sk, np.asarray(root[at : at + n], np.float64), r, fps, name=name))
        at += n
    return MotionDatabase(motions)


# --- the held-out-performer library (streamed F_E^15 rows) ----------------------------------

_LIBRARY_VERSION = 1
NOISE_M = 0.005


def subjects_of(files: list[Path]) -> list[str]:
    """The performer of each file: its folder (CMU subject number, HDM05 actor initials)."""
    return [f.parent.name for f in files]


def held_out(subjects: list[str], fold: int) -> set[str]:
    names = sorted(set(subjects))
    return {s for i, s in enumerate(names) if i % 4 == fold % 4}


def _scaled_skeleton(sk, rng):
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


def library_variant(m, v: int, rng: np.random.Generator, fps: float, mirrored: dict):
    """Copy ``v`` of clip ``m`` (``v`` 0: the clip itself), see the module doc."""
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


def load_takes(fps: float, data: Path | None, files: list[Path] | None = None):
    """The AMC takes of ``data`` (or ``files``) resampled to ``fps``: (files, motions)."""
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

    files, motions = base if base is not None else load_takes(fps, data)
    subj = subjects_of(files)
    hide = held_out(subj, fold)
    tag = hashlib.sha1(json.dumps([_LIBRARY_VERSION, n_rows, fold, seed, fps, [str(f.name) for f in files]]).encode())
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
        f = fe.transform_motion(library_variant(motions[c], v, rng, fps, mirrored))
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
