"""Motion templates and automatic feature selection on the HDM05 cuts (run by ``relational.py --templates``).

Leave-one-actor-out over the three actors (bd, bk, dg): templates learned from two actors'
cuts; retrieval over all 66 cuts, scored on the held-out actor's cuts (the ones to find;
each class has 2 per actor, 6 over the three folds); classification of the held-out cuts.

Figures (per class, pooled over the folds):

* ranking operating point: the best recall reached at precision >= 0.8 when the held-out
  cuts are ranked by the class template's cost (no threshold involved);
* calibrated threshold: precision and recall of the hits the matcher reports (cost <= the
  template's threshold, calibrated on the training examples only);
* classification: accuracy of the cheapest template (all 31 features and key features).

Automatic selection from a single example: every cut is a query against all 66 (relevant:
the other 5 cuts of its class). mAP of the ranking, per class the precision when the
ranking first reaches recall >= 0.9 (all 5), and P / R of the reported hits; for
``auto_search`` dtw (default), adaptive and 1-/2-mismatch. The relative cut of dtw hits is
chosen per fold on the other actors' queries only.
"""
from __future__ import annotations

import time

import numpy as np

from mocapflow.plugins.relational.auto import auto_template, select_features
from mocapflow.plugins.relational.classify import classify_clips
from mocapflow.plugins.relational.inverted import InvertedIndex
from mocapflow.plugins.relational.queries import example_query, search_set, subset_member
from mocapflow.plugins.relational.template import cutoff_hits, fit_templates, search_template
from mocapflow.plugins.relational.template_model import (clip_min_costs, fit_class_template, fit_template, frame_codes,
                                                       resample_rows)


def _meta(names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    return np.array([n.split("_")[2] for n in names]), np.array([n.split("_")[1] for n in names])


def _fit_fold(bits, offsets, cls, train, features="key", **kw):
    _, act = _meta(_fit_fold.names)
    classes = sorted(set(cls))
    return fit_templates(bits, offsets, list(cls), train, list(act), classes, features, **kw), classes


def templates_loao(bits: np.ndarray, offsets: np.ndarray, names: list[str], search_kw: dict | None = None, **kw) -> dict:
    """Leave-one-actor-out template retrieval and classification (module doc); ``search_kw``
    go to :func:`cutoff_hits` (e.g. ``step``: the coarse-rate search)."""
    cls, act = _meta(names)
    _fit_fold.names = names
    classes = sorted(set(cls))
    codes = frame_codes(bits)
    score = np.full((len(names), len(classes)), np.inf)   # held-out clip x template (key features)
    # rivals at the full rate (step 1) and with the step's default coarse-rate search (step auto)
    modes = {"threshold": ("threshold", {}), "rivals": ("rivals", {}), "coarse": ("rivals", {"step": "auto"})}
    hit = {m: np.zeros((len(names), len(classes)), bool) for m in modes}
    bounds = {m: np.zeros((len(names), len(classes))) for m in modes}
    pred_all, pred_key = np.empty(len(names), object), np.empty(len(names), object)
    for held in sorted(set(act)):
        train = act != held
        temps, _ = _fit_fold(bits, offsets, cls, train, **kw)
        te = np.flatnonzero(~train)
        for j, t in enumerate(temps):
            score[te, j] = clip_min_costs(codes, offsets, t.table())[te]
        for mode, (rule, kw_m) in modes.items():  # the cut-off lists the matcher reports (cutoff_hits), on the held-out cuts
            for j, (s, _, _, bound) in enumerate(cutoff_hits(temps, codes, offsets, rule, **{**kw_m, **(search_kw or {})})):
                found = np.zeros(len(names), bool)
                found[np.searchsorted(offsets, s, side="right") - 1] = True
                hit[mode][te, j] = found[te]
                bounds[mode][te, j] = bound
        sub = np.concatenate([bits[offsets[i]:offsets[i + 1]] for i in te])
        sub_off = np.concatenate([[0], np.cumsum(np.diff(offsets)[te])])
        pred_all[te] = np.array(classes)[classify_clips(temps, sub, sub_off, "all").argmin(axis=1)]
        pred_key[te] = np.array(classes)[classify_clips(temps, sub, sub_off, "key").argmin(axis=1)]
    rows = {}
    for j, c in enumerate(classes):
        y = cls == c
        order = np.argsort(score[:, j], kind="stable")
        tp = np.cumsum(y[order])
        prec, rec = tp / np.arange(1, len(y) + 1), tp / y.sum()
        best_r = float(rec[prec >= 0.8].max()) if np.any(prec >= 0.8) else 0.0
        row = [best_r]
        for mode in modes:
            h = hit[mode][:, j]
            row += [float((h & y).sum() / max(h.sum(), 1)), float((h & y).sum() / y.sum()), int(h.sum())]
        rows[c] = tuple(row)
    return {"rows": rows, "acc_all": float(np.mean(pred_all == cls)), "acc_key": float(np.mean(pred_key == cls)),
            "confusions": [(names[i], pred_all[i]) for i in np.flatnonzero(pred_all != cls)]}


def _ranking_metrics(costs: np.ndarray, rel: np.ndarray) -> tuple[float, float]:
    """(AP, precision when recall first reaches >= 0.9) of one query's clip costs."""
    fin = np.isfinite(costs)
    order = np.flatnonzero(fin)[np.argsort(costs[fin], kind="stable")]
    y = rel[order]
    if not y.any():
        return 0.0, 0.0
    tp = np.cumsum(y)
    ap = float((tp[y] / (np.flatnonzero(y) + 1)).sum() / rel.sum())
    reach = np.flatnonzero(tp / rel.sum() >= 0.9 - 1e-9)
    return ap, float(tp[reach[0]] / (reach[0] + 1)) if len(reach) else 0.0


def auto_single_example(bits: np.ndarray, offsets: np.ndarray, names: list[str], min_run: int = 4,
                        features: str = "all", weighting: float = 0.5, paper: bool = True, mutual_auto: bool | None = None) -> dict:
    """Automatic selection from one example (module doc); dtw (template on ``features``,
    surprise ``weighting``), with ``paper`` the paper's machinery, with ``mutual_auto``
    (default: as ``paper``) the ``auto_mutual: auto`` designs (:func:`mutual_auto_designs`)."""
    mutual_auto = paper if mutual_auto is None else mutual_auto
    from itertools import product

    from mocapflow.plugins.relational.auto import relative_cost_cut

    cls, act = _meta(names)
    n = len(names)
    codes = frame_codes(bits)
    bg = bits.mean(axis=0)
    cost = np.zeros((n, n))
    for q in range(n):
        t = auto_template(bits[offsets[q]:offsets[q + 1]], bg, None, min_run, features, weighting)
        cost[q] = clip_min_costs(codes, offsets, t.table())
    rel = (cls[:, None] == cls[None, :]) & ~np.eye(n, dtype=bool)
    masked = np.where(np.eye(n, dtype=bool), np.inf, cost)

    # the cut's parameters per fold: the most classes meeting P >= 0.7, R >= 0.9 on the other actors' queries
    designs = {"dtw": list(product(np.round(np.arange(0.5, 1.5, 0.05), 2), (0.25, 0.5, 0.75, 1.0))),  # blend (default)
               "dtw, cut x median (first design)": [(a, 0.0) for a in (0.4, 0.5, 0.6, 0.7, 0.8)]}
    out = {"cuts": {}}
    # mutual check (auto_mutual: clip): hit h of q kept only when q is a hit of h's whole clip as a query
    designs["dtw + mutual (whole clips)"] = designs["dtw"]
    mutual = {"dtw + mutual (whole clips)"}

    def hit_row(q, cut, key):
        hit = masked[q] <= relative_cost_cut(masked[q], *cut)
        if key in mutual:
            hit &= np.array([masked[h, q] <= relative_cost_cut(masked[h], *cut) if hit[h] else False for h in range(n)])
        return hit

    def hits_pr(q, cut, key="dtw"):
        hit = hit_row(q, cut, key)
        return (float((hit & rel[q]).sum() / max(hit.sum(), 1)), float((hit & rel[q]).sum() / rel[q].sum()))

    for key, grid in designs.items():
        chosen = np.zeros((n, 2))
        for held in sorted(set(act)):
            tr = np.flatnonzero(act != held)

            def n_good(cut):
                pr = np.array([hits_pr(q, cut, key) for q in tr])
                return sum((pr[cls[tr] == c, 0].mean() >= 0.7) & (pr[cls[tr] == c, 1].mean() >= 0.9) for c in set(cls)) \
                    + 1e-3 * pr.mean(axis=0).sum()
            chosen[act == held] = max(grid, key=n_good)
        out[key] = {}
        for q in range(n):
            ap, p9 = _ranking_metrics(masked[q], rel[q])
            out[key].setdefault(cls[q], []).append((ap, p9) + hits_pr(q, tuple(chosen[q]), key))
        out["cuts"][key] = sorted({tuple(float(x) for x in c) for c in chosen})
    if mutual_auto:  # auto_mutual: auto, c (and the window) chosen per fold
        more = mutual_auto_designs(bits, offsets, names, masked, rel, min_run, features, weighting)
        out["cuts"].update(more.pop("cuts"))
        out.update(more)
    # other actors only: one example, and two (the actor's other take as the extra example)
    out["dtw, other actors"], out["dtw + 1 example, other actors"] = {}, {}
    for q in range(n):
        other = rel[q] & (act != act[q])
        mate = np.flatnonzero(rel[q] & (act == act[q]))
        c1 = masked[q].copy()
        c1[mate] = np.inf
        t = auto_template(bits[offsets[q]:offsets[q + 1]], bg, [bits[offsets[m]:offsets[m + 1]] for m in mate], min_run,
                          features, weighting)
        c2 = clip_min_costs(codes, offsets, t.table())
        c2[q] = np.inf
        c2[mate] = np.inf
        for key, c in (("dtw, other actors", c1), ("dtw + 1 example, other actors", c2)):
            ap, p9 = _ranking_metrics(c, other)
            out[key].setdefault(cls[q], []).append((ap, p9, np.nan, np.nan))
    if not paper:
        return out
    # the paper's machinery on the selected features
    index = InvertedIndex().build(bits, np.repeat(np.arange(n), np.diff(offsets)).astype(np.int32))
    for mode, mm in (("adaptive", 0), ("mismatch", 1), ("mismatch", 2)):
        key = mode + (str(mm) if mode == "mismatch" else "")
        out[key] = {}
        for q in range(n):
            cols, sm, _ = select_features(bits[offsets[q]:offsets[q + 1]], bg, min_run=min_run, max_features=2)
            c = np.full(n, np.inf)
            if len(cols):
                h = example_query(index, sm, sorted(cols.tolist()), mode, mismatches=mm)
                np.minimum.at(c, h.clip, h.cost)
            c[q] = np.inf
            ap, p9 = _ranking_metrics(c, rel[q])
            hit = np.isfinite(c)
            out[key].setdefault(cls[q], []).append((ap, p9, float((hit & rel[q]).sum() / max(hit.sum(), 1)),
                                                    float((hit & rel[q]).sum() / rel[q].sum())))
    return out


#: ``mutual_ratio`` c values tried per fold (inf: every clip checked whole, i.e. ``auto_mutual: clip``)
MUTUAL_RATIOS = (1.5, 2.0, 3.0, 4.0, 6.0, 8.0, np.inf)
#: ``mutual_window`` m values tried (None: hits in clips longer than c x the query are not checked)
MUTUAL_WINDOWS = (None, 0.5, 1.0)


def _window_reverse(bits, offsets, min_run, features, weighting, m, min_ratio):
    """For every pair (query q, clip h) with h longer than ``min_ratio`` x q: q's least cost under
    the auto template of a window of q's length x (1 + m) centred on q's best path in h, and the
    5 % quantile / median of that template's per-range least costs (the window cut out of h,
    as the matcher: :func:`~mocapflow.plugins.relational.auto.reverse_costs`); nan elsewhere."""
    from mocapflow.plugins.relational.auto import reverse_costs
    from mocapflow.plugins.relational.template_model import template_costs

    n, L = len(offsets) - 1, np.diff(offsets)
    codes = frame_codes(bits)
    bg = bits.mean(axis=0)
    ranges = np.stack([offsets[:-1], offsets[1:]], axis=1)
    own, lo_q, med = (np.full((n, n), np.nan) for _ in range(3))
    for q in range(n):
        t = auto_template(bits[offsets[q]:offsets[q + 1]], bg, None, min_run, features, weighting)
        cost, start = template_costs(codes, t.table(), ranges)
        for h in np.flatnonzero(L > min_ratio * L[q]):
            seg = cost[offsets[h]:offsets[h + 1]]
            if not np.isfinite(seg).any():
                continue
            end = offsets[h] + int(np.argmin(seg))
            a, b = int(start[end]), end + 1
            width = max(int(round(L[q] * (1 + m))), b - a)
            wlo = int(np.clip((a + b) // 2 - width // 2, offsets[h], max(offsets[h], offsets[h + 1] - width)))
            whi = min(offsets[h + 1], wlo + width)
            own[q, h], per = reverse_costs(bits[wlo:whi], wlo, whi, codes[offsets[q]:offsets[q + 1]], codes, offsets, bg,
                                           min_run, features, weighting)
            fin = per[np.isfinite(per)]
            if len(fin):
                lo_q[q, h], med[q, h] = np.quantile(fin, 0.05), np.median(fin)
    return own, lo_q, med


def mutual_auto_designs(bits, offsets, names, masked, rel, min_run=4, features="all", weighting=0.5) -> dict:
    """``auto_mutual: auto`` on the cut database, vectorised over the clip-cost matrix
    ``masked`` (query x clip, diagonal inf): a hit in a clip of at most c x the query's
    length is kept when the clip finds the query too (the whole clip's row of ``masked``);
    in a longer clip it is checked on a window (``MUTUAL_WINDOWS`` m) or not at all and
    then must pass the plain cut (relative_cut x 1.15 / 1.3, as the matcher). Per fold
    (relative_cut, low_weight, c) are chosen on the other actors' queries: the most classes
    at P >= 0.7, R >= 0.9, then the smallest c (the weakest assumption of one motion per
    clip), then the best mean P + R. Returns the per-class rows and the choices."""
    from itertools import product

    cls, act = _meta(names)
    n, L = len(names), np.diff(offsets)
    fin = np.where(np.isfinite(masked), masked, np.nan)
    q05, med = np.nanquantile(fin, 0.05, axis=1), np.nanmedian(fin, axis=1)
    grid = list(product(MUTUAL_RATIOS, np.round(np.arange(0.9, 1.6, 0.05), 2), (0.5, 0.75, 1.0)))
    out = {"cuts": {}}
    for m in MUTUAL_WINDOWS:
        key = "dtw + mutual auto" + ("" if m is None else f", window m={m:g}")
        win = None if m is None else _window_reverse(bits, offsets, min_run, features, weighting, m, min(MUTUAL_RATIOS))

        def hit_matrix(c, rc, lw, win=win):
            cut = rc * q05 ** lw * med ** (1 - lw)
            h = masked <= cut[:, None]
            short = L[None, :] <= c * L[:, None]
            if win is None:
                far = masked <= (cut * 1.15 / 1.3)[:, None]
            else:
                own, lo_w, med_w = win
                with np.errstate(invalid="ignore"):
                    far = h & (own <= rc * lo_w ** lw * med_w ** (1 - lw))
            return np.where(short, h & h.T, far)

        def pr(hm, qs):
            tp = (hm & rel)[qs].sum(axis=1)
            return np.stack([tp / np.maximum(hm[qs].sum(axis=1), 1), tp / rel[qs].sum(axis=1)], axis=1)

        def score(p, qs):
            good = sum((p[cls[qs] == c_, 0].mean() >= 0.7) & (p[cls[qs] == c_, 1].mean() >= 0.9) for c_ in set(cls))
            return good, p.mean(axis=0).sum()

        chosen = {}
        for held in sorted(set(act)):
            tr = np.flatnonzero(act != held)
            best = max(grid, key=lambda g: (lambda sc: (sc[0], -g[0], sc[1]))(score(pr(hit_matrix(*g), tr), tr)))
            chosen[held] = best
        out[key] = {}
        for held, g in chosen.items():
            te = np.flatnonzero(act == held)
            p = pr(hit_matrix(*g), te)
            for i, q in enumerate(te):
                ap, p9 = _ranking_metrics(masked[q], rel[q])
                out[key].setdefault(cls[q], []).append((ap, p9, p[i, 0], p[i, 1]))
        out["cuts"][key] = {h: tuple(float(x) for x in g) for h, g in chosen.items()}
        if m is None:  # the matcher's fixed defaults, no per-fold choice
            from mocapflow.plugins.relational.matcher import RelationalMatcher

            c_def = RelationalMatcher.Params.model_fields["mutual_ratio"].default
            p = pr(hit_matrix(c_def, 1.3, 0.75), np.arange(n))
            out["dtw + mutual auto, fixed defaults"] = {}
            for q in range(n):
                ap, p9 = _ranking_metrics(masked[q], rel[q])
                out["dtw + mutual auto, fixed defaults"].setdefault(cls[q], []).append((ap, p9, p[q, 0], p[q, 1]))
    return out


def long_take_check(bits, offsets, names, ratio: float = 3.0, min_run: int = 4) -> dict:
    """Mode auto on a long take: per fold the held-out actor's 22 cuts concatenated into one
    clip (a take holding 22 motions), the other actors' 44 cuts as separate clips; every
    cut of the other actors is a query (the matcher's code path, :func:`auto_dtw_hits`). Per
    ``auto_mutual`` (off / auto / clip): recall = the held-out cuts of the query's class
    (2) found inside the take (a hit overlapping them), precision = such hits / all hits
    inside the take, and P / R over the separate cuts (relevant: the other cuts of the class
    among them). Returns {mode: (take P, take R, cuts P, cuts R)}."""
    from mocapflow.plugins.relational.auto import auto_dtw_hits

    cls, act = _meta(names)
    res = {m: [] for m in ("off", "auto", "clip")}
    for held in sorted(set(act)):
        te, tr = np.flatnonzero(act == held), np.flatnonzero(act != held)
        order = np.concatenate([te, tr])
        sub = np.concatenate([bits[offsets[i]:offsets[i + 1]] for i in order])
        lens = np.diff(offsets)[order]
        cut_off = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
        db_off = np.concatenate([[0], cut_off[len(te):]]).astype(np.int64)  # the held-out cuts: one clip
        codes, bg = frame_codes(sub), sub.mean(axis=0)
        for qi, q in enumerate(order[len(te):], start=len(te)):
            qb = sub[cut_off[qi]:cut_off[qi + 1]]
            t = auto_template(qb, bg, None, min_run)
            for mode in res:
                s, e, _ = auto_dtw_hits(t, qb, sub, codes, db_off, bg, mode, ratio=ratio, min_run=min_run)
                in_take = e <= db_off[1]
                which = np.searchsorted(cut_off, (s + e) // 2, side="right") - 1  # the cut a hit's middle lies in
                good_take = cls[order[which[in_take]]] == cls[q]
                found_take = {int(w) for w in which[in_take][good_take]}
                clip = np.searchsorted(db_off, s[~in_take], side="right") - 1
                hit_cuts = {int(c) + len(te) - 1 for c in clip} - {qi}
                rel_cuts = {j for j in range(len(te), len(order)) if cls[order[j]] == cls[q] and j != qi}
                res[mode].append((good_take.sum() / max(in_take.sum(), 1), len(found_take) / 2,
                                  len(hit_cuts & rel_cuts) / max(len(hit_cuts), 1), len(hit_cuts & rel_cuts) / len(rel_cuts)))
    return {m: tuple(np.mean(v, axis=0)) for m, v in res.items()}


def speed(bits: np.ndarray, offsets: np.ndarray, names: list[str], big_bits: np.ndarray, big_offsets: np.ndarray,
          repeats: int = 5) -> None:
    """Template query over the large database, and learning from 10 examples."""
    cls, _ = _meta(names)
    _fit_fold.names = names
    temps, classes = _fit_fold(bits, offsets, cls, np.ones(len(names), bool))
    prefilter_speed(bits, offsets, names, big_bits, big_offsets, repeats, temps)
    # learning: 10 examples of one class = its 6 cuts + 4 time-scaled copies (0.8, 0.9, 1.1, 1.2)
    print("\n== learning a class template from 10 examples ==")
    for c in ("kickLFront1Reps", "lieDownFloor"):
        ex = [bits[offsets[i]:offsets[i + 1]].astype(np.float32) for i in np.flatnonzero(cls == c)]
        ex += [(resample_rows(ex[i], int(len(ex[i]) * f)) > 0.5).astype(np.float32) for i, f in enumerate((0.8, 0.9, 1.1, 1.2))]
        fit_template(c, ex[:2])  # compile outside the timing
        t0 = time.perf_counter()
        fit_template(c, ex)
        t1 = time.perf_counter()
        fit_class_template(c, ex, bits.mean(axis=0), groups=[i % 6 // 2 for i in range(len(ex))])
        t2 = time.perf_counter()
        print(f"  {c:20s} ({np.mean([len(x) for x in ex]):.0f} frames on average): learning {(t1 - t0) * 1e3:.0f} ms, "
              f"learning + key features + leave-one-out threshold {(t2 - t1) * 1e3:.0f} ms (target <= 1 s)")


def report(bits: np.ndarray, offsets: np.ndarray, names: list[str]) -> None:
    """Print the template and auto-selection figures (module doc)."""
    t0 = time.perf_counter()
    res = templates_loao(bits, offsets, names)
    print(f"\n== motion templates, leave-one-actor-out ({time.perf_counter() - t0:.1f} s) ==")
    print("class".ljust(30) + "ranking: best R at P>=0.8 | cut-off threshold: P     R  hits | cut-off rivals, step 1: P     R  hits"
          " | rivals, step auto (default): P     R  hits")
    for c, (r, p, rr, h, pr, rr2, h2, pc, rc, hc) in res["rows"].items():
        print(f"{c:30s}{r:26.2f}{p:22.2f}{rr:6.2f}{h:6d}{pr:26.2f}{rr2:6.2f}{h2:6d}{pc:33.2f}{rc:6.2f}{hc:6d}")
    ok_rank = sum(v[0] >= 0.9 for v in res["rows"].values())
    ok_thr = sum(v[1] >= 0.8 and v[2] >= 0.9 for v in res["rows"].values())
    ok_riv = sum(v[4] >= 0.8 and v[5] >= 0.9 for v in res["rows"].values())
    ok_crs = sum(v[7] >= 0.8 and v[8] >= 0.9 for v in res["rows"].values())
    print(f"classes with R >= 0.9 at P >= 0.8: ranking {ok_rank} of 11, cut-off threshold {ok_thr} of 11, "
          f"cut-off rivals step 1 {ok_riv} of 11, step auto (default) {ok_crs} of 11 (target 9)")
    print(f"classification accuracy (held-out actor): all features {res['acc_all']:.3f}, key features {res['acc_key']:.3f} "
          f"(target 0.9); wrong: {res['confusions']}")
    report_auto(bits, offsets, names)


def report_auto(bits: np.ndarray, offsets: np.ndarray, names: list[str]) -> None:
    """Print the automatic-selection figures (module doc)."""
    t0 = time.perf_counter()
    auto = auto_single_example(bits, offsets, names)
    for label, f, w in (("dtw, key features unweighted (previous)", "key", 0.0), ("dtw, all features unweighted", "all", 0.0),
                        ("dtw, key features, weights^0.5", "key", 0.5), ("dtw, all features, weights^1", "all", 1.0)):
        other = auto_single_example(bits, offsets, names, features=f, weighting=w, paper=False)
        auto[label] = other["dtw"]
        auto["cuts"][label] = other["cuts"]["dtw"]
    print(f"\n== automatic feature selection from a single example ({time.perf_counter() - t0:.1f} s; "
          f"cut (relative_cut, low_weight) chosen per fold: {auto['cuts']}) ==")
    print("search (default: dtw, all features, surprise weights^0.5)".ljust(42) + "mAP    P@R0.9  hits P   hits R   classes P@R0.9>=0.7   classes hits P>=0.7,R>=0.9")
    mutual_keys = ["dtw + mutual auto", "dtw + mutual auto, fixed defaults"] + [f"dtw + mutual auto, window m={m:g}" for m in MUTUAL_WINDOWS if m is not None]
    for key in ("dtw", "dtw + mutual (whole clips)", *mutual_keys, "dtw, cut x median (first design)", "dtw, key features unweighted (previous)",
                "dtw, all features unweighted", "dtw, key features, weights^0.5", "dtw, all features, weights^1", "adaptive",
                "mismatch1", "mismatch2", "dtw, other actors", "dtw + 1 example, other actors"):
        per = {c: np.mean(v, axis=0) for c, v in auto[key].items()}
        allv = np.concatenate([np.array(v) for v in auto[key].values()])
        print(f"{key:42s}{allv[:, 0].mean():.3f}{allv[:, 1].mean():8.2f}{allv[:, 2].mean():9.2f}{allv[:, 3].mean():9.2f}"
              f"{sum(v[1] >= 0.7 for v in per.values()):14d}{sum(v[2] >= 0.7 and v[3] >= 0.9 for v in per.values()):26d}")
    t0 = time.perf_counter()
    take = long_take_check(bits, offsets, names)
    print(f"long take (held-out actor's 22 cuts as one clip; other actors' cuts as queries and separate clips; "
          f"{time.perf_counter() - t0:.1f} s): auto_mutual: take P / take R / cuts P / cuts R")
    for m, v in take.items():
        print(f"  {m:5s} " + " / ".join(f"{x:.2f}" for x in v))
    print("per class: AP / P@R0.9 / hits P / hits R (dtw) | hits P / hits R (dtw + mutual clip) | (dtw + mutual auto, default)")
    for c, v in auto["dtw"].items():
        m, mm = np.mean(v, axis=0), np.mean(auto["dtw + mutual (whole clips)"][c], axis=0)
        ma = np.mean(auto["dtw + mutual auto"][c], axis=0)
        print(f"  {c:30s} {m[0]:.2f} / {m[1]:.2f} / {m[2]:.2f} / {m[3]:.2f} | {mm[2]:.2f} / {mm[3]:.2f} | {ma[2]:.2f} / {ma[3]:.2f}")


def prefilter_speed(bits, offsets, names, big_bits, big_offsets, repeats: int = 3, temps=None) -> None:
    """Template queries over the large database (best of ``repeats`` each; templates from all
    three actors): the first design (full scan, no abandoning) as the same-run baseline, the
    threshold cut-off (inverted-list candidate regions + early abandoning) and the default
    rivals cut-off (the same search at the acceptance bound + the rival check)."""
    from mocapflow.plugins.relational.template_model import search_costs
    from mocapflow.plugins.relational.template_prefilter import candidate_ranges

    if temps is None:
        cls, _ = _meta(names)
        _fit_fold.names = names
        temps, _ = _fit_fold(bits, offsets, cls, np.ones(len(names), bool))
    codes = frame_codes(big_bits)
    t0 = time.perf_counter()
    index = InvertedIndex().build(big_bits, np.repeat(np.arange(len(big_offsets) - 1), np.diff(big_offsets)).astype(np.int32))
    print(f"\n== template queries over {len(big_bits):,} frames ({len(big_offsets) - 1:,} clips), index built in "
          f"{time.perf_counter() - t0:.2f} s; load average {open('/proc/loadavg').read().split()[0]} ==")
    print("baseline = full scan without abandoning (the first design); threshold = cut-off threshold with candidate "
          "regions + early abandoning; rivals = the default cut-off (acceptance bound + rival check)")
    whole = np.stack([big_offsets[:-1], big_offsets[1:]], axis=1)
    search_template(temps[0], codes, big_offsets, index=index)  # compile outside the timing
    cutoff_hits(temps, codes, big_offsets, "rivals", index=index, only=[0])
    from mocapflow.plugins.relational.template_cutoff import RivalTable

    t0 = time.perf_counter()
    table = RivalTable.build(temps, codes, big_offsets)
    print(f"  rival table (all-feature costs of the 11 templates, once per database like an index): "
          f"{time.perf_counter() - t0:.2f} s, {(table.own.nbytes + 3 * table.best.nbytes) / 1e6:.0f} MB")
    times, riv_t, base_t, lost = [], [], [], []

    cpu = {}

    def best_of(fn, key=None):  # best wall time; the CPU time of all threads (less load-dependent) kept by key
        b, c, out = np.inf, np.inf, None
        for _ in range(repeats):
            t1, c1 = time.perf_counter(), time.process_time()
            out = fn()
            b, c = min(b, time.perf_counter() - t1), min(c, time.process_time() - c1)
        if key:
            cpu[key] = c
        return b, out

    from mocapflow.plugins.relational.template_coarse import CoarseCodes, template_step

    coarse = CoarseCodes(codes, big_offsets)
    t0 = time.perf_counter()
    for st in (2, 3, 4):
        coarse.get(st)
    print(f"  coarse codes at steps 2, 3, 4 (once per database): {(time.perf_counter() - t0) * 1e3:.0f} ms")
    steps = {"3": (3, 7), "4": (4, 7), "auto/10": ("auto", 10), "auto/7 (default)": ("auto", 7)}
    coarse_t, coarse_cpu = {k: [] for k in steps}, {}
    for j, t in enumerate(temps):
        line = []
        for k, (st, cf) in steps.items():
            tc, lc = best_of(lambda: cutoff_hits(temps, codes, big_offsets, "rivals", index=index, only=[j], rival_table=table,
                                                 step=st, coarse_frames=cf, coarse=coarse), "coarse")
            coarse_t[k].append(tc)
            coarse_cpu.setdefault(k, []).append(cpu["coarse"])
            line.append(f"step {k} ({template_step(t, st, cf)}) {tc * 1e3:5.1f} ms CPU {cpu['coarse'] * 1e3:4.0f} "
                        f"({len(lc[0][0])} hits)")
        print(f"  {t.label:30s} rivals, coarse search: " + " | ".join(line))
    for j, t in enumerate(temps):
        tb, (fs, fe, _, _) = best_of(lambda: search_costs(codes, t.table(), whole, t.threshold, abandon=False))
        tt, (s, e, _) = best_of(lambda: search_template(t, codes, big_offsets, index=index), "threshold")
        tr, lists = best_of(lambda: cutoff_hits(temps, codes, big_offsets, "rivals", index=index, only=[j], rival_table=table),
                            "rivals")
        r2, frac2 = candidate_ranges(t, index, anchors=2)
        t2, (s2, e2, _, _) = best_of(lambda: search_costs(codes, t.table(), r2, t.threshold))
        miss2 = len(set(zip(fs.tolist(), fe.tolist())) - set(zip(s2.tolist(), e2.tolist())))
        _, frac = candidate_ranges(t, index)
        full = set(zip(fs.tolist(), fe.tolist()))
        miss = len(full - set(zip(s.tolist(), e.tolist())))
        times.append(tt)
        riv_t.append(tr)
        base_t.append(tb)
        lost.append(miss / max(len(full), 1))
        print(f"  {t.label:30s} K={t.n_frames:4d}: baseline {tb * 1e3:6.1f} ms | threshold {tt * 1e3:6.1f} ms (x{tb / tt:4.1f}, "
              f"{len(s)} hits, {miss} of the baseline's {len(fs)} lost; {100 * frac:4.1f} % of frames searched) | "
              f"rivals {tr * 1e3:6.1f} ms (x{tb / tr:4.1f}, {len(lists[0][0])} hits) | threshold, 2 anchors "
              f"{t2 * 1e3:6.1f} ms (x{tb / t2:4.1f}, {100 * frac2:4.1f} %, {miss2} lost) | CPU time threshold "
              f"{cpu['threshold'] * 1e3:.0f} ms, rivals {cpu['rivals'] * 1e3:.0f} ms")
    # reference measured in the same run: the paper's adaptive fuzzy query (5 levels, 6 of 12 upper features free)
    rng = np.random.default_rng(0)
    up = index.sets["upper"]
    ref = []
    for _ in range(200):
        k = int(rng.integers(0, up.n_segments - 5))
        free = rng.choice(up.n_features, 6, replace=False)
        mask = (1 << up.n_features) - 1 - int(sum(1 << int(b) for b in free))
        member = subset_member(up.seg_code[k:k + 5] & mask, mask, up.n_features)
        t1 = time.perf_counter()
        search_set(up, member, "adaptive")
        ref.append(time.perf_counter() - t1)
    print(f"  reference in this run: adaptive fuzzy query (5 levels) median {np.median(ref) * 1e3:.2f} ms "
          f"(docs/relational-features.md: 1.6 ms on an idle machine)")
    print(f"  threshold: median {np.median(times) * 1e3:.1f} ms, max {np.max(times) * 1e3:.1f} ms; rivals: median "
          f"{np.median(riv_t) * 1e3:.1f} ms, max {np.max(riv_t) * 1e3:.1f} ms; baseline median {np.median(base_t) * 1e3:.1f} ms; "
          "coarse rivals median/max wall (CPU): " + ", ".join(
              f"step {k} {np.median(v) * 1e3:.1f}/{np.max(v) * 1e3:.1f} ms ({np.median(coarse_cpu[k]) * 1e3:.0f}/"
              f"{np.max(coarse_cpu[k]) * 1e3:.0f})" for k, v in coarse_t.items()) + "; "
          f"hits lost to the candidate regions: mean {100 * np.mean(lost):.1f} % (target <= 50 ms per query); "
          f"load average {open('/proc/loadavg').read().split()[0]}")
