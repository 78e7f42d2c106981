"""Automatic feature selection for relational queries by example (``matchers.relational`` mode ``auto``).

Müller et al. 2005 leave the choice of features to the user and name learning it as future
work. From the query's own feature matrix (and, where given, a few more examples of the
same motion) :func:`select_features` chooses the features that characterise it:

1. each feature's on/off sequence is cleaned of flicker: runs shorter than ``min_run``
   frames are absorbed by their neighbours (:func:`smooth_runs`), shortest first;
2. features left constant carry no progression and are dropped, as are those with more
   than ``max_runs`` runs (still flickering, or periodic at a rate that varies between
   performers);
3. the remaining features are ranked by how characteristic their "on" phase is for this
   motion: ``score = on-fraction in the query x -log2(on-fraction in the database)``
   (a feature that is on for a large part of the query and rarely on elsewhere scores
   high); with examples, a feature must have the same smoothed run count in all of them;
4. the best ``max_features`` are kept.

Two searches use the selection (``auto_search``):

``dtw`` (default)
    The smoothed query is a motion template of one example (:mod:`.template_model`) on all
    31 features, its mismatches weighted by :func:`surprise_weights` (how rare the
    example's value is in the database), or (first design) on its key features
    (:func:`~.template_model.key_columns`) unweighted, and is retrieved by subsequence DTW;
    with further examples a proper template is fitted (cells where they disagree are don't
    care). A hit is a clip stretch whose cost is below a cut relative to the database's
    per-clip costs (:func:`relative_cost_cut`: a blend of their 5 % quantile and median) or
    below ``max_cost``; a hit's clip must find the query in turn where it is short next to
    the query (:func:`mutual_check`, ``auto_mutual: auto``, default: a cut motion; hits
    inside long takes are not checked) or always (``clip``: databases of cut motions).
``adaptive`` / ``mismatch``
    The smoothed bits of the ``max_features`` best-scoring features (steps 1-4) run
    through the paper's machinery (adaptive fuzzy or m-mismatch hits).

Measured on the HDM05 cuts (docs/templates.md): ``dtw`` mAP 0.91 (all features, surprise
weights; 0.88 for the first design's key features unweighted), ``adaptive`` 0.34. The
match table's ``features`` column names the features used.
"""
from __future__ import annotations

import numpy as np

from mocapflow.framework.errors import DataError


def runs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run-length encoding of a 1-D array: (values, lengths)."""
    x = np.asarray(x)
    if not len(x):
        return x[:0], np.zeros(0, np.int64)
    brk = np.flatnonzero(np.r_[True, x[1:] != x[:-1]])
    return x[brk], np.diff(np.append(brk, len(x)))


def smooth_runs(x: np.ndarray, min_run: int) -> np.ndarray:
    """Boolean sequence with runs shorter than ``min_run`` frames absorbed by their neighbours.

    The shortest run goes first (flipping it merges it with both neighbours); the first and
    last runs of the sequence are kept when shorter (the clip may cut them), unless the whole
    sequence is shorter than ``min_run``.
    """
    vals, lens = runs(np.asarray(x, bool))
    vals, lens = list(vals), list(lens)
    while len(lens) > 2:
        inner = range(1, len(lens) - 1)
        i = min(inner, key=lambda r: lens[r])
        if lens[i] >= min_run:
            break
        merged = lens[i - 1] + lens[i] + lens[i + 1]
        vals[i - 1:i + 2] = [vals[i - 1]]
        lens[i - 1:i + 2] = [merged]
    # an edge run shorter than min_run next to a long run is flicker at the cut: absorb it
    if len(lens) == 2 and min(lens) < min_run:
        keep = int(np.argmax(lens))
        vals, lens = [vals[keep]], [sum(lens)]
    return np.repeat(np.array(vals, bool), lens) if lens else np.zeros(0, bool)


def select_features(bits: np.ndarray, background: np.ndarray, examples: list[np.ndarray] | None = None,
                    min_run: int = 4, max_runs: int = 7, max_features: int = 3,
                    allowed: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features characterising one query (module doc).

    Parameters
    ----------
    bits : ndarray of shape (T, 31), 0/1
        The query frames.
    background : ndarray of shape (31,)
        On-fraction of each feature over the database (frames).
    examples : list of ndarray of shape (T_i, 31), optional
        Further examples of the same motion: a selected feature has the same smoothed run
        count in the query and all of them.
    min_run : int
        Runs shorter than this (frames) are flicker.
    max_runs : int
        Features with more smoothed runs are dropped.
    max_features : int
    allowed : ndarray of int, optional
        Columns that may be chosen (default all 31).

    Returns
    -------
    columns : ndarray of int64, shape (f,)
        Chosen feature columns, by decreasing score.
    smoothed : ndarray of bool, shape (T, 31)
        The query bits with flicker removed (every column).
    scores : ndarray of float64, shape (31,)
        Score per feature (0 for the dropped ones).
    """
    b = np.asarray(bits) > 0.5
    if b.ndim != 2 or b.shape[1] != len(background):
        raise DataError(f"auto feature selection needs (T, {len(background)}) query bits, got {b.shape}")
    sm = np.stack([smooth_runs(b[:, i], min_run) for i in range(b.shape[1])], axis=1) if len(b) else b.copy()
    n_runs = np.array([len(runs(sm[:, i])[1]) for i in range(b.shape[1])])
    ok = (n_runs >= 2) & (n_runs <= max_runs)
    if examples:
        for ex in examples:
            e = np.asarray(ex) > 0.5
            ok &= np.array([len(runs(smooth_runs(e[:, i], min_run))[1]) for i in range(b.shape[1])]) == n_runs
    if allowed is not None:
        mask = np.zeros(b.shape[1], bool)
        mask[np.asarray(allowed, np.int64)] = True
        ok &= mask
    on = sm.mean(axis=0) if len(sm) else np.zeros(b.shape[1])
    bg = np.clip(np.asarray(background, np.float64), 1e-4, 1.0)
    scores = np.where(ok, on * -np.log2(bg), 0.0)
    order = np.argsort(-scores, kind="stable")
    cols = order[: max_features][scores[order[: max_features]] > 0]
    return cols.astype(np.int64), sm, scores


def surprise_weights(quantized: np.ndarray, background: np.ndarray, power: float = 0.5) -> np.ndarray:
    """Per-cell weights (K, 31) of an auto template's local cost: the surprise of the cell's
    value under the database's on-fraction ``p_f`` (``-log2 p_f`` for a 1, ``-log2 (1 - p_f)``
    for a 0), to the power ``power`` (0: unweighted). A mismatch on a cell whose value is rare
    in the database (a hand raised, a foot off the floor) costs more than one on a value most
    frames share, so the template weights its distinctive cells without a feature choice;
    the background needs no labels."""
    p = np.clip(np.asarray(background, np.float64), 1e-3, 1 - 1e-3)
    s = np.where(np.asarray(quantized) >= 0.75, -np.log2(p), -np.log2(1 - p))
    return (s ** power).astype(np.float64) if power else np.ones_like(s)


def auto_template(bits: np.ndarray, background: np.ndarray, examples: list[np.ndarray] | None = None,
                  min_run: int = 4, features: str = "all", weighting: float = 0.5):
    """The motion template of ``auto_search: dtw``: the smoothed query, or (with examples) a
    template fitted on query and examples (don't care where they disagree); on all features
    (``features="all"``, default) or its key features (``"key"``, the first design), its local
    cost weighted by :func:`surprise_weights` to the power ``weighting`` (0: unweighted, the
    first design). Measured leave-one-actor-out in docs/templates.md."""
    from .template_model import MotionTemplate, fit_class_template, key_columns

    sm = np.stack([smooth_runs(np.asarray(x) > 0.5, min_run) for x in np.asarray(bits).T], axis=1)
    if examples:
        exs = [sm.astype(np.float32)] + [np.stack([smooth_runs(np.asarray(c) > 0.5, min_run) for c in np.asarray(e).T], axis=1)
                                         .astype(np.float32) for e in examples]
        t = fit_class_template("query", exs, background, features, calibrate=False)
    else:
        t = MotionTemplate("query", sm.astype(np.float32), np.arange(sm.shape[1]), 0.2, np.inf, 1)
        if features == "key":
            t.columns = key_columns(t, background)
    if weighting:
        t.weights = surprise_weights(t.quantized(), background, weighting)
    return t


def relative_cost_cut(per_clip: np.ndarray, relative_cut: float = 1.15, low_weight: float = 0.75,
                      low_quantile: float = 0.05) -> float:
    """The cost cut of an auto template from the database's per-clip least costs (one
    example gives no calibration, module doc): ``relative_cut x q^w x median^(1 - w)`` with
    ``q`` the ``low_quantile`` of the per-clip costs and ``w = low_weight``; ``w = 0`` is the
    first design (``relative_cut x median``). A geometric blend: the low quantile follows
    how cheaply the best clips match (it moves with the query's length and selectivity),
    the median keeps the cut off zero when a few clips match perfectly."""
    c = np.asarray(per_clip, float)
    c = c[np.isfinite(c)]
    if not len(c):
        return 0.0
    med = float(np.median(c))
    low = float(np.quantile(c, low_quantile))
    return float(relative_cut * low ** low_weight * med ** (1.0 - low_weight))


def auto_hits(template, codes: np.ndarray, offsets: np.ndarray, relative_cut: float = 1.15,
              max_cost: float | None = None, low_weight: float = 0.75,
              low_quantile: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Hits ``(start, end, cost)`` of an auto template and the cost cut used.

    The cut is ``max_cost`` if given, else :func:`relative_cost_cut` of each clip's least
    cost. Measured leave-one-actor-out on the HDM05 cuts (docs/templates.md): the blend
    (``low_weight`` 0.75) brings 6 of 11 classes to P >= 0.7, R >= 0.9 at the cut against
    2 with ``relative_cut`` x the median (``low_weight=0``, ``relative_cut`` 0.6).
    """
    from .template_model import template_costs, template_hits

    cost, start = template_costs(codes, template.table(), np.stack([offsets[:-1], offsets[1:]], axis=1))
    if max_cost is not None:
        cut = float(max_cost)
    else:
        nonempty = offsets[1:] > offsets[:-1]
        per_clip = np.minimum.reduceat(cost, offsets[:-1][nonempty]) if nonempty.any() else np.zeros(0)
        cut = relative_cost_cut(per_clip, relative_cut, low_weight, low_quantile)
    s, e, c = template_hits(cost, start, cut)
    return s, e, c, cut


def reverse_costs(rev_bits: np.ndarray, lo: int, hi: int, query_codes: np.ndarray, codes: np.ndarray,
                  offsets: np.ndarray, background: np.ndarray, min_run: int = 4, features: str = "all",
                  weighting: float = 0.5, max_clips: int | None = 256) -> tuple[float, np.ndarray]:
    """The reverse query of the mutual check: ``rev_bits`` (a hit's clip or a window of it,
    database frames ``[lo, hi)``) made an auto template. Returns the query's least cost under
    it and the least cost per database range: every other clip, and the rest of the clip
    holding ``[lo, hi)`` on either side (a long take stays searchable; paths never cross the
    cut). Only the cut's quantiles of these costs are used, so with more than ``max_clips``
    other clips a fixed random sample of ``max_clips`` of them (seed 0) stands for the
    database: each reverse search then costs about max_clips clips, not the whole database
    (None: every clip)."""
    from .template_model import template_costs

    t = auto_template(rev_bits, background, None, min_run, features, weighting)
    table = t.table()
    h = int(np.searchsorted(offsets, lo, side="right") - 1)  # the clip holding the reverse frames
    others = np.delete(np.arange(len(offsets) - 1), h)
    if max_clips is not None and len(others) > max_clips:
        others = np.sort(np.random.default_rng(0).choice(others, max_clips, replace=False))
    ranges = np.concatenate([np.stack([offsets[others], offsets[others + 1]], axis=1),
                             [[offsets[h], lo], [hi, offsets[h + 1]]]]).astype(np.int64)
    ranges = ranges[ranges[:, 1] > ranges[:, 0]]
    ranges = ranges[np.argsort(ranges[:, 0], kind="stable")]
    per_range = np.zeros(0)
    if len(ranges):
        cost, _ = template_costs(codes, table, ranges)
        # cost is inf outside the ranges, so the minimum from one range's start to the next one's is the range's
        per_range = np.minimum.reduceat(cost, ranges[:, 0])
    own, _ = template_costs(query_codes, table, np.array([[0, len(query_codes)]], np.int64))
    return float(own.min()) if len(own) else float("inf"), per_range


def _reverse_finds_query(rev_bits, lo, hi, q_codes, codes, offsets, background, min_run, features, weighting,
                         relative_cut, low_weight, max_clips=256) -> bool:
    """Whether the reverse query (:func:`reverse_costs`) finds the query: its least cost <=
    the :func:`relative_cost_cut` of the per-range costs."""
    own, per_range = reverse_costs(rev_bits, lo, hi, q_codes, codes, offsets, background, min_run, features, weighting,
                                   max_clips)
    return bool(np.isfinite(own) and own <= relative_cost_cut(per_range, relative_cut, low_weight))


def mutual_clips(query_bits: np.ndarray, hit_clips: np.ndarray, db_bits: np.ndarray, codes: np.ndarray,
                 offsets: np.ndarray, background: np.ndarray, min_run: int = 4, features: str = "all",
                 weighting: float = 0.5, relative_cut: float = 1.15, low_weight: float = 0.75) -> np.ndarray:
    """The mutual check of ``auto_mutual: clip`` (bool per entry of ``hit_clips``): the hit's
    whole clip, made an auto template in turn, must find the query among its own hits (the
    query's least cost <= the :func:`relative_cost_cut` of that template's per-clip least
    costs over the database, the hit clip itself left out). A short query (one hop) matches
    a stretch inside a longer motion (a jog); the jog clip as a query does not match the hop.
    Only for databases of cut motions (one motion per clip): a long take as a query matches
    almost nothing (:func:`mutual_check` with ``mode="auto"`` is the safe default). Needs no
    labels; costs one search of the database per distinct hit clip.

    ``query_bits`` (T, 31); ``hit_clips`` (h,) clip positions; ``db_bits`` (N, 31), ``codes``
    (N,) and ``offsets`` (n_clips + 1,) the database.
    """
    from .template_model import frame_codes

    q_codes = frame_codes(np.asarray(query_bits) > 0.5)
    return np.array([_reverse_finds_query(db_bits[offsets[h]:offsets[h + 1]], int(offsets[h]), int(offsets[h + 1]), q_codes,
                                          codes, offsets, background, min_run, features, weighting, relative_cut, low_weight)
                     for h in np.asarray(hit_clips, np.int64)], bool)


def mutual_check(query_bits: np.ndarray, hit_start: np.ndarray, hit_end: np.ndarray, db_bits: np.ndarray,
                 codes: np.ndarray, offsets: np.ndarray, background: np.ndarray, mode: str = "auto",
                 ratio: float = 3.0, window: float | None = None, min_run: int = 4, features: str = "all",
                 weighting: float = 0.5, relative_cut: float = 1.3, low_weight: float = 0.75,
                 max_clips: int | None = 256) -> tuple[np.ndarray, np.ndarray]:
    """The reverse check of ``auto_mutual`` per hit: ``(keep, checked)``, bool of shape (h,).

    ``mode="clip"``: every hit's whole clip is the reverse query (:func:`mutual_clips`).
    ``mode="auto"`` (default): only where the hit's clip is short next to the query (at most
    ``ratio`` x the query's T frames: a cut motion, whose one motion the whole clip is);
    in a longer clip (a long take holding many motions, where the whole clip as a query
    would find almost nothing) the hit is not checked (``window`` None, default) or the
    reverse query is a window of ``T x (1 + window)`` frames centred on the hit, inside its
    clip (the window's frames left out of the reverse search, the rest of the take kept). Unchecked hits are kept (``checked`` False: the matcher applies the plain cut to
    them). ``hit_start``/``hit_end`` are global frames (end exclusive); other arguments as
    :func:`mutual_clips`; ``max_clips``: :func:`reverse_costs`. ``ratio`` was chosen
    leave-one-actor-out (docs/templates.md).
    """
    from .template_model import frame_codes

    if mode not in ("clip", "auto"):
        raise DataError(f"auto_mutual must be clip or auto here, got {mode!r}")
    s, e = np.asarray(hit_start, np.int64), np.asarray(hit_end, np.int64)
    clip = np.searchsorted(offsets, s, side="right") - 1
    n_q = len(query_bits)
    q_codes = frame_codes(np.asarray(query_bits) > 0.5)
    keep, checked = np.ones(len(s), bool), np.zeros(len(s), bool)
    whole: dict[int, bool] = {}  # one reverse search per distinct short clip
    args = (q_codes, codes, offsets, background, min_run, features, weighting, relative_cut, low_weight, max_clips)
    for i, (a, b, h) in enumerate(zip(s, e, clip)):
        lo, hi = int(offsets[h]), int(offsets[h + 1])
        if mode == "clip" or hi - lo <= ratio * n_q:
            if h not in whole:
                whole[h] = _reverse_finds_query(db_bits[lo:hi], lo, hi, *args)
            keep[i], checked[i] = whole[h], True
        elif window is not None:
            width = max(int(round(n_q * (1.0 + window))), int(b - a))
            wlo = int(np.clip((a + b) // 2 - width // 2, lo, max(lo, hi - width)))
            whi = min(hi, wlo + width)
            keep[i] = _reverse_finds_query(db_bits[wlo:whi], wlo, whi, *args)
            checked[i] = True
    return keep, checked


def auto_dtw_hits(template, query_bits: np.ndarray, db_bits: np.ndarray, codes: np.ndarray, offsets: np.ndarray,
                  background: np.ndarray, mutual: str = "auto", relative_cut: float | None = None,
                  max_cost: float | None = None, low_weight: float = 0.75, ratio: float = 3.0,
                  window: float | None = None, min_run: int = 4, features: str = "all",
                  weighting: float = 0.5, max_clips: int | None = 256) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hits ``(start, end, cost)`` of ``auto_search: dtw`` with the mutual check (the matcher's
    code path): :func:`auto_hits` at the checked cut (``relative_cut``, default 1.3 with a
    check, 1.15 with ``mutual="off"``), :func:`mutual_check` (``mutual`` auto or clip), and
    for hits left unchecked (long clips under ``auto`` without ``window``) the plain cut
    (``relative_cut``, default 1.15; with ``max_cost`` the same fixed cut)."""
    plain = relative_cut or 1.15
    checked_cut = relative_cut or (1.3 if mutual != "off" else 1.15)  # a checked hit may cost more
    s, e, c, cut = auto_hits(template, codes, offsets, checked_cut, max_cost, low_weight)
    if mutual == "off" or not len(s):
        return s, e, c
    keep, checked = mutual_check(query_bits, s, e, db_bits, codes, offsets, background, mutual, ratio, window,
                                 min_run, features, weighting, checked_cut, low_weight, max_clips)
    keep &= checked | (c <= (cut if max_cost is not None else cut * plain / checked_cut))
    return s[keep], e[keep], c[keep]


__all__ = ["auto_dtw_hits", "auto_hits", "mutual_check", "mutual_clips", "auto_template", "relative_cost_cut", "reverse_costs", "runs", "select_features", "smooth_runs", "surprise_weights"]
