"""Reconstruction from 6 sparse markers (Krüger et al. 2010 §5.2): leave-one-subject-out.

    python benchmarks/reconstruct.py                # LOSO over the CMU subjects of ../shared/data
    python benchmarks/reconstruct.py --quick        # the bundled examples/data takes (3 subjects)
    python benchmarks/reconstruct.py --clips-per-subject 2 --seed 1   # another rotation of test clips

Prior: every take of ../shared/data usable as one (CMU and HDM05 ASF/AMC, the BVH sets:
cgspeed CMU, Xia styles, PyMO, Bandai-Namco -- read at run time, never copied), each with
its mirror image, resampled to 30 Hz, built once into ``$MOCAPFLOW_BENCH_CACHE`` and
memory-mapped. Test: for every CMU subject, ``--clips-per-subject`` of its AMC takes
(which ones rotates with ``--seed``), the first ``--max-frames`` frames at 30 Hz; the prior
withholds every take of that subject (AMC and BVH, mirror images too) and is retargeted to
the subject's bone lengths. Synthetic markers (root, head, wrists, ankles; ±1 mm).

Prints per clip ``avg (worst frame) [worst joint]`` cm and the mean confidence; for both
the root's heading given (a pelvis marker cluster; synthetic: from the hips ±1 mm) and six
points only (heading estimated): the mean over clips with a bootstrap 95 % CI (2000
resamples), the share of clips <= 3.5 cm, the worst frame and single joint error, the worst
clips, per-joint mean and worst errors, how the per-frame confidence ranks the frame errors
(Spearman) and the error of frames below/above confidence 0.5, frames per second (one
thread, prior built); then two baselines measured in the same run (the prior retargeted
to the median test skeleton instead of the performer's; the previous model: k 64, sides
from the solve, no smoothing pass: error and speed ratios), real takes at their own rate,
and the prior-size curve (nested random subsets of the prior takes, first test clip of
every subject). ``--rate native`` reconstructs the test clips at their own rate (CMU
AMC: 120 Hz), ``--rate 60`` at 60 Hz (``--max-frames`` is counted at 30 Hz: the same
seconds at any rate).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import CACHE, DATA, REPO

from mocapflow.framework import Motion
from mocapflow.framework.normalize import resample
from mocapflow.plugins.similarity.applications.reconstruct import MODEL, PosePrior, ReconstructModel, ReconstructParams
from mocapflow.plugins.similarity.applications.reconstruct_prior import PriorStore, bone_lengths, build_store
from mocapflow.plugins.similarity.applications.reconstruct_synthetic import PriorCache, reconstruct_motion, withheld

TARGET_CLIP_CM = 3.5
#: The model before the knee/elbow sides and the smoothing pass (speed and accuracy baseline).
PREVIOUS = dataclasses.replace(MODEL, swivel_states=0, smooth_passes=0)
PREVIOUS_K = 64


def prior_files(data: Path) -> list[Path]:
    """Every take usable as a prior: ASF/AMC of CMU and HDM05, every BVH set."""
    amc = sorted(data.glob("cmu/amc/*/*.amc")) + sorted(data.glob("cmu/*/*.amc"))
    return amc + sorted(data.glob("hdm05/amc/*/*.amc")) + sorted(data.glob("bvh/*/*.bvh"))


def read_take(path: Path) -> Motion:
    """A take with its performer in ``metadata['subject']`` (cgspeed BVH: the CMU subject)."""
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.bvh import read_bvh

    if path.suffix.lower() == ".amc":
        return read_amc(path)
    m = read_bvh(path)
    cmu = re.match(r"(?:cmu_)?(\d+)_\d+", path.stem) if path.parent.name == "cmu_cgspeed" else None
    subject = cmu.group(1).zfill(2) if cmu else path.parent.name
    return m.with_arrays(metadata={**m.metadata, "subject": subject, "source": path.parent.name})


def load_store(files: list[Path], fps: float = 30.0) -> PriorStore:
    """The prior store of ``files`` (built once, cached, memory-mapped)."""
    tag = hashlib.sha1(json.dumps([1, fps, [str(f.relative_to(f.parents[2])) for f in files]]).encode()).hexdigest()[
        :12
    ]
    folder = CACHE / f"reconstruct_prior_{tag}"
    if not (folder / "clips.json").is_file():
        t = time.perf_counter()
        build_store((read_take(f) for f in files), fps=fps).save(folder)
        print(f"  prior built in {time.perf_counter() - t:.0f} s -> {folder}")
    return PriorStore.load(folder)


def bootstrap_ci(values: np.ndarray, n: int = 2000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile bootstrap interval of the mean."""
    rng = np.random.default_rng(seed)
    means = values[rng.integers(0, len(values), (n, len(values)))].mean(1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def run_loso(
    tests: list[Motion],
    store: PriorStore,
    lengths: np.ndarray | None = None,
    verbose: bool = True,
    model: ReconstructModel = MODEL,
    params: ReconstructParams | None = None,
) -> dict:
    """Every test clip against the prior without its subject (retargeted to the clip's
    skeleton, or to bone ``lengths`` if given); the error summary."""
    cache, params = PriorCache(store, model), params or ReconstructParams()
    rows, frames, seconds = [], 0, 0.0
    joint_mean, joint_max, conf, frame_cm, frame_max = [], [], [], [], []
    for m in tests:
        if lengths is not None:
            prior = cache.get(~withheld(store, m, "subject"), lengths)
        else:
            prior = cache.for_motion(m, "subject")
        _, e = reconstruct_motion(m, prior, params, model)
        rows.append((m.name, e["avg_cm"], e["max_frame_cm"], e["max_joint_cm"], float(np.mean(e["confidence"]))))
        frames += m.n_frames
        seconds += e["seconds"]
        joint_mean.append(e["mean_cm"])
        joint_max.append(e["max_cm"])
        conf.append(e["confidence"])
        frame_cm.append(e["frame_cm"])
        frame_max.append(e["frame_max_cm"])
        if verbose:
            print(
                f"  {m.name:>8} {m.fps:4.0f} Hz {e['avg_cm']:6.2f} ({e['max_frame_cm']:6.2f}) [{e['max_joint_cm']:6.1f}] "
                f"confidence {np.mean(e['confidence']):.2f}",
                flush=True,
            )
    avg = np.array([r[1] for r in rows])
    jmax = np.array(joint_max)
    return {
        "rows": rows,
        "mean": float(avg.mean()),
        "ci": bootstrap_ci(avg),
        "share": float((avg <= TARGET_CLIP_CM).mean()),
        "max_joint": max(r[3] for r in rows),
        "max_frame": max(r[2] for r in rows),
        "joints": dict(zip(prior.joints, np.mean(joint_mean, 0), strict=True)),
        "joint_worst": {
            j: (float(jmax[:, i].max()), rows[int(np.argmax(jmax[:, i]))][0]) for i, j in enumerate(prior.joints)
        },
        "confidence": np.concatenate(conf),
        "frame_cm": np.concatenate(frame_cm),
        "frame_max_cm": np.concatenate(frame_max),
        "fps": frames / seconds,
    }


def report(label: str, r: dict) -> None:
    lo, hi = r["ci"]
    print(
        f"{label}: mean {r['mean']:.2f} cm per joint (95 % CI {lo:.2f}-{hi:.2f}), "
        f"{r['share']:.0%} of {len(r['rows'])} clips <= {TARGET_CLIP_CM} cm, worst frame {r['max_frame']:.1f} cm, "
        f"worst joint {r['max_joint']:.1f} cm, {r['fps']:.0f} frames/s"
    )


def report_details(r: dict) -> None:
    """Worst clips, per-joint mean and worst errors, and how the confidence tracks the error."""
    from scipy.stats import spearmanr

    worst = sorted(r["rows"], key=lambda x: -x[1])[:5]
    print("  worst clips (avg cm [worst joint]): " + ", ".join(f"{n} {a:.2f} [{w:.1f}]" for n, a, _, w, _ in worst))
    print("  per joint, mean cm: " + ", ".join(f"{j} {v:.1f}" for j, v in r["joints"].items()))
    print("  per joint, worst cm (clip): " + ", ".join(f"{j} {v:.1f} ({c})" for j, (v, c) in r["joint_worst"].items()))
    c, e = r["confidence"], r["frame_cm"]
    low = c < 0.5
    print(
        f"  confidence: Spearman {spearmanr(c, e)[0]:.2f} against the frame error; frames < 0.5: {low.mean():.0%} "
        f"(mean error {e[low].mean() if low.any() else float('nan'):.2f} cm) vs >= 0.5 "
        f"{e[~low].mean() if (~low).any() else float('nan'):.2f} cm; frames with a joint > 30 cm: "
        f"{', '.join(f'{n}' for n, _, _, w, _ in r['rows'] if w > 30) or 'none'}"
    )
    print(
        "  worst joint of the frames with confidence >= "
        + ", ".join(
            f"{c0:g}: {r['frame_max_cm'][c >= c0].max() if (c >= c0).any() else float('nan'):.1f} cm "
            f"({(c >= c0).mean():.0%} of frames)"
            for c0 in (0.05, 0.1, 0.2, 0.5)
        )
    )


def user_runs(store: PriorStore, data: Path) -> None:
    """What the CLI does, on real takes at their own rate (prior without the take's subject):
    CMU 135_02 from its C3D markers (marker set ``vicon``) on the subject's ASF skeleton,
    compared with the same take's AMC (frames aligned by the yaw and shift that best map
    the control points; skin markers sit off the joint centres: that offset is printed),
    and cgspeed BVH takes from their own end effectors, compared with themselves."""
    from mocapflow.plugins.formats.asf_amc import read_amc, read_asf
    from mocapflow.plugins.formats.c3d import read_c3d
    from mocapflow.plugins.similarity.applications.reconstruct import reconstruct_positions
    from mocapflow.plugins.similarity.applications.reconstruct_markers import control_from_markers, control_from_motion
    from mocapflow.plugins.similarity.applications.reconstruct_synthetic import joint_errors
    from mocapflow.plugins.similarity.applications.retarget import positions_to_motion

    def prior_for(skeleton_take: Motion, subject: str) -> PosePrior:
        keep = np.array([c["subject"] != subject for c in store.clips])
        return PosePrior.build(store, bone_lengths(skeleton_take.canonical_positions(store.joints), store.joints), keep)

    c3d, amc = data / "c3d/cmu/135_02.c3d", data / "cmu/amc/135/135_02.amc"
    if c3d.is_file() and amc.is_file():
        truth = read_amc(amc)
        control, heading, _, _ = control_from_markers(read_c3d(c3d), "vicon")
        want, _ = control_from_motion(truth)
        n = min(len(control), len(want))
        a, b = control[:n].reshape(-1, 3), want[:n].reshape(-1, 3)
        ca, cb = a.mean(0), b.mean(0)
        s = np.sum((b - cb)[:, 0] * (a - ca)[:, 2] - (b - cb)[:, 2] * (a - ca)[:, 0])
        c = np.sum((b - cb)[:, 0] * (a - ca)[:, 0] + (b - cb)[:, 2] * (a - ca)[:, 2])
        yaw = np.arctan2(s, c)
        rot = np.array([[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]])
        prior = prior_for(truth, "135")
        t = time.perf_counter()
        world, _ = reconstruct_positions(control[:n], prior, root_heading=heading[:n], fps=truth.fps)
        sec = time.perf_counter() - t
        out = positions_to_motion(read_asf(amc.parent / "135.asf"), world, prior.joints, truth.fps)
        aligned = (out.canonical_positions(prior.joints) - ca) @ rot.T + cb
        _, _, avg, worst = joint_errors(aligned, truth.canonical_positions(prior.joints)[:n])
        off = np.linalg.norm(((control[:n] - ca) @ rot.T + cb) - want[:n], axis=-1).mean(0) * 100
        print(
            f"  135_02.c3d -> 135.asf ({n} frames at {truth.fps:g} Hz): {avg:.2f} cm per joint against the AMC "
            f"(worst frame {worst:.1f}); marker centres off the joints: "
            + ", ".join(
                f"{p} {v:.1f}"
                for p, v in zip(("root", "head", "lwrist", "rwrist", "lankle", "rankle"), off, strict=True)
            )
            + f" cm; {n / sec:.0f} frames/s"
        )
    for f in sorted(data.glob("bvh/cmu_cgspeed/*.bvh")):
        take = read_take(f)
        control, heading = control_from_motion(take)
        prior = prior_for(take, str(take.metadata["subject"]))
        t = time.perf_counter()
        world, _ = reconstruct_positions(control, prior, root_heading=heading, fps=take.fps)
        sec = time.perf_counter() - t
        _, _, avg, worst = joint_errors(world, take.canonical_positions(prior.joints))
        print(
            f"  {f.name} ({take.n_frames} frames at {take.fps:.0f} Hz): {avg:.2f} cm per joint (worst frame {worst:.1f}), {take.n_frames / sec:.0f} frames/s"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--clips-per-subject", type=int, default=3)
    ap.add_argument("--max-frames", type=int, default=450, help="frames per test clip, counted at 30 Hz")
    ap.add_argument("--seed", type=int, default=0, help="rotation of the test clips within each subject")
    ap.add_argument(
        "--rate",
        default="30",
        help="test clips resampled to this rate (Hz; default the prior's 30), or 'native': at their own rate "
        "(CMU AMC: 120 Hz) as users run them",
    )
    ap.add_argument("--no-estimated", action="store_true", help="skip the six-points-only run (heading estimated)")
    ap.add_argument("--no-sizes", action="store_true", help="skip the prior-size curve")
    ap.add_argument("--no-baseline", action="store_true", help="skip the baselines (median skeleton, previous model)")
    ap.add_argument("--no-user-runs", action="store_true", help="skip the real takes at their own rate")
    args = ap.parse_args()
    data = REPO / "examples" / "data" if args.quick else DATA
    if args.quick:
        args.clips_per_subject, args.max_frames = 1, 120

    t0 = time.perf_counter()
    files = prior_files(data)
    store = load_store(files)
    test_files = sorted(data.glob("cmu/*/*.amc") if args.quick else data.glob("cmu/amc/*/*.amc"))
    by_subject: dict[str, list[Path]] = {}
    for f in test_files:
        by_subject.setdefault(f.parent.name, []).append(f)
    rng = np.random.default_rng(args.seed)
    chosen = [f for s in sorted(by_subject) for f in rng.permutation(by_subject[s])[: args.clips_per_subject]]
    tests = [read_take(Path(f)) for f in chosen]
    if args.rate != "native":
        try:
            rate = float(args.rate)
        except ValueError:
            ap.error(f"--rate must be a number of Hz or 'native', got {args.rate!r}")
        tests = [resample(m, rate) for m in tests]
    tests = [m.slice(0, min(m.n_frames, int(round(args.max_frames * m.fps / 30.0)))) for m in tests]
    print(
        f"prior: {len(store.clips)} takes (with mirror images), {store.n_frames} frames at {store.fps:g} Hz; "
        f"test: {len(tests)} clips of {len(by_subject)} subjects at {args.rate} Hz, "
        f"{sum(m.n_frames for m in tests)} frames (loaded in {time.perf_counter() - t0:.0f} s)"
    )
    warm = tests[0].slice(0, min(tests[0].n_frames, 20))  # compile the kernels before timing
    reconstruct_motion(warm, PosePrior.build(store, bone_lengths(warm.canonical_positions(store.joints), store.joints)))
    print(f"per clip: avg (worst frame) [worst joint] cm, mean confidence (k {ReconstructParams().k})")
    res = run_loso(tests, store)
    report("heading from the pelvis markers", res)
    report_details(res)
    if not args.no_estimated:
        est = run_loso(tests, store, verbose=False, model=dataclasses.replace(MODEL, root_heading=False))
        report("six points only (heading estimated)", est)
        report_details(est)

    if not args.no_baseline:
        med = np.median([bone_lengths(m.canonical_positions(store.joints), store.joints) for m in tests], 0)
        base = run_loso(tests, store, med, verbose=False)
        report("baseline (median test skeleton)", base)
        print(f"  ratio performer/baseline: mean error {res['mean'] / base['mean']:.2f}")
        old = run_loso(tests, store, verbose=False, model=PREVIOUS, params=ReconstructParams(k=PREVIOUS_K))
        report(f"baseline (previous model: k {PREVIOUS_K}, sides from the solve, no smoothing pass)", old)
        print(
            f"  ratio current/previous: mean error {res['mean'] / old['mean']:.2f}, "
            f"worst joint {res['max_joint'] / old['max_joint']:.2f}, speed {res['fps'] / old['fps']:.2f}"
        )

    if not (args.quick or args.no_user_runs):
        print("user runs (the CLI's path, real takes at their own rate, prior without the subject):")
        user_runs(store, data)

    if not args.no_sizes:
        print("prior size (first test clip of every subject; nested random subsets of the prior takes):")
        firsts = [next(m for m in tests if m.metadata.get("subject") == s) for s in sorted(by_subject)]
        order = np.random.default_rng(args.seed).permutation(len(store.clips))
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        for frac in (0.1, 0.3, 1.0):
            errs, sizes = [], []
            for m in firsts:
                keep = ~withheld(store, m, "subject") & (rank < max(1, int(round(frac * len(order)))))
                lengths = bone_lengths(m.canonical_positions(store.joints), store.joints)
                prior = PosePrior.build(store, lengths, keep)
                _, e = reconstruct_motion(m, prior)
                errs.append(e["avg_cm"])
                sizes.append(len(prior.poses))
            print(f"  {frac:4.0%}: prior {np.mean(sizes):8.0f} frames  mean {np.mean(errs):.2f} cm")


if __name__ == "__main__":
    main()
