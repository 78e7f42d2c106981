"""Motion templates (``matchers.template``, ``analyses.classify``) and mode ``auto`` of ``matchers.relational``.

1. Templates, leave-one-actor-out: templates learned from two actors' cuts, the list the
   matcher reports (``cutoff_hits`` with the step's defaults: coarse search, rival check)
   scored on the held-out actor's cuts (classes with R >= 0.9 at P >= 0.8); the ranking of
   one template's costs as the same-run baseline (best R at P >= 0.8); classification
   accuracy of the held-out cuts.
2. Mode auto with the matcher's defaults: every cut is a query against all cuts (relevant:
   the other cuts of its class); mAP of the ranking, P / R of the reported hits per class
   (classes with P >= 0.7, R >= 0.9).
3. Speed on a large tiled database: the default query (candidate regions from the inverted
   lists, coarse search, rival table) against the full-rate search (``step: 1``) measured
   in the same run, per template.

    python benchmarks/templates.py           # HDM05 cuts in ../shared/data (66 cuts), 1 M frames
    python benchmarks/templates.py --quick   # synthetic labelled cuts (3 classes x 3 actors x 2 takes), 20 k frames
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from mocapflow.plugins.relational.auto import auto_dtw_hits, auto_template
from mocapflow.plugins.relational.classify import classify_clips
from mocapflow.plugins.relational.inverted import InvertedIndex
from mocapflow.plugins.relational.template import cutoff_hits, fit_templates
from mocapflow.plugins.relational.template_coarse import CoarseCodes
from mocapflow.plugins.relational.template_cutoff import RivalTable
from mocapflow.plugins.relational.template_model import clip_min_costs, frame_codes


def meta(names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Class and actor of each HDM05-style cut name ``HDM_<actor>_<class>_<nnn>_<rate>``."""
    return np.array([n.split("_")[2] for n in names]), np.array([n.split("_")[1] for n in names])


def synthetic_cuts(seed: int = 0) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """3 classes x 3 actors x 2 takes: per class a random progression of feature runs, each
    take time-stretched by 0.8-1.25 with 2 % of its bits flipped."""
    rng = np.random.default_rng(seed)
    clips, names = [], []
    for c in range(3):
        pattern = np.repeat(rng.random((int(rng.integers(8, 14)), 31)) < 0.25, 5, axis=0)
        for actor in ("aa", "bb", "cc"):
            for take in range(2):
                n = int(len(pattern) * rng.uniform(0.8, 1.25))
                x = pattern[np.minimum((np.arange(n) * len(pattern) / n).astype(int), len(pattern) - 1)]
                clips.append(x ^ (rng.random(x.shape) < 0.02))
                names.append(f"HDM_{actor}_class{c}_{take:03d}_120")
    offsets = np.concatenate([[0], np.cumsum([len(x) for x in clips])]).astype(np.int64)
    return np.concatenate(clips), offsets, names


def hdm05_cuts(fps: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from relational import _measures, load_hdm05

    from mocapflow.plugins.relational.features import relational_features

    db = load_hdm05(fps)
    bits = relational_features(db.canonical_positions(), db.fps, _measures(db), None, db.offsets)
    return bits, np.asarray(db.offsets, np.int64), [m.name for m in db.motions]


def templates_loao(bits: np.ndarray, offsets: np.ndarray, names: list[str]) -> None:
    cls, act = meta(names)
    classes = sorted(set(cls))
    codes = frame_codes(bits)
    score = np.full((len(names), len(classes)), np.inf)
    hit = np.zeros((len(names), len(classes)), bool)
    pred = np.empty(len(names), object)
    for held in sorted(set(act)):
        train = act != held
        temps = fit_templates(bits, offsets, list(cls), train, list(act), classes)
        te = np.flatnonzero(~train)
        table = RivalTable.build(temps, codes, offsets)
        for j, (t, (s, _, _, _)) in enumerate(
            zip(temps, cutoff_hits(temps, codes, offsets, rival_table=table, step="auto"), strict=True)
        ):
            score[te, j] = clip_min_costs(codes, offsets, t.table())[te]
            found = np.zeros(len(names), bool)
            found[np.searchsorted(offsets, s, side="right") - 1] = True
            hit[te, j] = found[te]
        sub = np.concatenate([bits[offsets[i] : offsets[i + 1]] for i in te])
        sub_off = np.concatenate([[0], np.cumsum(np.diff(offsets)[te])])
        pred[te] = np.array(classes)[classify_clips(temps, sub, sub_off).argmin(axis=1)]
    print("\n== templates, leave-one-actor-out ==")
    print(f"{'class':30s} {'ranking: R at P>=0.8':>21s} {'reported: P':>12s} {'R':>5s} {'hits':>5s}")
    ok_rank = ok = 0
    for j, c in enumerate(classes):
        y = cls == c
        order = np.argsort(score[:, j], kind="stable")
        tp = np.cumsum(y[order])
        prec, rec = tp / np.arange(1, len(y) + 1), tp / y.sum()
        best_r = float(rec[prec >= 0.8].max()) if np.any(prec >= 0.8) else 0.0
        h = hit[:, j]
        p, r = (h & y).sum() / max(h.sum(), 1), (h & y).sum() / y.sum()
        ok_rank += best_r >= 0.9
        ok += p >= 0.8 and r >= 0.9
        print(f"{c:30s} {best_r:21.2f} {p:12.2f} {r:5.2f} {int(h.sum()):5d}")
    print(
        f"classes with R >= 0.9 at P >= 0.8: reported list {ok} of {len(classes)}, against the ranking "
        f"(same run) {ok_rank}; classification accuracy {np.mean(pred == cls):.3f}"
    )


def auto_queries(bits: np.ndarray, offsets: np.ndarray, names: list[str]) -> None:
    cls, _ = meta(names)
    n = len(names)
    codes, bg = frame_codes(bits), bits.mean(axis=0)
    aps, pr = [], {c: [] for c in sorted(set(cls))}
    for q in range(n):
        qb = bits[offsets[q] : offsets[q + 1]]
        t = auto_template(qb, bg)
        rel = (cls == cls[q]) & (np.arange(n) != q)
        cost = np.where(np.arange(n) == q, np.inf, clip_min_costs(codes, offsets, t.table()))
        order = np.argsort(cost, kind="stable")
        y = rel[order]
        tp = np.cumsum(y)
        aps.append(float((tp[y] / (np.flatnonzero(y) + 1)).sum() / max(rel.sum(), 1)))
        s, _, _ = auto_dtw_hits(t, qb, bits, codes, offsets, bg)
        found = set((np.searchsorted(offsets, s, side="right") - 1).tolist()) - {q}
        good = sum(bool(rel[c]) for c in found)
        pr[cls[q]].append((good / max(len(found), 1), good / max(rel.sum(), 1)))
    print(f"\n== mode auto, defaults: {n} queries, mAP {np.mean(aps):.3f} ==")
    ok = 0
    for c, v in pr.items():
        p, r = np.mean(v, axis=0)
        ok += p >= 0.7 and r >= 0.9
        print(f"  {c:30s} hits P {p:.2f} R {r:.2f}")
    print(f"classes with hits P >= 0.7, R >= 0.9: {ok} of {len(pr)}")


def tiled(bits: np.ndarray, offsets: np.ndarray, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    reps = max(1, n_frames // len(bits))
    big = np.concatenate([bits] * reps)
    off = np.concatenate([offsets[:-1] + k * len(bits) for k in range(reps)] + [[reps * len(bits)]]).astype(np.int64)
    return big, off


def speed(bits, offsets, names, n_frames: int, repeats: int) -> None:
    cls, act = meta(names)
    temps = fit_templates(bits, offsets, list(cls), np.ones(len(names), bool), list(act))
    big, off = tiled(bits, offsets, n_frames)
    codes = frame_codes(big)
    index = InvertedIndex().build(big, np.repeat(np.arange(len(off) - 1), np.diff(off)).astype(np.int32))
    table = RivalTable.build(temps, codes, off)
    coarse = CoarseCodes(codes, off)
    cutoff_hits(temps, codes, off, index, only=[0], rival_table=table, step="auto", coarse=coarse)  # compile

    def best(step, j):
        b = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = cutoff_hits(temps, codes, off, index, only=[j], rival_table=table, step=step, coarse=coarse)
            b = min(b, time.perf_counter() - t0)
        return b, len(out[0][0])

    print(
        f"\n== template queries over {len(big):,} frames ({len(off) - 1:,} clips), best of {repeats}; "
        f"load average {os.getloadavg()[0]:.1f} =="
    )
    ratios = []
    for j, t in enumerate(temps):
        t1, h1 = best(1, j)
        ta, ha = best("auto", j)
        ratios.append(t1 / ta)
        print(
            f"  {t.label:30s} K={t.n_frames:4d}: full rate {t1 * 1e3:7.1f} ms ({h1} hits) | default (step auto) "
            f"{ta * 1e3:7.1f} ms ({ha} hits): x{t1 / ta:.1f}"
        )
    print(f"median speed-up of the default over the full-rate search (same run): x{np.median(ratios):.1f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="synthetic labelled cuts, 20 k frames, no HDM05 needed")
    ap.add_argument("--frames", type=int, default=None, help="frames of the tiled database (default 1 M)")
    ap.add_argument("--fps", type=float, default=30.0)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    bits, offsets, names = synthetic_cuts() if args.quick else hdm05_cuts(args.fps)
    print(
        f"{len(names)} cuts, {len(bits)} frames ({'synthetic' if args.quick else 'HDM05'}), features in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    templates_loao(bits, offsets, names)
    auto_queries(bits, offsets, names)
    speed(bits, offsets, names, args.frames or (20_000 if args.quick else 1_000_000), 1 if args.quick else 3)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
