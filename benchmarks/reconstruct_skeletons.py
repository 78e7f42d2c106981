"""Reconstruction onto any skeleton: CMU, HDM05, Bandai-Namco, Xia, cgspeed and PyMO rigs.

    python benchmarks/reconstruct_skeletons.py                  # every family, 8 clips each, 5 s per clip
    python benchmarks/reconstruct_skeletons.py --quick          # 2 clips per family, 2 s each

For each skeleton family of ../shared/data, ``--clips`` takes (spread over its subjects,
chosen by ``--seed``; the first ``--seconds`` of each, at the take's own rate) are
reconstructed from their own root, head, wrists and ankles with the root's heading from
their hips, as ``mocapflow reconstruct`` does with a skeleton take. The skeleton is read
through the spine rule (:func:`~mocapflow.plugins.similarity.applications.reconstruct_prior.pose_skeleton`):
its pose joints are the canonical joints it has, composite bones where it lacks some. The
prior (every take of ../shared/data, mirror images, 30 Hz; cached like
``benchmarks/reconstruct.py``, whose helpers this imports) withholds the take's subject:
a CMU subject (its AMC and cgspeed BVH takes), an HDM05 actor, or the whole BVH set where
the set names no actor (Bandai-Namco, Xia, PyMO).

Prints per family: the mean error per joint over the joints the skeleton has, on the
output skeleton (the reconstructed positions turned into the skeleton's joint rotations),
with a bootstrap 95 % CI over clips; the mean of the reconstructed positions themselves;
the worst joint of any frame; and the CLI run end to end on the family's shortest take
(subprocess, prior store without the take's subject, output file read back and compared
with the input). Then a check of the composite bones: the CMU clips reconstructed on a
Bandai-like (no lowerback) and a PyMO-like (one spine bone, no neck) subset of their own
joints, measured on the joints all three share, against the full skeleton.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import CACHE, DATA, REPO
from reconstruct import bootstrap_ci, prior_files, read_take

from mocapflow.framework import Motion
from mocapflow.plugins.similarity.applications.reconstruct import PosePrior, reconstruct_positions
from mocapflow.plugins.similarity.applications.reconstruct_markers import control_from_motion
from mocapflow.plugins.similarity.applications.reconstruct_prior import (
    PriorStore,
    bone_lengths,
    build_store,
    pose_skeleton,
)
from mocapflow.plugins.similarity.applications.retarget import positions_to_motion

FAMILIES: dict[str, str] = {
    "CMU": "cmu/amc/*/*.amc",
    "HDM05": "hdm05/amc/*/*.amc",
    "Bandai": "bvh/bandai_namco_1/*.bvh",
    "Xia": "bvh/xia_style/*.bvh",
    "cgspeed": "bvh/cmu_cgspeed/*.bvh",
    "PyMO": "bvh/pymo_demo/*.bvh",
}

#: Subsets of the 25 canonical joints that a CMU skeleton is cut down to (composite-bone check).
CUTS: dict[str, tuple[str, ...]] = {"Bandai-like": ("lowerback",), "PyMO-like": ("lowerback", "upperback", "neck")}


def load_store(files: list[Path], fps: float = 30.0) -> PriorStore:
    """The prior store of ``files`` (built once, cached, memory-mapped)."""
    rel = [str(f.relative_to(f.parents[2])) for f in files]
    tag = hashlib.sha1(json.dumps(["skeletons-2", fps, rel]).encode()).hexdigest()[:12]
    folder = CACHE / f"reconstruct_prior_skel_{tag}"
    if not (folder / "clips.json").is_file():
        t = time.perf_counter()
        build_store((read_take(f) for f in files), fps=fps).save(folder)
        print(f"  prior built in {time.perf_counter() - t:.0f} s -> {folder}")
    return PriorStore.load(folder)


def pick(files: list[Path], n: int, seed: int) -> list[Path]:
    """``n`` takes spread over the subjects (round robin over the subject folders; a
    cgspeed take's subject is its CMU number), chosen by ``seed``."""
    rng = np.random.default_rng(seed)
    by: dict[str, list[Path]] = {}
    for f in files:
        by.setdefault(str(read_subject(f)), []).append(f)
    queues = [list(rng.permutation(v)) for _, v in sorted(by.items())]
    out: list[Path] = []
    while len(out) < n and any(queues):
        for q in queues:
            if q and len(out) < n:
                out.append(Path(q.pop(0)))
    return out


def read_subject(f: Path) -> str:
    if f.suffix.lower() == ".amc":
        return f.parent.name
    return str(read_take(f).metadata["subject"]) if f.parent.name == "cmu_cgspeed" else f.parent.name


class Priors:
    """PosePriors per (withheld subject, pose joints, bone lengths), the last one kept."""

    def __init__(self, store: PriorStore, rig: bool = True) -> None:
        self.store, self.rig, self.key, self.prior = store, rig, None, None

    def get(self, subject: str, joints: tuple[str, ...], lengths: np.ndarray, rest: np.ndarray) -> PosePrior:
        key = (subject, joints, np.round(lengths, 4).tobytes(), np.round(rest, 4).tobytes())
        if key != self.key:
            keep = np.array([c["subject"] != subject for c in self.store.clips])
            view = self.store.on_joints(joints, rest if self.rig else None)
            self.prior = PosePrior.build(view, lengths, keep)
            self.key = key
        assert self.prior is not None
        return self.prior


def reconstruct_take(m: Motion, priors: Priors, drop: tuple[str, ...] = ()) -> dict:
    """One take from its own control points on its own skeleton (minus canonical ``drop``)."""
    skel, joints = pose_skeleton(m.skeleton)
    if drop:
        skel = replace(skel, canonical={k: v for k, v in skel.canonical.items() if k not in drop})
        joints = tuple(j for j in joints if j not in drop)
    m = m.with_arrays(skeleton=skel)
    truth = m.canonical_positions(joints)
    control, heading = control_from_motion(m)
    rest = Motion(skel, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, skel.n_joints, 1)), m.fps)
    prior = priors.get(
        str(m.metadata.get("subject", "")), joints, bone_lengths(truth, joints), rest.canonical_positions(joints)[0]
    )
    t = time.perf_counter()
    world, _ = reconstruct_positions(control, prior, root_heading=heading)
    sec = time.perf_counter() - t
    out = positions_to_motion(skel, world, joints, m.fps)
    err = np.linalg.norm(out.canonical_positions(joints) - truth, axis=-1) * 100
    werr = np.linalg.norm(world - truth, axis=-1) * 100
    return {"joints": joints, "err": err, "world": werr, "seconds": sec, "frames": m.n_frames}


def family_report(name: str, rows: list[tuple[str, dict]]) -> None:
    avg = np.array([r["err"].mean() for _, r in rows])
    lo, hi = bootstrap_ci(avg) if len(avg) > 1 else (avg[0], avg[0])
    wavg = np.mean([r["world"].mean() for _, r in rows])
    worst = max(((r["err"].max(), r["joints"][int(r["err"].max(0).argmax())], c) for c, r in rows), key=lambda x: x[0])
    fps = sum(r["frames"] for _, r in rows) / sum(r["seconds"] for _, r in rows)
    print(
        f"{name:>8}: {len(rows)} clips, {len(rows[0][1]['joints'])} pose joints: mean {avg.mean():.2f} cm per joint "
        f"(95 % CI {lo:.2f}-{hi:.2f}) on the output skeleton, {wavg:.2f} cm reconstructed positions; "
        f"worst joint {worst[0]:.1f} cm ({worst[1]}, {worst[2]}); {fps:.0f} frames/s"
    )


def cli_run(f: Path, store: PriorStore, tmp: Path) -> str:
    """``mocapflow reconstruct`` on ``f`` with a prior store without its subject; the output read back."""
    subject = read_subject(f)
    tag = hashlib.sha1(json.dumps([str(f), len(store.clips)]).encode()).hexdigest()[:8]
    folder = CACHE / f"reconstruct_prior_skel_wo_{subject}_{tag}"
    if not (folder / "clips.json").is_file():
        store.select(np.array([c["subject"] != subject for c in store.clips])).save(folder)
    out = tmp / (f.stem + "_recon" + f.suffix.lower())
    exe = shutil.which("mocapflow", path=str(Path(sys.executable).parent) + os.pathsep + os.environ.get("PATH", ""))
    cmd = [exe or "mocapflow", "reconstruct", str(f), "--prior", str(folder), "-o", str(out)]
    t = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True)
    sec = time.perf_counter() - t
    if res.returncode != 0:
        return f"FAILED ({res.returncode}): {(res.stderr or res.stdout).strip()[-300:]}"
    truth = read_take(f)
    back = read_take(out)
    skel, joints = pose_skeleton(truth.skeleton)
    bskel, _ = pose_skeleton(back.skeleton)
    n = min(truth.n_frames, back.n_frames)
    want = truth.with_arrays(skeleton=skel).canonical_positions(joints)[:n]
    got = back.with_arrays(skeleton=bskel).canonical_positions(joints)[:n]
    err = np.linalg.norm(got - want, axis=-1) * 100
    ctrl = [joints.index(j) for j in ("root", "head", "lwrist", "rwrist", "lankle", "rankle")]
    same = back.skeleton.names == truth.skeleton.names
    return (
        f"{out.suffix[1:].upper()} of {back.skeleton.n_joints} joints{' (the input skeleton)' if same else ''}, "
        f"{n} frames at {back.fps:g} Hz read back: {err.mean():.2f} cm per joint, control points {err[:, ctrl].mean():.2f} cm "
        f"(max {err[:, ctrl].max():.1f}); {sec:.0f} s end to end"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="2 clips per family, the first 2 s of each")
    ap.add_argument("--clips", type=int, default=8, help="takes per family")
    ap.add_argument("--seconds", type=float, default=5.0, help="first seconds of each take")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--no-rig", action="store_true", help="clavicles from the prior's rig, not the skeleton's")
    ap.add_argument("--no-cli", action="store_true")
    ap.add_argument("--no-cuts", action="store_true", help="skip the composite-bone check on cut CMU skeletons")
    args = ap.parse_args()
    if args.quick:
        args.clips, args.seconds = 2, 2.0

    data, families = DATA, dict(FAMILIES)
    if not any(DATA.glob(FAMILIES["CMU"])):
        if not args.quick:
            raise SystemExit(f"corpus absent at {DATA} (set MOCAPFLOW_DATA)")
        data, families = REPO / "examples" / "data", {"CMU": "cmu/*/*.amc"}
        print(f"corpus absent at {DATA}: the bundled CMU takes of {data} only (prior and tests, subjects held out)")
    t0 = time.perf_counter()
    store = load_store(prior_files(data))
    src = {}
    for c in store.clips:
        src[c["source"]] = src.get(c["source"], 0) + (not c["mirrored"])
    print(
        f"prior: {len(store.clips)} takes (with mirror images), {store.n_frames} frames at {store.fps:g} Hz "
        f"(takes per source: {', '.join(f'{k} {v}' for k, v in sorted(src.items()))}); loaded in {time.perf_counter() - t0:.0f} s"
    )
    priors = Priors(store, rig=not args.no_rig)
    # compile the kd-tree and solver kernels before timing
    warm = read_take(sorted(data.glob(families["CMU"]))[0])
    reconstruct_take(warm.slice(0, 20), priors)
    cmu_tests: list[Motion] = []
    with tempfile.TemporaryDirectory() as tmp:
        for fam in args.families.split(","):
            files = sorted(data.glob(families[fam])) if fam in families else []
            if not files:
                print(f"{fam:>8}: no takes in {data}")
                continue
            rows = []
            for f in pick(files, args.clips, args.seed):
                m = read_take(f)
                m = m.slice(0, min(m.n_frames, int(round(args.seconds * m.fps))))
                rows.append((f.stem, reconstruct_take(m, priors)))
                if fam == "CMU":
                    cmu_tests.append(m)
            family_report(fam, rows)
            if not args.no_cli:
                shortest = min(files, key=lambda p: p.stat().st_size)
                print(f"          CLI {shortest.name}: {cli_run(shortest, store, Path(tmp))}")
    if cmu_tests and not args.no_cuts:
        print("composite bones: CMU clips on cut-down skeletons, on the joints all share")
        full = [reconstruct_take(m, priors) for m in cmu_tests]
        for cut, drop in CUTS.items():
            part = [reconstruct_take(m, priors, drop) for m in cmu_tests]
            common = [j for j in part[0]["joints"] if j not in sum(CUTS.values(), ())]
            a = np.array([r["err"][:, [r["joints"].index(j) for j in common]].mean() for r in full])
            b = np.array([r["err"][:, [r["joints"].index(j) for j in common]].mean() for r in part])
            lo, hi = bootstrap_ci(b - a)
            print(
                f"  {cut:>11} (no {', '.join(drop)}): {b.mean():.2f} cm vs full skeleton {a.mean():.2f} cm "
                f"(difference {np.mean(b - a):+.2f}, 95 % CI {lo:+.2f} to {hi:+.2f}) over {len(common)} joints"
            )


if __name__ == "__main__":
    main()
