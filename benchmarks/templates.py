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

from mocapflow.plugins.relational.auto import auto_dtw_hits, auto_template, fusion_mask
from mocapflow.plugins.relational.classify import classify_clips, decide
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


def hdm05_cuts(fps: float) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Relational bits, offsets, names and the numeric default search's F_E^15 features of the HDM05 cuts."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from relational import _measures, load_hdm05

    from mocapflow.plugins.relational.features import relational_features
    from mocapflow.plugins.similarity.knn.end_effectors import EndEffectorFeatures

    db = load_hdm05(fps)
    bits = relational_features(db.canonical_positions(), db.fps, _measures(db), None, db.offsets)
    fe = np.concatenate([EndEffectorFeatures(joints=5).transform_motion(m) for m in db.motions])
    return bits, np.asarray(db.offsets, np.int64), [m.name for m in db.motions], fe


def synthetic_numeric(bits: np.ndarray, seed: int = 0) -> np.ndarray:
    """Stand-in F_E^15 features of the synthetic cuts (--quick): a fixed random projection of the bits plus noise."""
    rng = np.random.default_rng(seed)
    return (bits @ rng.normal(0, 0.1, (31, 15)) + rng.normal(0, 0.02, (len(bits), 15))).astype(np.float32)


def boot_low(fn, n: int, groups: np.ndarray | None = None, reps: int = 1000, seed: int = 0) -> float:
    """2.5 % quantile of ``fn(sample)`` over bootstrap resamples of the ``n`` items (clips or
    queries; with ``groups``, resampled within each group so every class keeps its size)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(reps):
        if groups is None:
            idx = rng.integers(0, n, n)
        else:
            idx = np.concatenate(
                [rng.choice(np.flatnonzero(groups == g), (groups == g).sum()) for g in np.unique(groups)]
            )
        out.append(fn(idx))
    return float(np.quantile(out, 0.025))


def templates_loao(bits: np.ndarray, offsets: np.ndarray, names: list[str]) -> dict:
    """Leave-one-actor-out: templates from two actors, the matcher's reported list and the
    classification scored on the third actor's cuts, all rotations; per class R / P with the
    lower bound of the bootstrap 95 % CI over the held-out clips (resampled within class)."""
    cls, act = meta(names)
    classes = sorted(set(cls))
    codes = frame_codes(bits)
    score = np.full((len(names), len(classes)), np.inf)
    hit = np.zeros((len(names), len(classes)), bool)
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
    print("\n== templates, leave-one-actor-out (train on two actors, test on the third, every rotation) ==")
    print(
        f"{'class':30s} {'ranking: R at P>=0.8':>21s} {'reported: P':>12s} {'(low)':>6s} {'R':>5s} {'(low)':>6s} "
        f"{'hits':>5s}"
    )
    ok_rank = ok = ok_low = 0
    for j, c in enumerate(classes):
        y = cls == c
        order = np.argsort(score[:, j], kind="stable")
        tp = np.cumsum(y[order])
        prec, rec = tp / np.arange(1, len(y) + 1), tp / y.sum()
        best_r = float(rec[prec >= 0.8].max()) if np.any(prec >= 0.8) else 0.0
        h = hit[:, j]

        def pr(idx, h=h, y=y):
            return (h[idx] & y[idx]).sum() / max(h[idx].sum(), 1), (h[idx] & y[idx]).sum() / max(y[idx].sum(), 1)

        p, r = pr(np.arange(len(y)))
        p_lo = boot_low(lambda i, pr=pr: pr(i)[0], len(y), cls)
        r_lo = boot_low(lambda i, pr=pr: pr(i)[1], len(y), cls)
        ok_rank += best_r >= 0.9
        ok += p >= 0.8 and r >= 0.9
        ok_low += p_lo >= 0.8 and r_lo >= 0.9
        print(f"{c:30s} {best_r:21.2f} {p:12.2f} {p_lo:6.2f} {r:5.2f} {r_lo:6.2f} {int(h.sum()):5d}")
    print(
        f"classes with R >= 0.9 at P >= 0.8: reported list {ok} of {len(classes)} (bootstrap lower bounds: "
        f"{ok_low}), against the ranking (same run) {ok_rank}"
    )
    return {"classes": ok}


def stretched(bits: np.ndarray, offsets: np.ndarray, clips: np.ndarray, factor: float) -> tuple[np.ndarray, np.ndarray]:
    """The ``clips`` played ``factor`` times slower (nearest frame): a slower performer."""
    out = []
    for i in clips:
        x = bits[offsets[i] : offsets[i + 1]]
        m = max(1, int(round(len(x) * factor)))
        out.append(x[np.minimum((np.arange(m) / factor).astype(int), len(x) - 1)])
    return np.concatenate(out), np.concatenate([[0], np.cumsum([len(x) for x in out])]).astype(np.int64)


#: Penalties tried by the inner folds of the classification (``classify.SPAN_PENALTY``).
PENALTIES = (0.1, 0.2, 0.3, 0.4, 0.5, 1.0)
#: Slower copies of the held-out cuts also classified (performers slower than the training ones).
SLOWER = (1.0, 1.5, 2.0)


def _before(temps, bits, offsets, clips):
    """The previous rule (same run, baseline): only templates that span the clip compete, all
    of them when none can; label and confidence (1.0 when one template is left)."""
    from mocapflow.plugins.relational.template_cutoff import COVER

    best, conf = [], []
    for f in SLOWER:
        x, off = stretched(bits, offsets, clips, f)
        raw = classify_clips(temps, x, off, penalty=np.inf)
        full = np.where(np.isfinite(raw), raw, classify_clips(temps, x, off, penalty=0.0))  # unpenalised costs
        lengths = np.array([t.n_frames for t in temps])
        can = lengths[None, :] >= COVER * np.diff(off)[:, None]
        c = np.where(can | ~can.any(axis=1, keepdims=True), full, np.inf)
        o = np.sort(c, axis=1)
        best.append(np.argmin(c, axis=1))
        conf.append(np.where(np.isfinite(o[:, 1]), (o[:, 1] - o[:, 0]) / np.maximum(o[:, 1], 1e-12), 1.0))
    return np.concatenate(best), np.concatenate(conf)


def _classify(temps, bits, offsets, clips, penalty):
    """Decisions (best, confidence, runner-up) of the ``clips`` and their slower copies, concatenated."""
    outs = [decide(classify_clips(temps, *stretched(bits, offsets, clips, f), penalty=penalty)) for f in SLOWER]
    return (
        np.concatenate([o[0] for o in outs]),
        np.concatenate([o[3] for o in outs]),
        np.concatenate([o[2] for o in outs]),
    )


def classification_nested(bits: np.ndarray, offsets: np.ndarray, names: list[str]) -> dict:
    """Classification, nested leave-one-actor-out: per outer fold the span penalty is chosen by
    the inner folds (templates from one training actor, the other training actor's cuts and
    their slower copies classified), then the outer fold's templates (both training actors)
    classify the held-out actor's cuts and their 1.5x / 2x slower copies. Accuracy with the
    bootstrap lower bound, ``unknown`` rate, confidences of 1.0, confusion matrix."""
    cls, act = meta(names)
    classes = sorted(set(cls))
    actors = sorted(set(act))
    truth, pred, conf, rup, speed, chosen = [], [], [], [], [], {}
    before, before_conf = [], []
    for held in actors:
        train_actors = [a for a in actors if a != held]
        inner = np.zeros(len(PENALTIES))
        for ih in train_actors:
            tr = np.isin(act, [a for a in train_actors if a != ih])
            if len({a for a in act[tr]}) < 1:
                continue
            temps = fit_templates(bits, offsets, list(cls), tr, list(act), classes)
            te = np.flatnonzero(act == ih)
            y = np.tile(cls[te], len(SLOWER))
            for pi, pen in enumerate(PENALTIES):
                b, _, _ = _classify(temps, bits, offsets, te, pen)
                inner[pi] += np.mean(np.where(b >= 0, np.array(classes)[np.maximum(b, 0)], "unknown") == y)
        pen = PENALTIES[int(np.argmax(inner))]
        chosen[held] = (pen, inner / max(len(train_actors), 1))
        temps = fit_templates(bits, offsets, list(cls), act != held, list(act), classes)
        te = np.flatnonzero(act == held)
        b, c, r = _classify(temps, bits, offsets, te, pen)
        ob, oc = _before(temps, bits, offsets, te)
        before.append(np.array(classes)[ob])
        before_conf.append(oc)
        truth.append(np.tile(cls[te], len(SLOWER)))
        pred.append(np.where(b >= 0, np.array(classes)[np.maximum(b, 0)], "unknown"))
        conf.append(c)
        rup.append(r)
        speed.append(np.repeat(SLOWER, len(te)))
    truth, pred, conf, rup, speed, before, before_conf = map(
        np.concatenate, (truth, pred, conf, rup, speed, before, before_conf)
    )
    print("\n== classification, nested leave-one-actor-out (penalty chosen on the inner folds only) ==")
    for held, (pen, acc) in chosen.items():
        print(
            f"  outer fold {held}: inner accuracy per penalty {dict(zip(PENALTIES, np.round(acc, 3).tolist(), strict=True))} -> {pen}"
        )
    out = {}
    for f in SLOWER:
        w = speed == f
        a = float(np.mean(pred[w] == truth[w]))
        lo = boot_low(lambda i, w=w: float(np.mean(pred[w][i] == truth[w][i])), int(w.sum()), truth[w])
        print(
            f"  held-out cuts x{f:g} slower: accuracy {a:.3f} (low {lo:.3f}); unknown {np.mean(pred[w] == 'unknown'):.3f}; "
            f"confidence 1.0: {int(np.sum(conf[w] >= 1.0))}, without a runner-up: {int(np.sum(rup[w] < 0))}"
        )
        out[f] = a
        print(
            f"    before (spanning templates only, all when none can; same run): accuracy "
            f"{np.mean(before[w] == truth[w]):.3f}, confidence 1.0: {int(np.sum(before_conf[w] >= 1.0))}"
        )
    labels = classes + ["unknown"]
    print("  confusion matrix (all speeds; rows: truth, columns: label; classes by their first 6 letters)")
    print("  " + " " * 8 + " ".join(f"{x[:6]:>6s}" for x in labels))
    for c in classes:
        w = truth == c
        print("  " + f"{c[:8]:8s}" + " ".join(f"{int(np.sum(pred[w] == x)):6d}" for x in labels))
    return {"accuracy": out[1.0], "slower": out}


def numeric_costs(fe: np.ndarray, offsets: np.ndarray, q: int, db: np.ndarray) -> np.ndarray:
    """Per clip of ``db`` the rank cost of the numeric default search (``matchers.search``:
    exact subsequence DTW on F_E^15, accumulated cost, its default ``min_span``): the first
    match of the clip in the search's ranked, non-overlapping list (inf if none)."""
    from mocapflow.framework.matching import SearchSpace, min_frames_of, select_matches
    from mocapflow.plugins.similarity.search.sdtw import sdtw_costs

    sel = np.concatenate([np.arange(offsets[i], offsets[i + 1]) for i in db])
    cid = np.repeat(np.asarray(db, np.int32), np.diff(offsets)[db])
    frame = (sel - np.repeat(offsets[db], np.diff(offsets)[db])).astype(np.int32)
    space = SearchSpace(cid, frame, features=fe[sel])
    query = fe[offsets[q] : offsets[q + 1]]
    cost, start, length = sdtw_costs(query, space)
    ends = np.arange(len(cost), dtype=np.int64)
    # the search's own selection (as subsequence_dtw / matchers.search), without the paths
    keep = select_matches(
        ends,
        start,
        cost,
        length,
        count=10 * len(db),
        max_cost=None,
        rank_by="cost",
        min_frames=min_frames_of(0.5, len(query)),
    )
    out = np.full(len(offsets) - 1, np.inf)
    for e in keep[::-1]:  # ranked: the first match of a clip wins
        out[int(cid[e])] = float(cost[e])
    return out


def average_precision(cost: np.ndarray, rel: np.ndarray, pool: np.ndarray) -> float:
    order = pool[np.argsort(cost[pool], kind="stable")]
    y = rel[order]
    tp = np.cumsum(y)
    return float((tp[y] / (np.flatnonzero(y) + 1)).sum() / max(rel[pool].sum(), 1))


def auto_queries(bits: np.ndarray, offsets: np.ndarray, names: list[str], fe: np.ndarray) -> dict:
    """Query by example as a user asks it: one cut of one actor is the query, the database the
    other actors' cuts (relevant: their cuts of the query's class), every cut a query. Mode
    auto with the matcher's defaults (mAP of its ranking, P / R of its reported hits per
    class with bootstrap lower bounds over the class's queries) against the numeric default
    search on F_E^15 on the same queries (mAP; its default 10 matches as hits)."""
    cls, act = meta(names)
    n = len(names)
    aps, naps, qcls, pr, npr = [], [], [], [], []
    for q in range(n):
        db = np.flatnonzero(act != act[q])
        sub = np.concatenate([bits[offsets[i] : offsets[i + 1]] for i in db])
        sub_off = np.concatenate([[0], np.cumsum(np.diff(offsets)[db])]).astype(np.int64)
        codes, bg = frame_codes(sub), sub.mean(axis=0)
        qb = bits[offsets[q] : offsets[q + 1]]
        rel = cls[db] == cls[q]
        t = auto_template(qb, bg)
        aps.append(average_precision(clip_min_costs(codes, sub_off, t.table()), rel, np.arange(len(db))))
        s, _, _ = auto_dtw_hits(t, qb, sub, codes, sub_off, bg)
        found = np.unique(np.searchsorted(sub_off, s, side="right") - 1)
        pr.append((rel[found].sum(), len(found), rel.sum()))
        ncost = numeric_costs(fe, offsets, q, db)[db]
        naps.append(average_precision(ncost, rel, np.arange(len(db))))
        top = np.argsort(ncost, kind="stable")[:10]
        top = top[np.isfinite(ncost[top])]
        npr.append((rel[top].sum(), len(top), rel.sum()))
        qcls.append(cls[q])
    qcls, pr, npr, aps, naps = np.array(qcls), np.array(pr, float), np.array(npr, float), np.array(aps), np.array(naps)
    m_lo = boot_low(lambda i: aps[i].mean(), n, qcls)
    nm_lo = boot_low(lambda i: naps[i].mean(), n, qcls)
    print(
        f"\n== query by example, other actors' cuts as the database: {n} queries ==\n"
        f"mode auto mAP {aps.mean():.3f} (low {m_lo:.3f}); numeric default search (F_E^15 sDTW, same queries) "
        f"mAP {naps.mean():.3f} (low {nm_lo:.3f})"
    )
    print(
        f"{'class':30s} {'auto: AP':>9s} {'hits P':>7s} {'(low)':>6s} {'R':>5s} {'(low)':>6s} | numeric AP  P@10  R@10"
    )
    ok = ok_low = 0
    for c in sorted(set(qcls)):
        w = np.flatnonzero(qcls == c)

        def p_of(i, a=pr):
            return float(np.mean(a[i, 0] / np.maximum(a[i, 1], 1)))

        def r_of(i, a=pr):
            return float(np.mean(a[i, 0] / np.maximum(a[i, 2], 1)))

        p, r = p_of(w), r_of(w)
        p_lo = boot_low(lambda i, w=w: p_of(w[i]), len(w))
        r_lo = boot_low(lambda i, w=w: r_of(w[i]), len(w))
        ok += p >= 0.8 and r >= 0.9
        ok_low += p_lo >= 0.8 and r_lo >= 0.9
        print(
            f"{c:30s} {aps[w].mean():9.2f} {p:7.2f} {p_lo:6.2f} {r:5.2f} {r_lo:6.2f} | {naps[w].mean():10.2f}"
            f" {p_of(w, npr):5.2f} {r_of(w, npr):5.2f}"
        )
    print(f"classes with auto hits P >= 0.8, R >= 0.9: {ok} of {len(set(qcls))} (bootstrap lower bounds: {ok_low})")
    return {"map": float(aps.mean()), "numeric_map": float(naps.mean()), "classes": ok}


def _anchor_query(temps, j, codes, offsets, index, table, coarse):
    """The previous default (anchor regions from the inverted lists, not admissible): baseline."""
    from _template_anchor import candidate_ranges

    from mocapflow.plugins.relational.template_coarse import coarse_search, template_step
    from mocapflow.plugins.relational.template_cutoff import acceptance_bound

    t = temps[j]
    s, e, _ = coarse_search(
        t, coarse, candidate_ranges(t, index)[0], acceptance_bound(t), 0.5, template_step(t, "auto")
    )
    return s[table.mask(j, s, e, offsets)]


def _best(fn, repeats):
    fn()
    b, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        b = min(b, time.perf_counter() - t0)
    return b, out


#: Fusion constants tried by the inner folds (None: fusion off).
FUSIONS = (None, 1.0, 1.3, 1.6, 2.0, 2.5)


def _qbe_record(bits, offsets, fe, cls, q, db):
    """One query by example against the clips ``db``: mode auto's hit clips (global clip
    numbers), the numeric default search's per-clip costs (over ``db``) and relevance."""
    sub = np.concatenate([bits[offsets[i] : offsets[i + 1]] for i in db])
    sub_off = np.concatenate([[0], np.cumsum(np.diff(offsets)[db])]).astype(np.int64)
    codes, bg = frame_codes(sub), sub.mean(axis=0)
    qb = bits[offsets[q] : offsets[q + 1]]
    t = auto_template(qb, bg)
    s, _, _ = auto_dtw_hits(t, qb, sub, codes, sub_off, bg)
    found = np.unique(np.searchsorted(sub_off, s, side="right") - 1)
    return found, numeric_costs(fe, offsets, q, db)[db], cls[db] == cls[q]


def _qbe_classes(records, qcls, fusion):
    """Classes whose queries' fused hits reach P >= 0.8 and R >= 0.9 (class means), mean F1, and per query (tp, hits, rel)."""
    pr = []
    for found, ncost, rel in records:
        keep = found[fusion_mask(found, ncost, fusion)]
        pr.append((rel[keep].sum(), len(keep), rel.sum()))
    pr = np.array(pr, float)
    p = pr[:, 0] / np.maximum(pr[:, 1], 1)
    r = pr[:, 0] / np.maximum(pr[:, 2], 1)
    ok, f1 = 0, []
    for c in sorted(set(qcls)):
        w = qcls == c
        ok += p[w].mean() >= 0.8 and r[w].mean() >= 0.9
        f1.append(2 * p[w].mean() * r[w].mean() / max(p[w].mean() + r[w].mean(), 1e-9))
    return ok, float(np.mean(f1)), pr


def fusion_nested(bits: np.ndarray, offsets: np.ndarray, names: list[str], fe: np.ndarray) -> dict:
    """Relational + numeric fusion (``fusion`` of ``matchers.relational``), nested leave-one-
    actor-out: per outer fold the constant is chosen on the inner folds (one training actor's
    cuts as queries, the other training actor's as the database: classes passing, then mean
    F1), then the held-out actor's cuts query the training actors' cuts with it."""
    cls, act = meta(names)
    actors = sorted(set(act))
    cache: dict = {}

    def records(qa, da):
        key = (qa, tuple(da))
        if key not in cache:
            db = np.flatnonzero(np.isin(act, da))
            cache[key] = [_qbe_record(bits, offsets, fe, cls, q, db) for q in np.flatnonzero(act == qa)]
        return cache[key]

    print("\n== relational + numeric fusion, nested leave-one-actor-out (constant chosen on the inner folds) ==")
    outer_pr, outer_cls, chosen = {f: [] for f in FUSIONS}, [], {}
    for held in actors:
        train = [a for a in actors if a != held]
        score = []
        for f in FUSIONS:
            tot, f1s = 0, []
            for qa in train:
                recs = records(qa, [a for a in train if a != qa])
                ok, f1, _ = _qbe_classes(recs, cls[act == qa], f)
                tot += ok
                f1s.append(f1)
            score.append((int(tot), round(float(np.mean(f1s)), 3)))
        best = FUSIONS[max(range(len(FUSIONS)), key=lambda i: score[i])]
        chosen[held] = best
        print(
            f"  outer fold {held}: inner (classes, mean F1) per constant {dict(zip(FUSIONS, score, strict=True))} -> {best}"
        )
        recs = records(held, train)
        outer_cls.append(cls[act == held])
        for f in FUSIONS:
            outer_pr[f].append(_qbe_classes(recs, cls[act == held], f)[2])
        outer_pr.setdefault("chosen", []).append(_qbe_classes(recs, cls[act == held], best)[2])
    qcls = np.concatenate(outer_cls)
    for f in (*FUSIONS, "chosen"):
        pr = np.concatenate(outer_pr[f])
        p, r = pr[:, 0] / np.maximum(pr[:, 1], 1), pr[:, 0] / np.maximum(pr[:, 2], 1)
        ok = ok_low = 0
        for c in sorted(set(qcls)):
            w = np.flatnonzero(qcls == c)
            pc, rc = p[w].mean(), r[w].mean()
            ok += pc >= 0.8 and rc >= 0.9
            p_lo = boot_low(lambda i, w=w, p=p: p[w[i]].mean(), len(w))
            r_lo = boot_low(lambda i, w=w, r=r: r[w[i]].mean(), len(w))
            ok_low += p_lo >= 0.8 and r_lo >= 0.9
        tag = "chosen per fold (nested)" if f == "chosen" else f"fixed {f} (outer view: not a selection)"
        print(
            f"  {tag:42s}: classes P >= 0.8, R >= 0.9: {ok} of {len(set(qcls))} (lower bounds {ok_low}); P {p.mean():.2f}, R {r.mean():.2f}"
        )
    return {"chosen": chosen}


def latency(bits: np.ndarray, offsets: np.ndarray, names: list[str], repeats: int = 3) -> None:
    """Per-query wall time over the whole cut set (the pipelines' setting): every template
    (learned from all cuts) as a query with the rival table built once, the default (every
    clip, admissible bound) against the previous anchor pre-filter in the same run; every cut
    as a mode-auto query with the matcher's defaults; best of ``repeats``, median over queries."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    cls, act = meta(names)
    temps = fit_templates(bits, offsets, list(cls), np.ones(len(names), bool), list(act))
    codes, bg = frame_codes(bits), bits.mean(axis=0)
    index = InvertedIndex().build(bits, np.repeat(np.arange(len(offsets) - 1), np.diff(offsets)).astype(np.int32))
    table = RivalTable.build(temps, codes, offsets)
    coarse = CoarseCodes(codes, offsets)
    tt = [
        _best(
            lambda j=j: cutoff_hits(temps, codes, offsets, only=[j], rival_table=table, step="auto", coarse=coarse),
            repeats,
        )[0]
        for j in range(len(temps))
    ]
    tb = [
        _best(lambda j=j: _anchor_query(temps, j, codes, offsets, index, table, coarse), repeats)[0]
        for j in range(len(temps))
    ]
    ta = []
    for q in range(len(names)):
        qb = bits[offsets[q] : offsets[q + 1]]
        ta.append(_best(lambda qb=qb: auto_dtw_hits(auto_template(qb, bg), qb, bits, codes, offsets, bg), repeats)[0])
    print(
        f"\n== per-query latency over the {len(names)} cuts ({len(bits)} frames), best of {repeats}; load "
        f"{os.getloadavg()[0]:.1f} ==\ntemplate retrieval median {1e3 * np.median(tt):.1f} ms (max {1e3 * max(tt):.1f}) "
        f"against the anchor pre-filter {1e3 * np.median(tb):.1f} ms (x{np.median(tt) / np.median(tb):.2f}); "
        f"mode auto median {1e3 * np.median(ta):.1f} ms (max {1e3 * max(ta):.1f})"
    )


def tiled(bits: np.ndarray, offsets: np.ndarray, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    reps = max(1, n_frames // len(bits))
    big = np.concatenate([bits] * reps)
    off = np.concatenate([offsets[:-1] + k * len(bits) for k in range(reps)] + [[reps * len(bits)]]).astype(np.int64)
    return big, off


def speed(bits, offsets, names, n_frames: int, repeats: int) -> None:
    """Template queries on the tiled database: the default (every clip, the kernel's admissible
    bound, coarse search) against the previous anchor pre-filter (baseline) and the full-rate
    search, same run; hits lost by the anchors against the default."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    cls, act = meta(names)
    temps = fit_templates(bits, offsets, list(cls), np.ones(len(names), bool), list(act))
    big, off = tiled(bits, offsets, n_frames)
    codes = frame_codes(big)
    index = InvertedIndex().build(big, np.repeat(np.arange(len(off) - 1), np.diff(off)).astype(np.int32))
    table = RivalTable.build(temps, codes, off)
    coarse = CoarseCodes(codes, off)
    print(
        f"\n== template queries over {len(big):,} frames ({len(off) - 1:,} clips), best of {repeats}; "
        f"load average {os.getloadavg()[0]:.1f} =="
    )
    tf, td, tb = [], [], []
    for j, t in enumerate(temps):
        t1, h1 = _best(
            lambda j=j: cutoff_hits(temps, codes, off, only=[j], rival_table=table, step=1, coarse=coarse), repeats
        )
        ta, ha = _best(
            lambda j=j: cutoff_hits(temps, codes, off, only=[j], rival_table=table, step="auto", coarse=coarse), repeats
        )
        t0, h0 = _best(lambda j=j: _anchor_query(temps, j, codes, off, index, table, coarse), repeats)
        tf.append(t1)
        td.append(ta)
        tb.append(t0)
        lost = len(np.setdiff1d(ha[0][0], h0))
        print(
            f"  {t.label:30s} K={t.n_frames:4d}: default {ta * 1e3:7.1f} ms ({len(ha[0][0])} hits) | anchors "
            f"{t0 * 1e3:7.1f} ms ({len(h0)} hits, {lost} of the default's lost) | full rate {t1 * 1e3:7.1f} ms ({len(h1[0][0])})"
        )
    print(
        f"median per template: default {1e3 * np.median(td):.1f} ms, anchors {1e3 * np.median(tb):.1f} ms "
        f"(default x{np.median(td) / np.median(tb):.2f} of the anchors; total x{np.sum(td) / np.sum(tb):.2f}), "
        f"full rate {1e3 * np.median(tf):.1f} ms"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="synthetic labelled cuts, 20 k frames, no HDM05 needed")
    ap.add_argument("--frames", type=int, default=None, help="frames of the tiled database (default 1 M)")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--no-speed", action="store_true", help="skip the large tiled database")
    ap.add_argument("--no-auto", action="store_true", help="templates and classification only")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.quick:
        bits, offsets, names = synthetic_cuts()
        fe = synthetic_numeric(bits)
    else:
        bits, offsets, names, fe = hdm05_cuts(args.fps)
    print(
        f"{len(names)} cuts, {len(bits)} frames ({'synthetic' if args.quick else 'HDM05'}), features in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    templates_loao(bits, offsets, names)
    classification_nested(bits, offsets, names)
    if args.no_auto:
        return 0
    auto_queries(bits, offsets, names, fe)
    fusion_nested(bits, offsets, names, fe)
    latency(bits, offsets, names, 1 if args.quick else 3)
    if args.no_speed:
        return 0
    speed(bits, offsets, names, args.frames or (20_000 if args.quick else 1_000_000), 1 if args.quick else 3)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
