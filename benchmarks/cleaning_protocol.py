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


def _f1(r: float, p: float) -> float:
    return 2 * r * p / (r + p) if r + p > 0 else 0.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", choices=tuple(SUBJECTS), action="append")
    ap.add_argument("--quick", action="store_true", help="6 test clips per category, small context only")
    ap.add_argument("--tune", action="store_true", help="evaluate on the tuning subjects / trials")
    ap.add_argument("--contexts", default=None, help="comma-separated contexts (default local,small)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="cleaner parameter (JSON value)")
    ap.add_argument("--json", help="also write every row to this JSON file")
    args = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"needs the corpus at {DATA}", file=sys.stderr)
        return 2
    from mocapflow.plugins.selfsim.clean_eval import CleaningEvaluationParams, evaluate_category
    from mocapflow.plugins.formats.asf_amc import read_amc

    cleaner = {}
    for kv in args.set:
        k, _, v = kv.partition("=")
        try:
            cleaner[k] = json.loads(v)
        except json.JSONDecodeError:
            cleaner[k] = v
    contexts = tuple(args.contexts.split(",")) if args.contexts else (("small",) if args.quick else ("local", "small"))
    kw = {"contexts": contexts, "cleaner": cleaner}
    if args.quick:
        kw["n_test"] = 6
    if args.tune:
        kw["held_out"] = TUNE
    p = CleaningEvaluationParams(**kw)
    out = {}
    for cat in args.category or tuple(SUBJECTS):
        files = sorted(f for s in SUBJECTS[cat] for f in (DATA / s).glob("*.amc"))
        t0 = time.perf_counter()
        rows, rep, kinds = evaluate_category(cat, [read_amc(f) for f in files], p,
                                             log=lambda m: print("  " + m, file=sys.stderr, flush=True))
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
        print(f"  {'method':12s} {'context':6s} {'global before->after':>22s} {'clips lower':>11s} "
              f"{'err cells before->after':>24s} {'clean edited (mean/max)':>24s} {'clean max edit':>14s}")
        for r in rep:
            print(f"  {r['method']:12s} {r['context']:6s} {r['global_before']:9.4f} -> {r['global_after']:8.4f} "
                  f"{r['share_global_lower']:11.2f} {r['cells_before']:10.4f} -> {r['cells_after']:9.4f} "
                  f"{r['clean_edited_share']:11.4f}/{r['clean_edited_share_max']:.4f} {r['clean_max_edit_deg']:12.1f} deg")
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
