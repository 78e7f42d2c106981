"""Benchmark of the MDM cleaner (``cleaners.mdm``, ``analyses.clean_eval``; docs/cleaning.md).

Four measurements, on the CMU corpus of ../shared/data (``MOCAPFLOW_DATA`` overrides it):

    python benchmarks/cleaning.py speed      # analysis with the pruned KNN against the brute force
                                             # (tests/naive/cleaning.py), whole clean paper vs calibrated
    python benchmarks/cleaning.py protocol   # errors at the paper's density on held-out clips: detection,
                                             # repair, clean takes, per kind; F1 against the best baseline
    python benchmarks/cleaning.py native     # the protocol's clean takes cleaned at their own rate (120 fps)
    python benchmarks/cleaning.py scores     # how separable are the errors by per-cell scores?
    python benchmarks/cleaning.py loso       # leave-one-subject-out over every walk / run / dance take at
                                             # its own rate, >= 10 seeds, bootstrap CI; --sweep: per kind,
                                             # magnitude x duration (evaluation/generalization.py)
    python benchmarks/cleaning.py --quick    # all four, tiny, on the bundled examples/data (seconds)

``protocol`` and ``native`` take ``--tune`` (the tuning subjects / trials), ``--category``,
``--set KEY=VALUE`` (a cleaner parameter, JSON value; ``calibrated.false_alarm=0.002`` for a
nested one); ``protocol`` also ``--contexts``, ``--seed`` (repeatable: seeds pooled),
``--cache DIR`` (KNN analyses memoised on disk: a change of the decision only is scored on
the same analyses in seconds) and ``--json FILE``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from _cleaning_loso import CMU, EXAMPLES, _read, _sets, loso, stability

REPO = Path(__file__).resolve().parent.parent
SUBJECTS = {"locomotion": ("02", "07", "16", "35", "49"), "dance": ("60", "61")}
TUNE = {"locomotion": ("02", "49"), "dance": ("01", "02", "04", "05")}


# ``loso``: every walk / run / dance take of the corpus by subject (MANIFEST.md's descriptions)
def _category(cat: str, quick: bool) -> list:
    if quick:  # the bundled takes play both categories
        return _read(sorted(EXAMPLES.glob("*/*.amc")))
    return _read(sorted(f for s in SUBJECTS[cat] for f in (CMU / s).glob("*.amc")))


def _f1s(row: dict) -> list[float]:
    """F1 of a protocol row: word, (word, joint), cell."""
    pairs = [(row[f"{k}recall"], row[f"{k}precision"]) for k in ("word_", "wj_", "")]
    return [2 * r * p / (r + p) if r + p > 0 else 0.0 for r, p in pairs]


def speed(args) -> None:
    """The analysis of one take against itself, pruned vs brute-force KNN; a whole clean."""
    sys.path.insert(0, str(REPO / "tests"))
    from naive.cleaning import brute_knn

    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner
    from mocapflow.plugins.selfsim.paper.knn import ContextTextures, knn_search

    path = EXAMPLES / "16" / "16_15.amc" if args.quick else CMU / "14" / "14_02.amc"
    take = resample(_read([path])[0], 24.0)
    take = take.slice(0, min(take.n_frames, 240 if args.quick else 480)).with_arrays(name=path.stem)
    MDMCleaner().analyse(take.slice(0, 40))  # compile the kernels (numba caches them on disk)
    t0, c0 = time.perf_counter(), time.process_time()
    res = MDMCleaner().analyse(take)
    t_map, c_map = time.perf_counter() - t0, time.process_time() - c0
    nb = res.neighbours[0]
    ctx = ContextTextures.from_arrays([res.texture.q])
    kw = {"self_clip": 0, "word_starts": nb.starts}
    brute_knn(
        res.texture.q[:40], ContextTextures.from_arrays([res.texture.q[:40]]), nb.groups, nb.starts[:1], self_clip=0
    )
    t0 = time.perf_counter()
    fast = knn_search(res.texture.q, ctx, nb.groups, **kw)
    t_fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    target, distance, n_brute = brute_knn(res.texture.q, ctx, nb.groups, **kw)
    t_brute = time.perf_counter() - t0
    same = np.array_equal(target, fast.target) and np.array_equal(distance, fast.distance)
    print(f"speed: {take.name} ({take.n_frames} frames at 24 fps) against itself")
    print(
        f"  whole analysis {t_map:.2f} s ({c_map:.2f} s CPU); KNN pruned {t_fast:.2f} s ({fast.n_dtw} DTWs), brute "
        f"force {t_brute:.2f} s ({n_brute} DTWs): x{t_brute / max(t_fast, 1e-9):.1f}, identical neighbours: {same}"
    )
    cpu = {}
    for mode in ("paper", "calibrated"):
        c0 = time.process_time()
        MDMCleaner(mode=mode, write_bvh=False, heatmaps=False).clean(take)
        cpu[mode] = time.process_time() - c0
    print(
        f"  whole clean, CPU: paper {cpu['paper']:.2f} s, calibrated {cpu['calibrated']:.2f} s "
        f"(x{cpu['calibrated'] / cpu['paper']:.2f}: the calibration analyses the context once more)"
    )
    if args.quick:
        return
    # the take against about 600 s of other CMU takes (the paper: ~3 h)
    from mocapflow.plugins.selfsim.paper.motion_words import motion_texture

    context, total = [], 0.0
    for f in sorted(CMU.glob("*/*.amc")):
        if f.stem != path.stem and total < 600.0:
            context.append(resample(_read([f])[0], 24.0))
            total += context[-1].duration
    joints = tuple(j for j in res.joints if all(j in c.skeleton.canonical for c in context))
    ctx_q = [motion_texture(take, joints).q] + [motion_texture(c, joints).q for c in context]
    t0 = time.perf_counter()
    big = knn_search(ctx_q[0], ContextTextures.from_arrays(ctx_q), nb.groups, **kw)
    every = nb.groups.n_groups * len(nb.starts) * sum(max(0, len(q) - 14) for q in ctx_q)
    print(
        f"  against {len(context)} takes ({total:.0f} s): KNN pruned {time.perf_counter() - t0:.2f} s, "
        f"{big.n_dtw} of {every} DTWs ({1 - big.n_dtw / every:.1%} avoided)"
    )


def install_cache(folder: Path) -> None:
    """Memoise the KNN analyses on disk, keyed by the clips and the analysis parameters."""
    import hashlib
    import pickle

    from mocapflow.plugins.selfsim import cleaner
    from mocapflow.plugins.selfsim.paper import mdm

    folder.mkdir(parents=True, exist_ok=True)
    original = mdm.digression_map
    decision = {"mode", "calibrated", "threshold", "savgol_window", "savgol_order", "write_bvh", "heatmaps"}

    def cached(motion, context=None, params=None):
        p = params or cleaner.MDMParams()
        h = hashlib.sha1()
        for c in mdm.context_motions(motion, context, p.include_self):
            h.update(c.name.encode())
            h.update(np.ascontiguousarray(c.rotations).tobytes())
        h.update(
            json.dumps(
                {k: v for k, v in p.model_dump(mode="json").items() if k not in decision}, sort_keys=True
            ).encode()
        )
        path = folder / f"{h.hexdigest()}.pkl"
        if path.exists():
            return pickle.loads(path.read_bytes())
        res = original(motion, context, p)
        path.with_suffix(".tmp").write_bytes(pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
        path.with_suffix(".tmp").replace(path)
        return res

    cleaner.MDMCleaner.analyse = lambda self, motion, context=None: cached(motion, context, self.params)


def pooled(results: list) -> tuple[list, list, list]:
    """Rows of several seeds pooled: counts summed and ratios recomputed, repair rows averaged
    (weighted by clips; maxima as maxima), kind rows summed."""
    if len(results) == 1:
        return results[0]
    from mocapflow.plugins.selfsim.evaluation.scores import _ratios

    rows = []
    for group in zip(*(r[0] for r in results), strict=True):
        row = dict(group[0])
        for k in [k for k in row if isinstance(row[k], int) and k != "n_clips"] + ["n_clips"]:
            row[k] = sum(g[k] for g in group)
        rows.append({**row, **_ratios(row)})
    rep = []
    for group in zip(*(r[1] for r in results), strict=True):
        w = np.array([g["n_clips"] for g in group], float)
        row = {
            k: (
                max(g[k] for g in group)
                if "max" in k
                else sum(g[k] for g in group)
                if isinstance(v, int)
                else float(np.average([g[k] for g in group], weights=w))
                if isinstance(v, float)
                else v
            )
            for k, v in group[0].items()
        }
        rep.append(row)
    kinds: dict[tuple, dict] = {}
    for r in results:
        for k in r[2]:
            cur = kinds.setdefault(
                (k["method"], k["context"], k["kind"]),
                {**k, **dict.fromkeys(("errors", "found", "cells", "cells_flagged", "eq2_before", "eq2_after"), 0)},
            )
            for f in ("errors", "found", "cells", "cells_flagged", "eq2_before", "eq2_after"):
                cur[f] += k[f]
    return rows, rep, list(kinds.values())


def protocol(args) -> None:
    """The protocol of ``analyses.clean_eval`` (module doc there), printed."""
    from mocapflow.plugins.selfsim.evaluation.clean_eval import CleaningEvaluationParams, evaluate_category

    if args.cache:
        install_cache(args.cache)
    kw: dict = {
        "contexts": tuple(args.contexts.split(",")) if args.contexts else ("local", "small"),
        "cleaner": _sets(args.set),
    }
    if args.tune:
        kw["held_out"] = TUNE
    if args.quick:
        kw.update(held_out={}, n_test=1, small_size=2, contexts=("small",))
    out = {}
    for cat in ["locomotion"] if args.quick else args.category or list(SUBJECTS):
        t0 = time.perf_counter()
        clips = _category(cat, args.quick)
        rows, rep, kinds = pooled(
            [
                evaluate_category(
                    cat,
                    clips,
                    CleaningEvaluationParams(**kw, seed=sd),
                    log=lambda m: print("  " + m, file=sys.stderr, flush=True),
                )
                for sd in args.seed or [0]
            ]
        )
        out[cat] = {"rows": rows, "repair": rep, "kinds": kinds}
        print(
            f"\nprotocol, {cat}: {rows[0]['n_clips'] if rows else 0} test clips "
            f"({'tuning' if args.tune else 'held-out'}), {time.perf_counter() - t0:.0f} s"
        )
        base = [_f1s(r) for r in rows if r["method"].startswith("baseline")] or [[0.0] * 3]
        best = [max(col) for col in zip(*base, strict=True)]
        print(
            f"  {'method':22s} {'context':7s} {'word R/P':>11s} {'(w,j) R/P':>11s} {'cell R/P':>11s} "
            f"{'F1 / best baseline: word, (w,j), cell':>38s}"
        )
        for r in rows:
            ratio = ", ".join(f"{x / y:.2f}x" if y > 0 else "-" for x, y in zip(_f1s(r), best, strict=True))
            print(
                f"  {r['method']:22s} {r['context']:7s} {r['word_recall']:5.3f}/{r['word_precision']:5.3f} "
                f"{r['wj_recall']:5.3f}/{r['wj_precision']:5.3f} {r['recall']:5.3f}/{r['precision']:5.3f}   {ratio}"
            )
        for r in rep:
            print(
                f"  {r['method']:12s} {r['context']:6s} eq. 2 global {r['global_before']:.4f} -> {r['global_after']:.4f}, "
                f"fell on {r['share_global_lower']:.2f} (did not rise {r['share_global_not_higher']:.2f}; glitches "
                f"out {r['share_global_lower_ng']:.2f}), erroneous cells {r['cells_before']:.4f} -> "
                f"{r['cells_after']:.4f}; clean takes edited {100 * r['clean_edited_share']:.2f} % / worst "
                f"{100 * r['clean_edited_share_max']:.2f} %, largest {r['clean_max_edit_deg']:.1f} deg "
                f"({r['clean_max_edit_deg_ng']:.1f} outside the source glitches)"
            )
        for r in kinds:
            if r["method"] == "mdm":
                ratio = r["eq2_after"] / r["eq2_before"] if r["eq2_before"] > 0 else float("nan")
                print(
                    f"  kind {r['kind']:7s} {r['context']:6s} found {r['found']}/{r['errors']}, cells flagged "
                    f"{r['cells_flagged']}/{r['cells']}, eq. 2 on its cells x{ratio:.2f}"
                )
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))


def native(args) -> None:
    """The protocol's clean takes cleaned at their own frame rate, with and without the carry guard."""
    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner, clean_motion
    from mocapflow.plugins.selfsim.evaluation.clean_eval import GROUP_BY, MIN_FRAMES, CleaningEvaluationParams, clip_key
    from mocapflow.plugins.selfsim.paper import repair

    cleaner = MDMCleaner(**{"write_bvh": False, "heatmaps": False, **_sets(args.set)})
    guarded = repair.apply_to_input
    for cat in ["locomotion"] if args.quick else args.category or list(SUBJECTS):
        clips = sorted(_category(cat, args.quick), key=lambda m: -m.n_frames)
        held = TUNE[cat] if args.tune else CleaningEvaluationParams().held_out[cat]
        tests = [
            i
            for i, c in enumerate(clips)
            if c.n_frames * 24.0 / c.fps >= MIN_FRAMES and (args.quick or clip_key(c.name, GROUP_BY[cat]) in held)
        ][: 1 if args.quick else None]
        figs: dict[str, list] = {"default": [], "no guard": []}
        for i in tests:
            trial = clip_key(clips[i].name, "trial")
            ctx = [
                c for k, c in enumerate(clips) if k != i and not (cat == "dance" and clip_key(c.name, "trial") == trial)
            ][: 2 if args.quick else 8]
            res = cleaner.analyse(clips[i], ctx)  # one analysis, two carries of the same decision
            idx = [clips[i].skeleton.canonical[j] for j in res.joints]
            for name, guard in (("default", True), ("no guard", False)):
                repair.apply_to_input = lambda *a, g=guard, **kw: guarded(*a, **{**kw, "guard": g})
                try:
                    out = clean_motion(cleaner, clips[i], ctx, analysis=res)
                finally:
                    repair.apply_to_input = guarded
                ang = np.degrees(quat.geodesic_angle(clips[i].rotations[:, idx], out.cleaned.rotations[:, idx]))
                figs[name].append(((ang > 1e-4).mean(), ang.max(initial=0.0)))
        print(f"\nnative, {cat}: {len(tests)} clean takes at their own rate ({'tuning' if args.tune else 'held-out'})")
        for name, v in figs.items():
            if v:
                share, big = np.array(v).T
                print(
                    f"  {name:9s} edited {100 * share.mean():.2f} % / worst {100 * share.max():.2f} %, largest edit "
                    f"{big.max():.1f} deg, takes > 30 deg: {int((big > 30).sum())}"
                )


def _sweep(z: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Best F1 over all thresholds of ``z``, and the best precision at recall 0.8."""
    order = np.argsort(-z, axis=None)
    hit = truth.ravel()[order]
    tp, fp = np.cumsum(hit), np.cumsum(~hit)
    rec, prec = tp / max(truth.sum(), 1), tp / np.maximum(tp + fp, 1)
    f1 = 2 * prec * rec / np.maximum(prec + rec, 1e-12)
    return float(f1.max()), float(prec[rec >= 0.8].max()) if (rec >= 0.8).any() else 0.0


def scores(args) -> None:
    """Every threshold of per-cell scores (each joint's row over its median) on the protocol's
    corrupted clips, small context: no threshold of a score reaches a precision no choice of
    threshold will."""
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner
    from mocapflow.plugins.selfsim.evaluation.clean_eval import (
        CleaningEvaluationParams,
        context_clips,
        corrupted_clips,
        protocol_clips,
    )

    cleaner = MDMCleaner(write_bvh=False, heatmaps=False)
    p = cleaner.params
    ev = CleaningEvaluationParams(n_test=1 if args.quick else 4, **({"held_out": {}} if args.quick else {}))
    for cat in ["locomotion"] if args.quick else args.category or list(SUBJECTS):
        clips, joints = protocol_clips(_category(cat, args.quick), p.joints, p.fps)
        runs = []
        for case in corrupted_clips(clips, ev, joints, p.fps, cat):
            res = cleaner.analyse(case.bad, context_clips("small", case.others, ev))
            shape = res.difference.shape
            lo, tot, cnt = np.full(shape, np.inf), np.zeros(shape), np.zeros(shape)
            nb, n = res.neighbours[0], p.source_length
            for g, si, k in zip(*np.nonzero(nb.target >= 0), strict=True):
                s, jm = nb.starts[si], nb.groups.mask[g]
                dot = np.abs(np.sum(res.texture.q[s : s + n] * nb.warped[g, si, k], -1))
                a = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))[:, jm]
                lo[s : s + n, jm] = np.minimum(lo[s : s + n, jm], a)
                tot[s : s + n, jm] += a
                cnt[s : s + n, jm] += 1
            runs.append(
                {
                    "truth": case.truth,
                    "angle to T̄ (the MDM's)": res.difference,
                    "smallest angle to a KNN sample": np.where(np.isfinite(lo), lo, 0.0),
                    "mean angle to the KNN samples": tot / np.maximum(cnt, 1),
                    "angle to T̄ / KNN spread": res.difference / np.sqrt(res.spread**2 + 0.035**2),
                }
            )
        truth = np.concatenate([r["truth"] for r in runs])
        print(f"\nscores, {cat}, small context: {truth.size:,} cells, {int(truth.sum())} erroneous")
        for name in [k for k in runs[0] if k != "truth"]:
            z = np.concatenate([r[name] / np.maximum(np.median(r[name], 0, keepdims=True), 1e-3) for r in runs])
            f1, p80 = _sweep(z, truth)
            print(f"  {name:34s} best F1 {f1:.3f}, precision at recall 0.8 {p80:.3f}")


#: Development takes of the shipped null: subjects no protocol holds out or uses as context.
NULL_SUBJECTS = ("01", "10", "11", "14", "118", "135")


def null(args) -> None:
    """The null shipped with the package (``calibrated/null.json``): every take of
    :data:`NULL_SUBJECTS` (cropped to 20 s) analysed against two other takes of them (15 s),
    the detectors' evidence on its interior cells (:func:`.null.build_shipped`)."""
    from _cleaning_loso import _crop

    from mocapflow.plugins.selfsim.calibrated.detectors import evidence
    from mocapflow.plugins.selfsim.calibrated.null import SHIPPED, build_shipped
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner

    files = sorted(f for s in NULL_SUBJECTS for f in (CMU / s).glob("*.amc"))
    takes = _read(files)
    rng = np.random.default_rng(0)
    cleaner = MDMCleaner(write_bvh=False, heatmaps=False)
    evs, joints, names = [], [], []
    for i, take in enumerate(takes):
        t = _crop(take, 20.0, rng)
        others = [k for k in range(len(takes)) if k != i and files[k].parent != files[i].parent]
        ctx = [_crop(takes[k], 15.0, rng) for k in rng.choice(others, 2, replace=False)]
        res = cleaner.analyse(t, ctx)
        ev = evidence(res.texture.q, res.mean_texture, res.spread, res.joints)[3:-3]
        evs.append(ev)
        joints.append(res.joints)
        names.append(take.name)
        print(f"  null: {take.name} {len(ev)} frames", file=sys.stderr, flush=True)
    data = build_shipped(evs, joints, names)
    print(f"shipped null: {data['cells']} cells of {len(names)} takes; rate -> threshold:")
    for a, t in zip(data["alphas"], data["taus"], strict=True):
        print(f"  {a:8.0e}  {t:8.2f}")
    if args.write:
        SHIPPED.write_text(json.dumps(data, indent=1) + "\n")
        print(f"written {SHIPPED}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "part",
        nargs="?",
        choices=("speed", "protocol", "native", "scores", "loso", "stability", "null"),
        default=None,
    )
    ap.add_argument("--quick", action="store_true", help="every part, tiny, on the bundled examples/data")
    ap.add_argument("--category", choices=tuple(SUBJECTS), action="append")
    ap.add_argument("--tune", action="store_true", help="the tuning subjects / trials instead of the held-out ones")
    ap.add_argument("--contexts", help="protocol: comma-separated contexts (default local,small)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="cleaner parameter (JSON value)")
    ap.add_argument("--seed", type=int, action="append", help="protocol: injection seed (repeatable, pooled)")
    ap.add_argument("--cache", type=Path, help="protocol: memoise the KNN analyses in this folder")
    ap.add_argument("--json", help="protocol / loso: also write every row / run to this JSON file")
    ap.add_argument("--seeds", type=int, default=10, help="loso: seeds 0..N-1 (unless --seed)")
    ap.add_argument("--take-s", type=float, default=0.0, help="loso: held-out takes cropped to this, s (0: full)")
    ap.add_argument("--family", action="append", choices=("A", "B"), help="loso: injector families (default both)")
    ap.add_argument("--subjects", nargs="*", help="loso: only these held-out subjects (development subsets)")
    ap.add_argument("--context-n", type=int, default=3, help="loso: context takes from the other subjects")
    ap.add_argument("--density", type=float, default=0.125, help="loso: share of the words given an error")
    ap.add_argument("--sweep", action="store_true", help="loso: also the magnitude x duration table per kind")
    ap.add_argument("--load", action="append", help="loso: print the runs of these JSON files instead of running")
    ap.add_argument("--write", action="store_true", help="null: write calibrated/null.json")
    args = ap.parse_args(argv)
    if not args.quick and not CMU.is_dir():
        print(f"needs the corpus at {CMU} (or --quick)", file=sys.stderr)
        return 2
    parts = {
        "speed": speed,
        "protocol": protocol,
        "native": native,
        "scores": scores,
        "loso": loso,
        "stability": stability,
        "null": null,
    }
    quick_parts = [k for k in parts if k != "null"]  # the shipped null reads the corpus: never quick
    for name in [args.part] if args.part else (quick_parts if args.quick else ["speed"]):
        parts[name](args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
