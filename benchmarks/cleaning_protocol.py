"""The cleaning protocol of issue 14 on ../shared/data: detection, repair and clean takes.

Runs :func:`mocapflow.plugins.selfsim.clean_eval.evaluate_category` (errors at the
paper's density on held-out subjects / trials, module doc there) and prints, per category
and context, recall / precision per word, per (word, joint) and per cell for the
calibrated cleaner (``mdm``), the paper (``mdm[paper]``) and the baselines; eq. 2 before
and after (global and on the erroneous cells) with the share of clips whose global error
fell; the clean-take edit share and largest edit; and the per-kind figures.

    python benchmarks/cleaning_protocol.py                       # held-out clips, local + small
    python benchmarks/cleaning_protocol.py --tune                # the tuning subjects / trials instead
    python benchmarks/cleaning_protocol.py --quick               # 6 test clips per category, small context
    python benchmarks/cleaning_protocol.py --category dance --set false_alarm=0.001
    python benchmarks/cleaning_protocol.py --cache /tmp/mdm-cache  # reuse analyses (design iteration)

``--cache DIR`` stores every KNN analysis (test clips, clean takes and the calibration
clips with their synthetic errors) on disk, keyed by the clip's rotations, its context and
the analysis parameters, so a second run that changes only the decision or the repair
takes a fraction of the time and scores exactly the same analyses. Timings (``s/clip``)
are meaningless with a warm cache.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu" / "amc"
SUBJECTS = {"locomotion": ("02", "07", "16", "35", "49"), "dance": ("60", "61")}
TUNE = {"locomotion": ("02", "49"), "dance": ("01", "02", "04", "05")}


def parse_sets(items: list[str]) -> dict:
    """``--set KEY=VALUE`` options as cleaner parameters (a JSON value, else the string)."""
    out = {}
    for kv in items:
        k, _, v = kv.partition("=")
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def _f1(r: float, p: float) -> float:
    return 2 * r * p / (r + p) if r + p > 0 else 0.0


def pooled(results: list[tuple[list[dict], list[dict], list[dict]]]) -> tuple[list[dict], list[dict], list[dict]]:
    """Rows of several seeds of :func:`evaluate_category` pooled: counts summed, ratios
    recomputed; repair rows averaged over seeds (shares and means weighted by clips, maxima
    as maxima); kind rows summed."""
    if len(results) == 1:
        return results[0]
    from mocapflow.plugins.selfsim.clean_eval import _ratios

    rows = []
    for group in zip(*(r[0] for r in results)):
        row = dict(group[0])
        for k in ("tp", "fp", "fn", "word_tp", "word_fp", "word_fn", "wj_tp", "wj_fp", "wj_fn", "n_clips",
                  "fp_sub", "wj_fp_sub", "word_fp_sub"):
            if k in row:
                row[k] = sum(g[k] for g in group)
        row.update(_ratios(row))
        row["seconds_per_clip"] = float(np.mean([g["seconds_per_clip"] for g in group]))
        rows.append(row)
    rep = []
    for group in zip(*(r[1] for r in results)):
        row = dict(group[0])
        w = np.array([g["n_clips"] for g in group], float)
        for k in ("global_before", "global_after", "share_global_lower", "cells_before", "cells_after",
                  "clean_edited_share", "global_before_ng", "global_after_ng", "share_global_lower_ng",
                  "share_global_not_higher", "share_global_unchanged", "share_global_not_higher_ng",
                  "clean_edited_share_ng"):
            row[k] = float(np.average([g[k] for g in group], weights=w))
        for k in ("clean_edited_share_max", "clean_max_edit_deg", "clean_max_edit_deg_ng", "clean_edited_share_max_ng"):
            row[k] = max(g[k] for g in group)
        for k in ("glitch_cells", "clean_glitch_edits"):
            row[k] = sum(g[k] for g in group)
        row["n_clips"] = int(w.sum())
        rep.append(row)
    kinds: dict[tuple, dict] = {}
    for r in results:
        for k in r[2]:
            key = (k["method"], k["context"], k["kind"])
            if key not in kinds:
                kinds[key] = dict(k)
            else:
                cur = kinds[key]
                for f in ("errors", "found", "cells", "cells_flagged", "eq2_before", "eq2_after"):
                    cur[f] += k[f]
    return rows, rep, list(kinds.values())


def install_cache(folder: Path) -> None:
    """Memoise :func:`mocapflow.plugins.selfsim.mdm.digression_map` on disk (module doc)."""
    import hashlib
    import pickle

    from mocapflow.plugins.selfsim import mdm

    folder.mkdir(parents=True, exist_ok=True)
    original = mdm.digression_map
    decision_only = {"mode", "false_alarm", "null_quantile", "calibration_frames", "calibration_density",
                     "calibration_seed", "cues", "max_edit", "swap_gain", "swap_level", "swap_max", "mirror_swaps", "offset_level", "flag_rule", "interp_max", "merge_gap", "agree", "acc_persist", "acc_persist_fit", "acc_body", "freeze_still", "flag_min_deg", "flag_min_scope", "flag_min_revert", "freeze_moving", "shrink_full", "shrink_cues", "accept_margin", "accept_offsets", "unclaimed_revert", "unclaimed_frames", "freeze_hold", "freeze_fill", "freeze_guard", "spike_level", "spike_exact", "spike_keep", "spike_least_deg", "noise_fix", "noise_null", "noise_cues", "noise_half", "noise_factor", "cue_fa", "words_half", "words_slack", "words_erode", "words_reach", "floor_only", "merge_jolts", "merge_mirror", "gap_cap", "jitter", "jitter_half", "write_bvh", "heatmaps", "threshold",
                     "savgol_window", "savgol_order", "include_self"}

    def cached(motion, context=None, params=None):
        p = params or mdm.MDMParams()
        h = hashlib.sha1()
        for c in mdm.context_motions(motion, context, p.include_self):
            h.update(c.name.encode())
            h.update(np.ascontiguousarray(c.rotations).tobytes())
        h.update(json.dumps({k: v for k, v in p.model_dump(mode="json").items() if k not in decision_only},
                            sort_keys=True).encode())
        path = folder / f"{h.hexdigest()}.pkl"
        if path.exists():
            try:
                return pickle.loads(path.read_bytes())
            except Exception:
                pass
        res = original(motion, context, p)
        tmp = path.with_suffix(".tmp")
        tmp.write_bytes(pickle.dumps(res, protocol=pickle.HIGHEST_PROTOCOL))
        tmp.replace(path)
        return res

    mdm.digression_map = cached
    mdm.MDMCleaner.analyse = lambda self, motion, context=None: cached(motion, context, self.params)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", choices=tuple(SUBJECTS), action="append")
    ap.add_argument("--quick", action="store_true", help="6 test clips per category, small context only")
    ap.add_argument("--tune", action="store_true", help="evaluate on the tuning subjects / trials")
    ap.add_argument("--contexts", default=None, help="comma-separated contexts (default local,small)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="cleaner parameter (JSON value)")
    ap.add_argument("--json", help="also write every row to this JSON file")
    ap.add_argument("--seed", type=int, action="append", help="injection seed (repeatable: the clips are scored "
                    "once per seed, pooled; default 0)")
    ap.add_argument("--glitch-returns", action="store_true", help="count jump-and-return excursions of the clean "
                    "references as source glitches too (the '_ng' figures; the strict ones do not change)")
    ap.add_argument("--cache", type=Path, help="memoise the KNN analyses in this folder (module doc)")
    args = ap.parse_args(argv)
    if args.cache:
        install_cache(args.cache)
    if not DATA.is_dir():
        print(f"needs the corpus at {DATA}", file=sys.stderr)
        return 2
    from mocapflow.plugins.selfsim.clean_eval import CleaningEvaluationParams, evaluate_category
    from mocapflow.plugins.formats.asf_amc import read_amc

    cleaner = parse_sets(args.set)
    contexts = tuple(args.contexts.split(",")) if args.contexts else (("small",) if args.quick else ("local", "small"))
    kw = {"contexts": contexts, "cleaner": cleaner, "glitch_returns": args.glitch_returns}
    if args.quick:
        kw["n_test"] = 6
    if args.tune:
        kw["held_out"] = TUNE
    seeds = args.seed or [0]
    out = {}
    for cat in args.category or tuple(SUBJECTS):
        files = sorted(f for s in SUBJECTS[cat] for f in (DATA / s).glob("*.amc"))
        t0 = time.perf_counter()
        motions = [read_amc(f) for f in files]
        rows, rep, kinds = pooled([evaluate_category(cat, motions, CleaningEvaluationParams(**kw, seed=sd),
                                                     log=lambda m: print("  " + m, file=sys.stderr, flush=True))
                                   for sd in seeds])
        out[cat] = {"rows": rows, "repair": rep, "kinds": kinds}
        n = rows[0]["n_clips"] if rows else 0
        dens = [r for r in rows if r["method"] == "baseline_a_limits"]
        print(f"\n{cat}: {n} test clips ({'tuning' if args.tune else 'held-out'} set), {time.perf_counter() - t0:.0f} s")
        if dens:
            d = dens[0]
            print(f"  erroneous words {d['word_tp'] + d['word_fn']}, erroneous (word, joint) {d['wj_tp'] + d['wj_fn']}, "
                  f"erroneous cells {d['tp'] + d['fn']}")
        print(f"  {'method':22s} {'context':6s} {'word R/P':>12s} {'(w,j) R/P':>12s} {'cell R/P':>12s} "
              f"{'F1 w/wj/cell':>16s} {'s/clip':>6s}")
        for r in rows:
            f = [_f1(r[a], r[b]) for a, b in (("word_recall", "word_precision"), ("wj_recall", "wj_precision"),
                                              ("recall", "precision"))]
            print(f"  {r['method']:22s} {r['context']:6s} {r['word_recall']:5.3f}/{r['word_precision']:5.3f} "
                  f"{r['wj_recall']:5.3f}/{r['wj_precision']:5.3f} {r['recall']:5.3f}/{r['precision']:5.3f} "
                  f"{f[0]:5.3f}/{f[1]:5.3f}/{f[2]:5.3f} {r['seconds_per_clip']:6.2f}")
        for r in rows:
            if "wj_precision_dc" in r and r["method"].startswith("mdm"):
                print(f"  {r['method']:22s} {r['context']:6s} precision with cells moved < min_angle as don't care: "
                      f"word {r['word_precision_dc']:5.3f}, (w,j) {r['wj_precision_dc']:5.3f}, "
                      f"cell {r['precision_dc']:5.3f}")
        print(f"  {'method':12s} {'context':6s} {'global before->after':>22s} {'clips lower':>11s} "
              f"{'err cells before->after':>24s} {'clean edited (mean/max)':>24s} {'clean max edit':>14s}")
        for r in rep:
            print(f"  {r['method']:12s} {r['context']:6s} {r['global_before']:9.4f} -> {r['global_after']:8.4f} "
                  f"{r['share_global_lower']:11.2f} {r['cells_before']:10.4f} -> {r['cells_after']:9.4f} "
                  f"{r['clean_edited_share']:11.4f}/{r['clean_edited_share_max']:.4f} {r['clean_max_edit_deg']:12.1f} deg")
        for r in rep:
            if "share_global_not_higher" in r:
                print(f"  {r['method']:12s} {r['context']:6s} clips whose global error fell {r['share_global_lower']:.2f}, "
                      f"did not rise {r['share_global_not_higher']:.2f} (left exactly as they were "
                      f"{r['share_global_unchanged']:.2f}); glitches out: fell {r['share_global_lower_ng']:.2f}, "
                      f"did not rise {r['share_global_not_higher_ng']:.2f}")
        for r in rep:
            if "share_global_lower_ng" in r:
                print(f"  {r['method']:12s} {r['context']:6s} source glitches left out ({r['glitch_cells']} cells of the "
                      f"clean references): global {r['global_before_ng']:.4f} -> {r['global_after_ng']:.4f}, lower on "
                      f"{r['share_global_lower_ng']:.2f}; clean takes: largest edit outside them "
                      f"{r['clean_max_edit_deg_ng']:.1f} deg, {r['clean_glitch_edits']} edits on them; edited outside "
                      f"them (mean/max) {r['clean_edited_share_ng']:.4f}/{r['clean_edited_share_max_ng']:.4f}")
        for r in kinds:
            if r["method"] == "mdm":
                ratio = r["eq2_after"] / r["eq2_before"] if r["eq2_before"] > 0 else float("nan")
                print(f"  kind {r['kind']:7s} {r['context']:6s} found {r['found']}/{r['errors']}, cells flagged "
                      f"{r['cells_flagged']}/{r['cells']}, eq.2 on its cells after/before {ratio:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
