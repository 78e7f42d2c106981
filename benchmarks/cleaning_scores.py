"""How separable are injected errors by per-cell MDM scores? (docs/cleaning.md, issue 6)

Runs the evaluation protocol of ``analyses.clean_eval`` (the 4 longest clips of a category,
every error kind once, seed = clip position, ground truth = cells moved > 10 degrees) with
the small-scale context, keeps the KNN of every source word, and sweeps *every* threshold
of several per-cell scores (each joint's row divided by its median, as the default
``normalization: median`` does). Printed per score: the best cell F1 (with its precision
and recall) and the best precision at recall 0.5 / 0.7 / 0.8 / 0.9; then, per error kind,
where the erroneous cells sit against the clean cells (in row medians).

    python benchmarks/cleaning_scores.py                 # locomotion and dance
    python benchmarks/cleaning_scores.py --category dance --context local
    python benchmarks/cleaning_scores.py --quick         # locomotion, 2 test clips, local context

A threshold-free view: when no threshold of a score reaches a precision, no choice of
``robust_factor`` or threshold will. Needs ../shared/data.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu" / "amc"
SUBJECTS = {"locomotion": ("02", "07", "16", "35", "49"), "dance": ("60", "61")}


def angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, -1)), 0.0, 1.0))


def analyses(category: str, context: str, n_test: int = 4) -> list[dict]:
    """The protocol of ``analyses.clean_eval`` for one category and context, per test clip."""
    from mocapflow.plugins.selfsim.clean_eval import (CleaningEvaluationParams, context_clips, corrupted_clips,
                                                       protocol_clips)
    from mocapflow.plugins.selfsim.mdm import MDMCleaner, MDMParams
    from mocapflow.plugins.formats.asf_amc import read_amc

    p = MDMParams(write_bvh=False, heatmaps=False)
    ev = CleaningEvaluationParams(n_test=n_test)
    files = sorted(f for s in SUBJECTS[category] for f in (DATA / s).glob("*.amc"))
    clips, joints = protocol_clips([read_amc(f) for f in files], p.joints, p.fps)
    cleaner = MDMCleaner(p)
    out = []
    for case in corrupted_clips(clips, ev, joints, p.fps):
        res = cleaner.analyse(case.bad, context_clips(context, case.others, ev))
        col = {int(j): c for c, j in enumerate(case.clean_texture.joint_index)}
        out.append({"bad": res.texture.q, "mean": res.mean_texture, "diff": res.difference, "spread": res.spread,
                    "joints": res.joints, "truth": case.truth, "neighbours": res.neighbours,
                    "errors": [(e.kind, [col[j] for j in e.joints if j in col], e.start, e.end) for e in case.errors]})
        print(f"  analysed {case.clean.name} ({res.seconds:.1f} s)", file=sys.stderr, flush=True)
    return out


def sample_scores(c: dict) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and mean angle from each cell to the KNN samples covering it."""
    q = c["bad"]
    lo = np.full(q.shape[:2], np.inf)
    tot = np.zeros(q.shape[:2])
    cnt = np.zeros(q.shape[:2])
    for nb in c["neighbours"]:
        n = nb.warped.shape[3]
        for g in range(nb.groups.n_groups):
            jm = nb.groups.mask[g]
            for si, s in enumerate(nb.starts):
                for k in np.flatnonzero(nb.target[g, si] >= 0):
                    a = angle(q[s:s + n], nb.warped[g, si, k])[:, jm]
                    lo[s:s + n, jm] = np.minimum(lo[s:s + n, jm], a)
                    tot[s:s + n, jm] += a
                    cnt[s:s + n, jm] += 1
    return np.where(np.isfinite(lo), lo, 0.0), np.where(cnt > 0, tot / np.maximum(cnt, 1), 0.0)


def tolerant(c: dict, tol: int) -> np.ndarray:
    """Smallest angle between T and T̄ shifted by up to ``tol`` frames."""
    q, mq = c["bad"], c["mean"]
    t = len(q)
    d = np.full(q.shape[:2], np.inf)
    for o in range(-tol, tol + 1):
        a, b = max(0, -o), min(t, t - o)
        d[a:b] = np.minimum(d[a:b], angle(q[a:b], mq[a + o:b + o]))
    return d


def swap_aware(c: dict, scale: float = 0.1) -> np.ndarray:
    """Row-median z of the default score plus a mislabelled-limb cue (not in the paper): how
    much closer a left/right joint is to the *mirrored* KNN mean of its counterpart than to
    its own KNN mean (radians, positive part), in units of ``scale``, times 3."""
    from mocapflow.plugins.selfsim.error_injection import mirror

    names = list(c["joints"])
    other = [names.index(("r" if n[0] == "l" else "l") + n[1:]) if n[0] in "lr" and
             (("r" if n[0] == "l" else "l") + n[1:]) in names else i for i, n in enumerate(names)]
    q, mq = c["bad"], c["mean"]
    own = angle(q, mq)
    cue = np.where(np.array(other) != np.arange(len(names)), own - angle(q, mirror(mq[:, other])), 0.0)
    return row_median(own) + 3.0 * np.clip(cue, 0.0, None) / scale


def sweep(z: np.ndarray, truth: np.ndarray) -> dict:
    """Best F1 (precision, recall) and best precision at fixed recalls over all thresholds."""
    order = np.argsort(-z, axis=None)
    hit = truth.ravel()[order]
    tp = np.cumsum(hit)
    fp = np.cumsum(~hit)
    rec = tp / max(truth.sum(), 1)
    prec = tp / np.maximum(tp + fp, 1)
    f1 = 2 * prec * rec / np.maximum(prec + rec, 1e-12)
    b = int(np.argmax(f1))
    out = {"F1": f1[b], "P": prec[b], "R": rec[b]}
    for r in (0.5, 0.7, 0.8, 0.9):
        ok = rec >= r
        out[f"P@R{r}"] = float(prec[ok].max()) if ok.any() else 0.0
    return out


def row_median(s: np.ndarray) -> np.ndarray:
    return s / np.maximum(np.median(s, axis=0, keepdims=True), 1e-3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--category", choices=tuple(SUBJECTS), action="append")
    ap.add_argument("--context", choices=("local", "small", "large"), default=None, help="default small (quick: local)")
    ap.add_argument("--quick", action="store_true", help="locomotion only, 2 test clips, the local context")
    args = ap.parse_args(argv)
    args.context = args.context or ("local" if args.quick else "small")
    if args.quick and not args.category:
        args.category = ["locomotion"]
    if not DATA.is_dir():
        print(f"needs the corpus at {DATA}", file=sys.stderr)
        return 2
    for cat in args.category or tuple(SUBJECTS):
        runs = analyses(cat, args.context, n_test=2 if args.quick else 4)
        truth = np.concatenate([c["truth"] for c in runs])
        samples = [sample_scores(c) for c in runs]
        scores = {
            "angle to chordal KNN mean (default)": [c["diff"] for c in runs],
            "same, best of +-1 frame of the mean": [tolerant(c, 1) for c in runs],
            "same, best of +-2 frames of the mean": [tolerant(c, 2) for c in runs],
            "smallest angle to a KNN sample": [s[0] for s in samples],
            "mean angle to the KNN samples": [s[1] for s in samples],
            "angle / KNN spread": [c["diff"] / np.sqrt(c["spread"] ** 2 + 0.035 ** 2) for c in runs],
        }
        swap = np.concatenate([swap_aware(c) for c in runs])
        print(f"\n{cat}, {args.context} context: {truth.size:,} cells, {int(truth.sum())} erroneous")
        print(f"  {'score':40s} {'best F1':>8s} {'(P':>6s} {'R)':>5s} " + " ".join(f"{'P@R' + str(r):>7s}" for r in (0.5, 0.7, 0.8, 0.9)))
        for name, s in scores.items():
            r = sweep(np.concatenate([row_median(x) for x in s]), truth)
            print(f"  {name:40s} {r['F1']:8.3f} {r['P']:6.3f} {r['R']:5.2f} "
                  + " ".join(f"{r[f'P@R{x}']:7.3f}" for x in (0.5, 0.7, 0.8, 0.9)))
        r = sweep(swap, truth)
        print(f"  {'default + mirrored-limb cue (ours)':40s} {r['F1']:8.3f} {r['P']:6.3f} {r['R']:5.2f} "
              + " ".join(f"{r[f'P@R{x}']:7.3f}" for x in (0.5, 0.7, 0.8, 0.9)))
        z = [row_median(c["diff"]) for c in runs]
        clean = np.concatenate([zz[~c["truth"]] for zz, c in zip(z, runs)])
        print("  clean cells, row medians at the 90/95/99th percentile:",
              " / ".join(f"{v:.1f}" for v in np.quantile(clean, [0.9, 0.95, 0.99])))
        kinds: dict[str, list[np.ndarray]] = {}
        for zz, c in zip(z, runs):
            for kind, cols, s, e in c["errors"]:
                if cols:
                    t = c["truth"][s:e][:, cols]
                    kinds.setdefault(kind, []).append(zz[s:e][:, cols][t])
        for kind, v in kinds.items():
            v = np.concatenate(v)
            if len(v):
                print(f"  {kind:7s} {len(v):4d} erroneous cells, median {np.median(v):5.1f} row medians")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
