"""Benchmark of the MDM cleaner's motion-word KNN (Aristidou 2018 §5 "Implementation").

Paper (MATLAB, six-core i7): about 140 s for a 20 s clip with local context, about 3 h with
a 600 s context. Targets on the 2-core development machine: <= 2 s and <= 120 s, with the
KNN identical to brute force.

Cases (CMU corpus at ../shared/data, resampled to 24 fps):

1. a 20 s take (14_02, first 20 s) against itself: full MDM analysis with the pruned KNN,
   then with the brute-force KNN, neighbours compared;
2. the same take against a ~600 s context of CMU takes: the pruned KNN, and (unless
   ``--skip-brute``) the brute force on a 60 s slice of that context, extrapolated.

    python benchmarks/cleaning.py            # both cases
    python benchmarks/cleaning.py --quick    # 10 s take, 120 s context
"""
from __future__ import annotations

import argparse
import glob
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
CMU = REPO.parent / "shared" / "data" / "cmu" / "amc"


def _load(path: str, fps: float = 24.0):
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc

    return resample(read_amc(path), fps)


def _search(tex, ctx_q, self_clip, method):
    from mocapflow.plugins.selfsim.knn import ContextTextures, knn_search
    from mocapflow.plugins.selfsim.motion_words import DEFAULT_GROUPS, resolve_groups, source_word_starts

    ctx = ContextTextures.from_arrays(ctx_q)
    groups = resolve_groups(tex.joints, DEFAULT_GROUPS)
    starts = source_word_starts(tex.n_frames, 15, 5)
    t0 = time.perf_counter()
    res = knn_search(tex.q, ctx, groups, self_clip=self_clip, word_starts=starts, method=method)
    return res, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10 s take and a 120 s context")
    ap.add_argument("--skip-brute", action="store_true", help="no brute force in the large case")
    args = ap.parse_args(argv)
    if not CMU.is_dir():
        print(f"corpus not found at {CMU}", file=sys.stderr)
        return 1
    from mocapflow.plugins.selfsim.mdm import MDMParams, digression_map
    from mocapflow.plugins.selfsim.motion_words import motion_texture

    take_s = 10.0 if args.quick else 20.0
    ctx_s = 120.0 if args.quick else 600.0
    take = _load(str(CMU / "14" / "14_02.amc"))
    take = take.slice(0, int(take_s * 24))
    take = take.with_arrays(name="14_02[:%ds]" % take_s)
    # warm-up: compile the kernels on a tiny input (numba caches them on disk)
    digression_map(take.slice(0, 40))

    print(f"case 1: {take.name} ({take.n_frames} frames at 24 fps) against itself")
    t0, c0 = time.perf_counter(), time.process_time()
    res = digression_map(take, None, MDMParams(knn_method="pruned"))
    t_fast, c_fast = time.perf_counter() - t0, time.process_time() - c0
    t0 = time.perf_counter()
    ref = digression_map(take, None, MDMParams(knn_method="brute"))
    t_brute = time.perf_counter() - t0
    same = all(np.array_equal(a.target, b.target) and np.array_equal(a.distance, b.distance)
               for a, b in zip(res.neighbours, ref.neighbours))
    print(f"  MDM analysis, pruned KNN : {t_fast:7.2f} s  ({res.n_dtw} DTWs)   target <= 2 s, paper ~140 s")
    print(f"     CPU time of this process: {c_fast:.2f} s (an idle 2-core machine needs between half of it and all of it; "
          f"load average now {os.getloadavg()[0]:.1f})")
    print(f"  MDM analysis, brute KNN  : {t_brute:7.2f} s  ({ref.n_dtw} DTWs)")
    print(f"  speed-up pruned/brute    : {t_brute / t_fast:7.2f} x   DTWs avoided {1 - res.n_dtw / ref.n_dtw:.1%}")
    print(f"  KNN identical to brute force: {same}")
    from mocapflow.plugins.selfsim.mdm import MDMCleaner

    c0 = time.process_time()
    MDMCleaner(mode="paper", write_bvh=False, heatmaps=False).clean(take)
    c_paper = time.process_time() - c0
    c0 = time.process_time()
    MDMCleaner(write_bvh=False, heatmaps=False).clean(take)
    c_cal = time.process_time() - c0
    print(f"  whole clean (analysis, decision, repair), CPU: paper {c_paper:.2f} s, calibrated {c_cal:.2f} s "
          f"(ratio {c_cal / c_paper:.2f}; the calibration analyses the take once more with synthetic errors)")

    # case 2: a context of CMU takes adding up to ctx_s seconds (the take's own subject first)
    files = sorted(glob.glob(str(CMU / "*" / "*.amc")))
    context, total = [], 0.0
    for f in files:
        if Path(f).stem == "14_02" or total >= ctx_s:
            continue
        m = _load(f)
        context.append(m)
        total += m.duration
    tex = motion_texture(take, MDMParams().joints)
    joints = tuple(j for j in tex.joints if all(j in c.skeleton.canonical for c in context))
    tex = motion_texture(take, joints)
    ctx_q = [tex.q] + [motion_texture(c, joints).q for c in context]
    n_ctx = sum(len(q) for q in ctx_q)
    print(f"case 2: {take.name} against {len(context)} takes + itself, {n_ctx / 24:.0f} s ({n_ctx} frames at 24 fps)")
    c0 = time.process_time()
    fast, t_big = _search(tex, ctx_q, 0, "pruned")
    c_big = time.process_time() - c0
    brute_dtw = 5 * len(fast.starts) * sum(max(0, len(q) - 15 + 1) for q in ctx_q)
    print(f"  KNN, pruned              : {t_big:7.2f} s  ({fast.n_dtw} of {brute_dtw} DTWs, "
          f"{1 - fast.n_dtw / brute_dtw:.1%} avoided)   target <= 120 s, paper ~3 h")
    print(f"     CPU time of this process: {c_big:.2f} s")
    if not args.skip_brute:
        # brute force on the first ~60 s of the context, scaled by frames
        part, acc = [], 0
        for q in ctx_q:
            if acc >= 60 * 24:
                break
            part.append(q)
            acc += len(q)
        fp, tp = _search(tex, part, 0, "pruned")
        bp, tb = _search(tex, part, 0, "brute")
        same = np.array_equal(fp.target, bp.target) and np.array_equal(fp.distance, bp.distance)
        est = tb * n_ctx / acc
        print(f"  brute force on {acc / 24:.0f} s of it : {tb:7.2f} s (pruned {tp:.2f} s, identical: {same}); "
              f"brute on the whole context ~{est:.0f} s by extrapolation, pruned speed-up ~{est / t_big:.1f} x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
