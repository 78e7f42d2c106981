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
    below ``max_cost``; optionally the hit's clip must find the query in turn
    (:func:`mutual_clips`, databases of cut motions).
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


def mutual_clips(query_bits: np.ndarray, hit_clips: np.ndarray, db_bits: np.ndarray, codes: np.ndarray,
                 offsets: np.ndarray, background: np.ndarray, min_run: int = 4, features: str = "all",
                 weighting: float = 0.5, relative_cut: float = 1.15, low_weight: float = 0.75) -> np.ndarray:
    """The mutual check of ``auto_mutual: clip`` (bool per entry of ``hit_clips``): the hit's
    whole clip, made an auto template in turn, must find the query among its own hits (the
    query's least cost <= the :func:`relative_cost_cut` of that template's per-clip least
    costs over the database, the hit clip itself left out). A short query (one hop) matches
    a stretch inside a longer motion (a jog); the jog clip as a query does not match the hop.
    Only for databases of cut motions (one motion per clip): a long take as a query matches
    almost nothing. Needs no labels; costs one search of the database per distinct hit clip.

    ``query_bits`` (T, 31); ``hit_clips`` (h,) clip positions; ``db_bits`` (N, 31), ``codes``
    (N,) and ``offsets`` (n_clips + 1,) the database.
    """
    from .template_model import clip_min_costs, frame_codes

    q_codes = frame_codes(np.asarray(query_bits) > 0.5)
    q_off = np.array([0, len(q_codes)], np.int64)
    keep = np.zeros(len(hit_clips), bool)
    for i, h in enumerate(np.asarray(hit_clips, np.int64)):
        t = auto_template(db_bits[offsets[h]:offsets[h + 1]], background, None, min_run, features, weighting)
        per_clip = clip_min_costs(codes, offsets, t.table())
        per_clip[h] = np.inf
        own = clip_min_costs(q_codes, q_off, t.table())[0]
        keep[i] = bool(np.isfinite(own) and own <= relative_cost_cut(per_clip, relative_cut, low_weight))
    return keep


__all__ = ["auto_hits", "mutual_clips", "auto_template", "relative_cost_cut", "runs", "select_features", "smooth_runs", "surprise_weights"]
