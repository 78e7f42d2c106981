"""Mode ``auto`` of ``matchers.relational``: a query by example without a feature list.

Müller et al. 2005 leave the choice of features to the user and name learning it as future
work. Here the example itself becomes a motion template (:mod:`.template_model`):

1. each feature's on/off sequence is cleaned of flicker: runs shorter than :data:`MIN_RUN`
   frames are absorbed by their neighbours (:func:`smooth_runs`), shortest first;
2. the smoothed query is a template of one example on all 31 features (with further
   examples a fitted template, don't care where they disagree), each cell's mismatch
   weighted by :func:`surprise_weights` (how rare the example's value is in the database);
3. it is retrieved by subsequence DTW; a hit is a clip stretch whose cost is below a cut
   relative to the database's per-clip least costs (:func:`relative_cost_cut`);
4. the mutual check (``auto_mutual``): a hit's clip, made a query in turn, must find the
   example (:func:`mutual_check`); ``auto`` checks only clips at most ``mutual_ratio`` x the
   query long (cut motions), ``clip`` every hit (databases of cuts), ``off`` none.

Measured on the HDM05 cuts, one actor's cut as the query and the other actors' cuts as the
database (docs/templates.md): mAP 0.896 against 0.865 for the numeric default search on the
same queries, 7 of 11 classes at P >= 0.8, R >= 0.9 on the reported hits; 0.34-0.49 mAP for
the paper's adaptive and m-mismatch hits on features chosen from the example.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from mocapflow.framework.errors import DataError

if TYPE_CHECKING:  # pragma: no cover
    from .template_model import MotionTemplate

#: Runs shorter than this (frames) are flicker.
MIN_RUN = 4
#: Power of the surprise weights (0: unweighted, the first design).
WEIGHTING = 0.5
#: Weight of the low quantile in the relative cut (0: relative_cut x the median).
LOW_WEIGHT, LOW_QUANTILE = 0.75, 0.05
#: Default relative cut of unchecked and of mutually checked hits.
PLAIN_CUT, CHECKED_CUT = 1.15, 1.3
#: The reverse search of the mutual check covers a fixed random sample of this many clips.
MUTUAL_SAMPLE = 256


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
    run_vals, run_lens = runs(np.asarray(x, bool))
    vals, lens = list(run_vals), list(run_lens)
    while len(lens) > 2:
        inner = range(1, len(lens) - 1)
        i = min(inner, key=lambda r: lens[r])
        if lens[i] >= min_run:
            break
        merged = lens[i - 1] + lens[i] + lens[i + 1]
        vals[i - 1 : i + 2] = [vals[i - 1]]
        lens[i - 1 : i + 2] = [merged]
    # an edge run shorter than min_run next to a long run is flicker at the cut: absorb it
    if len(lens) == 2 and min(lens) < min_run:
        keep = int(np.argmax(lens))
        vals, lens = [vals[keep]], [sum(lens)]
    return np.repeat(np.array(vals, bool), lens) if lens else np.zeros(0, bool)


def surprise_weights(quantized: np.ndarray, background: np.ndarray, power: float = 0.5) -> np.ndarray:
    """Per-cell weights (K, 31) of an auto template's local cost: the surprise of the cell's
    value under the database's on-fraction ``p_f`` (``-log2 p_f`` for a 1, ``-log2 (1 - p_f)``
    for a 0), to the power ``power`` (0: unweighted). A mismatch on a cell whose value is rare
    in the database (a hand raised, a foot off the floor) costs more than one on a value most
    frames share, so the template weights its distinctive cells without a feature choice;
    the background needs no labels."""
    p = np.clip(np.asarray(background, np.float64), 1e-3, 1 - 1e-3)
    s = np.where(np.asarray(quantized) >= 0.75, -np.log2(p), -np.log2(1 - p))
    return (s**power).astype(np.float64) if power else np.ones_like(s)


def auto_template(
    bits: np.ndarray,
    background: np.ndarray,
    examples: list[np.ndarray] | None = None,
    min_run: int = MIN_RUN,
    weighting: float = WEIGHTING,
) -> MotionTemplate:
    """The smoothed query as a motion template on all 31 features, or (with examples) a
    template fitted on query and examples (don't care where they disagree), its local cost
    weighted by :func:`surprise_weights` to the power ``weighting``."""
    from .template_model import MotionTemplate, fit_class_template

    def smooth(x: np.ndarray) -> np.ndarray:
        return np.stack([smooth_runs(np.asarray(c) > 0.5, min_run) for c in np.asarray(x).T], axis=1)

    sm = smooth(bits)
    if examples:
        exs = [sm.astype(np.float32)] + [smooth(e).astype(np.float32) for e in examples]
        t = fit_class_template("query", exs, background, "all", calibrate=False)
    else:
        t = MotionTemplate("query", sm.astype(np.float32), np.arange(sm.shape[1]), 0.2, np.inf, 1)
    if weighting:
        t.weights = surprise_weights(t.quantized(), background, weighting)
    return t


def relative_cost_cut(per_clip: np.ndarray, relative_cut: float = PLAIN_CUT) -> float:
    """The cost cut of an auto template from the database's per-clip least costs (one
    example gives no calibration): ``relative_cut x q^w x median^(1 - w)`` with ``q`` the 5 %
    quantile of the finite per-clip costs and ``w`` :data:`LOW_WEIGHT`. A geometric blend:
    the low quantile follows how cheaply the best clips match (it moves with the query's
    length and selectivity), the median keeps the cut off zero when a few clips match
    perfectly."""
    c = np.asarray(per_clip, float)
    c = c[np.isfinite(c)]
    if not len(c):
        return 0.0
    med = float(np.median(c))
    low = float(np.quantile(c, LOW_QUANTILE))
    return float(relative_cut * low**LOW_WEIGHT * med ** (1.0 - LOW_WEIGHT))


def auto_hits(
    template: MotionTemplate, codes: np.ndarray, offsets: np.ndarray, relative_cut: float = PLAIN_CUT
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Hits ``(start, end, cost)`` of an auto template below :func:`relative_cost_cut` of
    each clip's least cost, and that cut."""
    from .template_model import template_costs, template_hits

    cost, start = template_costs(codes, template.table(), np.stack([offsets[:-1], offsets[1:]], axis=1))
    nonempty = offsets[1:] > offsets[:-1]
    per_clip = np.minimum.reduceat(cost, offsets[:-1][nonempty]) if nonempty.any() else np.zeros(0)
    cut = relative_cost_cut(per_clip, relative_cut)
    s, e, c = template_hits(cost, start, cut)
    return s, e, c, cut


def reverse_costs(
    rev_bits: np.ndarray,
    lo: int,
    hi: int,
    query_codes: np.ndarray,
    codes: np.ndarray,
    offsets: np.ndarray,
    background: np.ndarray,
    max_clips: int | None = MUTUAL_SAMPLE,
) -> tuple[float, np.ndarray]:
    """The reverse query of the mutual check: ``rev_bits`` (a hit's clip or a window of it,
    database frames ``[lo, hi)``) made an auto template. Returns the query's least cost under
    it and the least cost per database range: every other clip, and the rest of the clip
    holding ``[lo, hi)`` on either side (a long take stays searchable; paths never cross the
    cut). Only the cut's quantiles of these costs are used, so with more than ``max_clips``
    other clips a fixed random sample of ``max_clips`` of them (seed 0) stands for the
    database: each reverse search then costs about max_clips clips, not the whole database
    (None: every clip)."""
    from .template_model import template_costs

    table = auto_template(rev_bits, background).table()
    h = int(np.searchsorted(offsets, lo, side="right") - 1)  # the clip holding the reverse frames
    others = np.delete(np.arange(len(offsets) - 1), h)
    if max_clips is not None and len(others) > max_clips:
        others = np.sort(np.random.default_rng(0).choice(others, max_clips, replace=False))
    ranges = np.concatenate(
        [np.stack([offsets[others], offsets[others + 1]], axis=1), [[offsets[h], lo], [hi, offsets[h + 1]]]]
    ).astype(np.int64)
    ranges = ranges[ranges[:, 1] > ranges[:, 0]]
    ranges = ranges[np.argsort(ranges[:, 0], kind="stable")]
    per_range = np.zeros(0)
    if len(ranges):
        cost, _ = template_costs(codes, table, ranges)
        # cost is inf outside the ranges, so the minimum from one range's start to the next one's is the range's
        per_range = np.minimum.reduceat(cost, ranges[:, 0])
    own, _ = template_costs(query_codes, table, np.array([[0, len(query_codes)]], np.int64))
    return float(own.min()) if len(own) else float("inf"), per_range


def _reverse_finds_query(
    rev_bits: np.ndarray,
    lo: int,
    hi: int,
    q_codes: np.ndarray,
    codes: np.ndarray,
    offsets: np.ndarray,
    background: np.ndarray,
    relative_cut: float,
    max_clips: int | None,
) -> bool:
    """Whether the reverse query (:func:`reverse_costs`) finds the query: its least cost <=
    the :func:`relative_cost_cut` of the per-range costs."""
    own, per_range = reverse_costs(rev_bits, lo, hi, q_codes, codes, offsets, background, max_clips)
    return bool(np.isfinite(own) and own <= relative_cost_cut(per_range, relative_cut))


def mutual_check(
    query_bits: np.ndarray,
    hit_start: np.ndarray,
    hit_end: np.ndarray,
    db_bits: np.ndarray,
    codes: np.ndarray,
    offsets: np.ndarray,
    background: np.ndarray,
    mode: str = "auto",
    ratio: float = 3.0,
    relative_cut: float = CHECKED_CUT,
    max_clips: int | None = MUTUAL_SAMPLE,
) -> tuple[np.ndarray, np.ndarray]:
    """The reverse check of ``auto_mutual`` per hit: ``(keep, checked)``, bool of shape (h,).

    The hit's whole clip, made an auto template in turn, must find the query (its least cost
    <= the :func:`relative_cost_cut` of that template's per-clip costs, the hit clip left
    out): a short query (one hop) matches a stretch inside a longer motion (a jog), but the
    jog clip as a query does not match the hop. ``mode="clip"``: every hit is checked (for
    databases of cut motions: a long take as a query matches almost nothing).
    ``mode="auto"``: only hits whose clip is at most ``ratio`` x the query's frames (a cut
    motion); hits in longer clips are kept unchecked (``checked`` False: the matcher applies
    the plain cut to them). ``hit_start``/``hit_end`` are global frames (end exclusive);
    ``db_bits`` (N, 31), ``codes`` (N,) and ``offsets`` (n_clips + 1,) the database;
    ``max_clips``: :func:`reverse_costs`.
    """
    from .template_model import frame_codes

    if mode not in ("clip", "auto"):
        raise DataError(f"auto_mutual must be clip or auto here, got {mode!r}")
    s = np.asarray(hit_start, np.int64)
    clip = np.searchsorted(offsets, s, side="right") - 1
    n_q = len(query_bits)
    q_codes = frame_codes(np.asarray(query_bits) > 0.5)
    keep, checked = np.ones(len(s), bool), np.zeros(len(s), bool)
    whole: dict[int, bool] = {}  # one reverse search per distinct clip
    for i, h in enumerate(clip):
        lo, hi = int(offsets[h]), int(offsets[h + 1])
        if mode == "clip" or hi - lo <= ratio * n_q:
            if h not in whole:
                whole[h] = _reverse_finds_query(
                    db_bits[lo:hi], lo, hi, q_codes, codes, offsets, background, relative_cut, max_clips
                )
            keep[i], checked[i] = whole[h], True
    return keep, checked


def fusion_mask(hit_clips: np.ndarray, numeric_clip_costs: np.ndarray, fusion: float | None) -> np.ndarray:
    """Relational + numeric fusion of mode auto (``fusion`` of ``matchers.relational``): a hit
    is kept when the numeric search's cost of its clip (``numeric_clip_costs`` per clip,
    inf: no match) is at most ``fusion`` x :func:`relative_cost_cut` of those costs (the auto
    cut's blend, relative cut 1). None: every hit kept."""
    hit_clips = np.asarray(hit_clips, np.int64)
    if fusion is None or not len(hit_clips):
        return np.ones(len(hit_clips), bool)
    cut = relative_cost_cut(np.asarray(numeric_clip_costs, np.float64), float(fusion))
    return cast("np.ndarray", np.asarray(numeric_clip_costs, np.float64)[hit_clips] <= cut)


def auto_dtw_hits(
    template: MotionTemplate,
    query_bits: np.ndarray,
    db_bits: np.ndarray,
    codes: np.ndarray,
    offsets: np.ndarray,
    background: np.ndarray,
    mutual: str = "auto",
    relative_cut: float | None = None,
    ratio: float = 3.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hits ``(start, end, cost)`` of mode auto with the mutual check (the matcher's code
    path): :func:`auto_hits` at the checked cut (``relative_cut``, default 1.3 with a check,
    1.15 with ``mutual="off"``), :func:`mutual_check` (``mutual`` auto or clip), and for
    hits left unchecked (long clips under ``auto``) the plain cut (``relative_cut``, default
    1.15)."""
    plain = relative_cut or PLAIN_CUT
    checked_cut = relative_cut or (CHECKED_CUT if mutual != "off" else PLAIN_CUT)  # a checked hit may cost more
    s, e, c, cut = auto_hits(template, codes, offsets, checked_cut)
    if mutual == "off" or not len(s):
        return s, e, c
    keep, checked = mutual_check(query_bits, s, e, db_bits, codes, offsets, background, mutual, ratio, checked_cut)
    keep &= checked | (c <= cut * plain / checked_cut)
    return s[keep], e[keep], c[keep]
