"""Clean takes cleaned at their own frame rate, as `mocapflow clean` does (issue 14).

The protocol (`benchmarks/cleaning_protocol.py`) resamples every clip to the analysis rate
(24 fps) before it injects errors, so it never sees how a repair computed at 24 fps is
carried to a 120-fps take. This script cleans the protocol's held-out (or tuning) *clean*
takes at their native rate with the protocol's small context (the 8 longest other clips,
never the clip itself nor, for dance, its partner's take) and prints, per take and per
category, the share of input cells (frames x texture joints) edited and the largest edit,
for the default cleaner and for the same decision carried without the guard of
`repair.apply_to_input` (``guard=False``, the carry before 2026-12-02).

    python benchmarks/cleaning_native.py                 # held-out takes, both categories
    python benchmarks/cleaning_native.py --tune --category dance
    python benchmarks/cleaning_native.py --quick         # 4 takes per category
    python benchmarks/cleaning_native.py --context other # walks against salsa, salsa against walks
    python benchmarks/cleaning_native.py --set noise_fix=lowpass

Targets (issue 14): a take with nothing injected has <= 1 % of its cells edited and no edit
larger than 30 degrees.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from cleaning_protocol import DATA, SUBJECTS, TUNE, parse_sets


def _category_clips(category: str) -> list:
    from mocapflow.plugins.formats.asf_amc import read_amc

    files = sorted(f for s in SUBJECTS[category] for f in (DATA / s).glob("*.amc"))
    return sorted((read_amc(f) for f in files), key=lambda m: -m.n_frames)  # longest first, as the protocol


def _native_cases(category: str, tune: bool, n_test: int, small: int, context: str = "protocol"):
    """(take, context) pairs at the native rate, chosen as the protocol chooses them; with
    ``context="other"`` the context is the other category's ``small`` longest clips (a
    motion the context does not hold: walking cleaned against salsa and the reverse)."""
    from mocapflow.plugins.selfsim.clean_eval import CleaningEvaluationParams, clip_key

    p = CleaningEvaluationParams(**({"held_out": TUNE} if tune else {}))
    held, by = p.held_out.get(category, ()), p.group_by.get(category, "subject")
    clips = _category_clips(category)
    foreign = [] if context == "protocol" else _category_clips(next(c for c in SUBJECTS if c != category))[:small]
    tests = [i for i, c in enumerate(clips)
             if c.n_frames * 24.0 / c.fps >= p.min_frames and clip_key(c.name, by) in held][:n_test]
    for i in tests:
        trial = clip_key(clips[i].name, "trial")
        others = [c for k, c in enumerate(clips) if k != i
                  and not (category == "dance" and clip_key(c.name, "trial") == trial)]
        yield clips[i], (others[:small] if context == "protocol" else foreign)


def _edit_figures(motion, cleaned, joints) -> tuple[float, float, int]:
    """Share of (frame, texture joint) cells edited, largest edit (degrees), cells edited."""
    from mocapflow.framework import quaternions as quat

    idx = [motion.skeleton.canonical[j] for j in joints if j in motion.skeleton.canonical]
    ang = np.degrees(quat.geodesic_angle(motion.rotations[:, idx], cleaned.rotations[:, idx]))
    moved = ang > 1e-4
    return float(moved.mean()), float(ang.max(initial=0.0)), int(moved.sum())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", choices=tuple(SUBJECTS), action="append")
    ap.add_argument("--tune", action="store_true", help="the tuning subjects / trials instead of the held-out ones")
    ap.add_argument("--quick", action="store_true", help="4 takes per category")
    ap.add_argument("--n-test", type=int, default=40, help="at most this many takes per category (longest first)")
    ap.add_argument("--context", choices=("protocol", "other"), default="protocol", help="the protocol's small "
                    "context, or the other category's 8 longest clips (a motion the context does not hold)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="cleaner parameter (JSON value)")
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"needs the corpus at {DATA}", file=sys.stderr)
        return 2
    from mocapflow.plugins.selfsim import repair
    from mocapflow.plugins.selfsim.mdm import MDMCleaner, MDMParams

    cleaner = MDMCleaner(MDMParams(**{"write_bvh": False, "heatmaps": False, **parse_sets(args.set)}))
    guarded = repair.apply_to_input

    def unguarded(*a, **kw):
        return guarded(*a, **{**kw, "guard": False})

    n_test = 4 if args.quick else args.n_test
    for cat in args.category or tuple(SUBJECTS):
        rows = []
        t0 = time.perf_counter()
        for take, context in _native_cases(cat, args.tune, n_test, 8, args.context):
            res = cleaner.analyse(take, context)  # one analysis, two carries of the same decision
            figs = {}
            for name, carry in (("default", guarded), ("no guard", unguarded)):
                repair.apply_to_input = carry
                try:
                    out = _clean_with(cleaner, take, context, res)
                finally:
                    repair.apply_to_input = guarded
                figs[name] = _edit_figures(take, out.cleaned, cleaner.params.joints)
            rows.append((take.name, take.fps, take.n_frames, figs))
            d, u = figs["default"], figs["no guard"]
            print(f"  {take.name:>8} {take.fps:5.0f} fps {take.n_frames:6d} frames: edited {100 * d[0]:5.2f} % "
                  f"(no guard {100 * u[0]:5.2f} %), largest {d[1]:6.1f} deg (no guard {u[1]:6.1f})",
                  file=sys.stderr, flush=True)
        if not rows:
            continue
        print(f"\n{cat}: {len(rows)} clean takes at their own rate ({'tuning' if args.tune else 'held-out'}), "
              f"{'small' if args.context == 'protocol' else 'foreign'} context {args.set or ''}, "
              f"{time.perf_counter() - t0:.0f} s")
        print("| carry | edited share mean / worst | takes > 1 % | largest edit, degrees | takes > 30 deg |")
        print("|---|---|---|---|---|")
        for name in ("default", "no guard"):
            share = np.array([r[3][name][0] for r in rows])
            big = np.array([r[3][name][1] for r in rows])
            print(f"| {name} | {100 * share.mean():.2f} % / {100 * share.max():.2f} % | {int((share > 0.01).sum())} "
                  f"| {big.max():.1f} | {int((big > 30).sum())} |")
        worst = sorted(rows, key=lambda r: -r[3]["default"][1])[:3]
        print("largest edits (default): " + ", ".join(f"{r[0]} {r[3]['default'][1]:.1f}" for r in worst))
    return 0


def _clean_with(cleaner, take, context, analysis):
    """:func:`decision.clean_motion` on a given analysis (calibration refitted: it is cheap)."""
    from mocapflow.plugins.selfsim.decision import clean_motion

    return clean_motion(cleaner, take, context, analysis=analysis)


if __name__ == "__main__":
    raise SystemExit(main())
