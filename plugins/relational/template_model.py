"""Motion templates (Müller & Röder 2006): learning, storage and template search.

A motion template of a class is a real-valued matrix ``(K, 31)`` in [0, 1]: template frame
``k`` and relational feature ``i`` hold the fraction of the class examples whose feature
``i`` is on at the time that corresponds to ``k`` after DTW alignment. Cells where the
examples disagree (``delta < value < 1 - delta``) are *don't care*: the quantised template
``(K, 31)`` holds 0, 1 or 0.5 (don't care), and the local cost of retrieval ignores them.

Learning (:func:`fit_template`): the medoid example (least total DTW cost to the others)
is the time axis; every example is aligned to the current template by DTW (local cost mean
|difference| over the features) and averaged onto it (the frames an example maps onto one
template frame are averaged first); ``iterations`` rounds re-align to the averaged
template. Müller & Röder average reference-free (pairwise merging and unwarping to a mean
length); the medoid axis is a simplification that keeps the template as long as a typical
example and costs ``n`` alignments per round.

Retrieval (:func:`template_costs`, :func:`template_hits`): subsequence DTW of the quantised
template against the database frames (``_template_kernels``), local cost = mean over the
cared-for features of a template frame of |template - bit|; a hit is a local minimum of
the end-frame cost below the template's threshold, overlapping hits suppressed greedily.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from mocapflow.framework.errors import DataError

MODEL_FILE = "templates.npz"


@dataclass
class MotionTemplate:
    """One class template: ``mean`` (K, 31) float32 averaged feature values in [0, 1];
    ``columns`` (f,) the feature columns used (the others don't care everywhere); values in
    ``(delta, 1 - delta)`` are don't care; a hit has mean local cost <= ``threshold``;
    ``example_costs`` (n_examples,) are the leave-one-out costs that calibrated it."""

    label: str
    mean: np.ndarray
    columns: np.ndarray
    delta: float
    threshold: float
    n_examples: int
    example_costs: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: optional per-cell weights (K, 31) of the local cost (mode auto's surprise weights,
    #: :func:`.auto.surprise_weights`); None: every cared-for cell counts 1. Not stored by
    #: :func:`save_templates` (class templates are unweighted).
    weights: np.ndarray | None = None
    #: :func:`.template_coarse.coarse_template`'s cache: (key, the coarse template)
    _coarse: tuple[Any, ...] | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def n_frames(self) -> int:
        return int(self.mean.shape[0])

    def quantized(self) -> np.ndarray:
        """Quantised template (K, 31): 0, 1, or 0.5 for don't care (and for unused features)."""
        q = np.full(self.mean.shape, 0.5, np.float32)
        used = np.zeros(self.mean.shape[1], bool)
        used[self.columns] = True
        m = self.mean
        q[:, used] = np.where(m[:, used] <= self.delta, 0.0, np.where(m[:, used] >= 1 - self.delta, 1.0, 0.5))
        return q

    def dont_care_fraction(self) -> float:
        q = self.quantized()[:, self.columns]
        return float((q == 0.5).mean()) if q.size else 1.0

    def table(self) -> np.ndarray:
        """Per-part local-cost lookup table (6400, K) float32 for the search kernel (cached
        for the current columns and delta)."""
        key = (self.columns.tobytes(), self.delta, self.mean.shape, None if self.weights is None else id(self.weights))
        cached = getattr(self, "_table", None)
        if cached is None or cached[0] != key:
            cached = (key, cost_table(self.quantized(), self.weights))
            self._table = cached
        return cached[1]


def cost_table(q: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Lookup table of a quantised template ``q (K, 31)`` (0, 1, 0.5 = don't care).

    Row ``offset_p + c`` holds, per template frame, the cost contribution of code ``c`` of
    part ``p`` (lower bits 0-10, upper 11-22, mixed 23-30): the number of cared-for bits of
    the part that differ from the template, divided by the number of cared-for features
    of the frame (all parts); a frame with none costs 0. With ``weights`` (K, 31) >= 0 the
    counts are weighted sums (a mismatch of cell (k, f) costs ``weights[k, f]``, divided by
    the frame's total cared-for weight), still a mean in [0, 1].
    """
    from ._template_kernels import PART_OFFSETS, TABLE_ROWS

    q = np.asarray(q, np.float64)
    care = (q != 0.5).astype(np.float64)
    if weights is not None:
        care = care * np.asarray(weights, np.float64)
    n = np.where(care.sum(axis=1) > 0, care.sum(axis=1), 1.0)
    table = np.zeros((TABLE_ROWS, len(q)), np.float64)
    for off, (lo, hi) in zip(PART_OFFSETS, ((0, 11), (11, 23), (23, 31)), strict=True):
        width = hi - lo
        codes = np.arange(1 << width)
        bits = ((codes[:, None] >> np.arange(width)[None, :]) & 1).astype(np.float64)  # (C, width)
        # |bit - q| on a cared cell is q + bit (1 - 2q) for q in {0, 1}: one matrix product per part
        c, w = care[:, lo:hi], (care * (1 - 2 * q))[:, lo:hi]
        table[off : off + len(codes)] = ((c * q[:, lo:hi]).sum(axis=1)[None, :] + bits @ w.T) / n[None, :]
    return table.astype(np.float32)


def frame_codes(bits: np.ndarray) -> np.ndarray:
    """31-bit code per frame (bit i = column i) of a (T, 31) 0/1 matrix, int64."""
    b = np.asarray(bits) > 0.5
    return cast("np.ndarray", (b.astype(np.int64) << np.arange(b.shape[1], dtype=np.int64)).sum(axis=1))


def align_average(template: np.ndarray, example: np.ndarray) -> tuple[np.ndarray, float]:
    """The example warped onto the template's time axis (frames mapped to one template
    frame averaged) and the DTW cost per template frame."""
    from ._template_kernels import dtw_path

    cost, path = dtw_path(np.ascontiguousarray(template, np.float64), np.ascontiguousarray(example, np.float64))
    k = len(template)
    sums = np.zeros((k, example.shape[1]))
    np.add.at(sums, path[:, 0], example[path[:, 1]])
    counts = np.bincount(path[:, 0], minlength=k)
    return sums / counts[:, None], float(cost) / k


def pairwise_costs(examples: list[np.ndarray], columns: np.ndarray) -> np.ndarray:
    """DTW cost per path step between every two examples, (n, n) symmetric, zero diagonal."""
    from ._template_kernels import dtw_path

    n = len(examples)
    pair = np.zeros((n, n))
    for a in range(n):
        for b in range(a + 1, n):
            c, p = dtw_path(
                np.ascontiguousarray(examples[a][:, columns], np.float64),
                np.ascontiguousarray(examples[b][:, columns], np.float64),
            )
            pair[a, b] = pair[b, a] = c / len(p)
    return pair


def fit_template(
    label: str,
    examples: list[np.ndarray],
    columns: np.ndarray | None = None,
    delta: float = 0.2,
    iterations: int = 2,
    pair: np.ndarray | None = None,
) -> MotionTemplate:
    """Learn one class template from its examples' 0/1 feature matrices (T_i, 31), each of
    at least 2 frames: ``columns`` used (default all 31), ``iterations`` re-alignment rounds
    after the first average, ``pair`` their :func:`pairwise_costs` (computed when omitted)."""
    if not examples:
        raise DataError(f"template {label!r}: no examples")
    xs = [np.asarray(x, np.float64) for x in examples]
    if any(len(x) < 2 for x in xs):
        raise DataError(f"template {label!r}: every example needs at least 2 frames")
    cols = np.arange(xs[0].shape[1]) if columns is None else np.asarray(columns, np.int64)
    if len(xs) > 1:
        pair = pairwise_costs(xs, cols) if pair is None else pair
        ref = int(np.argmin(pair.sum(axis=1)))
    else:
        ref = 0
    tmpl = xs[ref].copy()
    for _ in range(max(iterations, 0) + 1):
        warped = [align_average(tmpl[:, cols], x[:, cols])[0] for x in xs]
        new = np.zeros_like(tmpl)
        new[:, cols] = np.mean(warped, axis=0)
        tmpl = new
    return MotionTemplate(label, tmpl.astype(np.float32), cols, float(delta), np.inf, len(xs))


def template_costs(codes: np.ndarray, table: np.ndarray, ranges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Subsequence DTW of a template (``table`` (6400, K), :func:`cost_table`) over the
    database's :func:`frame_codes` (N,) within frame ``ranges`` (R, 2) ``[lo, hi)``, each inside
    one clip. Returns the mean local cost of the best path ending at each frame (N,) float64
    (inf outside the ranges) and its start frame (N,) int64."""
    from ._template_kernels import template_sdtw

    cost = np.full(len(codes), np.inf)
    start = np.full(len(codes), -1, np.int64)
    r = np.asarray(ranges, np.int64).reshape(-1, 2)
    if len(r) and table.shape[1]:
        template_sdtw(
            np.ascontiguousarray(codes, np.int64),
            np.ascontiguousarray(table),
            np.ascontiguousarray(r[:, 0]),
            np.ascontiguousarray(r[:, 1]),
            cost,
            start,
        )
    return cost, start


def search_costs(
    codes: np.ndarray,
    table: np.ndarray,
    ranges: np.ndarray,
    threshold: float,
    min_gap: float = 0.5,
    abandon: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hits of one template over frame ranges in two passes: end-frame costs only
    (``sdtw_cost``, abandoning cells above ``threshold`` when ``abandon``), then the merged
    windows around candidate ends again with path starts.

    Returns ``(start, end, cost)`` as :func:`template_hits` and the cost array (N,; with
    ``abandon`` exact where ``<= threshold``, inf or exact elsewhere). The hits equal those
    of :func:`template_costs` + :func:`template_hits` except that a range boundary counts as
    an inf neighbour (a start may differ only between equal-cost paths).
    """
    from ._template_kernels import sdtw_cost, template_sdtw

    n = len(codes)
    cost = np.full(n, np.inf)
    r = np.asarray(ranges, np.int64).reshape(-1, 2)
    if len(r) and table.shape[1]:
        sdtw_cost(
            np.ascontiguousarray(codes, np.int64),
            np.ascontiguousarray(table),
            np.ascontiguousarray(r[:, 0]),
            np.ascontiguousarray(r[:, 1]),
            cost,
            np.full(len(r), float(threshold) if abandon else np.inf),
        )
    from ._hit_kernels import greedy_hits, range_minima

    if not 0.0 <= min_gap < 1.0:
        raise DataError(f"min_gap must be in [0, 1), got {min_gap}")
    order = np.argsort(r[:, 0], kind="stable")
    r = r[order]
    cand = range_minima(cost, np.ascontiguousarray(r[:, 0]), np.ascontiguousarray(r[:, 1]), float(threshold))
    full_start = np.zeros(n, np.int64)
    if len(cand):
        # windows [end - 2K + 1, end] (inside the candidate's range) hold every path ending at a
        # candidate; overlapping windows are merged and searched again, with path starts
        which = np.searchsorted(r[:, 0], cand, side="right") - 1
        lo = np.maximum(r[which, 0], cand - 2 * table.shape[1] + 1)
        hi = cand + 1
        new = np.r_[True, (lo[1:] > hi[:-1]) | (which[1:] != which[:-1])]
        first = np.flatnonzero(new)
        wlo = np.ascontiguousarray(lo[first])
        whi = np.ascontiguousarray(np.maximum.reduceat(hi, first))
        scratch_cost = np.empty(n)
        scratch_start = np.empty(n, np.int64)
        # no abandoning here: the windows hold the candidates' paths, where most cells are live
        # (measured: the bounded kernel's bookkeeping costs more than it saves for 2 of 4 templates)
        template_sdtw(
            np.ascontiguousarray(codes, np.int64), np.ascontiguousarray(table), wlo, whi, scratch_cost, scratch_start
        )
        full_start[cand] = scratch_start[cand]
    ends = greedy_hits(cand, cost, full_start, float(min_gap), n)
    return full_start[ends], ends + 1, cost[ends], cost


def template_hits(
    cost: np.ndarray, start: np.ndarray, threshold: float, min_gap: float = 0.5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Hits from end-frame costs: local minima with cost <= threshold, greedy suppression.

    A candidate is dropped when it overlaps an accepted (cheaper) hit by more than
    ``min_gap`` (< 1) of the shorter span. Returns ``(start, end exclusive, cost)`` global
    frames, by ascending cost (compiled: ``_template_kernels.select_hits``).
    """
    from ._hit_kernels import select_hits

    if not 0.0 <= min_gap < 1.0:
        raise DataError(f"min_gap must be in [0, 1), got {min_gap}")
    c = np.ascontiguousarray(cost, np.float64)
    ends = (
        select_hits(c, np.ascontiguousarray(start, np.int64), float(threshold), float(min_gap))
        if len(c)
        else np.zeros(0, np.int64)
    )
    return np.asarray(start)[ends].astype(np.int64), ends + 1, c[ends]


def save_templates(templates: list[MotionTemplate], directory: Path, meta: dict[str, Any] | None = None) -> None:
    """Write the templates to ``directory / templates.npz`` (one archive, JSON header)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, Any] = {}
    templates_json: list[dict[str, Any]] = []
    header = {"meta": meta or {}, "templates": templates_json}
    for i, t in enumerate(templates):
        arrays[f"mean_{i}"] = t.mean
        arrays[f"columns_{i}"] = t.columns
        arrays[f"costs_{i}"] = t.example_costs
        templates_json.append(
            {"label": t.label, "delta": t.delta, "threshold": t.threshold, "n_examples": t.n_examples}
        )
    np.savez(d / MODEL_FILE, header=np.array(json.dumps(header)), **arrays)


def load_templates(directory: Path) -> tuple[list[MotionTemplate], dict[str, Any]]:
    """Read templates written by :func:`save_templates`; returns (templates, meta)."""
    p = Path(directory) / MODEL_FILE
    if not p.is_file():
        raise DataError(f"{Path(directory)} holds no fitted motion templates ({MODEL_FILE})")
    with np.load(p) as z:
        header = json.loads(str(z["header"]))
        out = [
            MotionTemplate(
                h["label"],
                z[f"mean_{i}"],
                z[f"columns_{i}"],
                h["delta"],
                h["threshold"],
                h["n_examples"],
                z[f"costs_{i}"],
            )
            for i, h in enumerate(header["templates"])
        ]
    return out, header["meta"]


def key_columns(template: MotionTemplate, background: np.ndarray, contrast: float = 0.3) -> np.ndarray:
    """The template's characteristic features: those that run through a progression
    (cared-for 0 somewhere and 1 elsewhere) or whose mean departs from the background
    on-fraction (``background`` (31,), e.g. over the training database) by more than
    ``contrast``. Features constant in the template and typical of all motions are left out."""
    cols = template.columns
    m = template.mean[:, cols]
    d = template.delta
    prog = (m.max(axis=0) >= 1 - d) & (m.min(axis=0) <= d)
    odd = np.abs(m.mean(axis=0) - np.asarray(background)[cols]) > contrast
    keep = cols[prog | odd]
    return keep if len(keep) else cols


def clip_min_costs(codes: np.ndarray, offsets: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Per clip the least end-frame cost of the template (inf when no path fits)."""
    ranges = np.stack([offsets[:-1], offsets[1:]], axis=1)
    cost, _ = template_costs(codes, table, ranges)
    out = np.full(len(ranges), np.inf)
    nonempty = ranges[:, 1] > ranges[:, 0]
    out[nonempty] = np.minimum.reduceat(cost, ranges[nonempty, 0])
    return out


def calibrate_threshold(positive: np.ndarray, negative: np.ndarray | None = None, margin: float = 0.25) -> float:
    """A cost threshold from held-out costs of class examples and of other clips.

    Without negatives: ``(1 + margin)`` times the largest finite positive cost. With
    negatives: the cut maximising F1 (positives below it found, negatives below it false
    hits), placed midway between the neighbouring costs; ties go to the larger cut.
    """
    pos = np.asarray(positive, float)
    pos = pos[np.isfinite(pos)]
    if not len(pos):
        return 0.1
    neg = np.zeros(0) if negative is None else np.asarray(negative, float)
    neg = neg[np.isfinite(neg)]
    if not len(neg):
        return float((1 + margin) * pos.max())
    values = np.unique(np.concatenate([pos, neg]))
    best, cut = -1.0, float(pos.max())
    for a, b in zip(values, np.append(values[1:], values[-1] * (1 + margin) + 1e-9), strict=True):
        tp = (pos <= a).sum()
        fp = (neg <= a).sum()
        f1 = 2 * tp / (2 * tp + fp + (len(pos) - tp))
        if f1 >= best:
            best, cut = f1, 0.5 * (a + b)
    return float(cut)


def fit_class_template(
    label: str,
    examples: list[np.ndarray],
    background: np.ndarray | None = None,
    features: str = "key",
    delta: float = 0.2,
    iterations: int = 2,
    calibrate: bool = True,
    margin: float = 0.25,
    groups: list[Any] | None = None,
    negatives: list[np.ndarray] | None = None,
) -> MotionTemplate:
    """A class template retrieving on :func:`key_columns` (``features="key"``, against the
    per-feature on-fraction ``background`` (31,)) or on all 31, with a calibrated threshold.

    ``calibrate``: each group of examples (``groups``, e.g. the actor; default each example)
    is left out in turn, a template fitted on the others and the left-out examples' least
    costs kept (``example_costs``); ``negatives`` (clips of other classes) give the false-hit
    side of :func:`calibrate_threshold`. Without calibration, or with one group, the
    threshold is ``(1 + margin)`` x 0.08 (one cared-for feature wrong in ~10 per frame).
    """
    xs = [np.asarray(x, np.float32) for x in examples]
    bg = np.mean(np.concatenate(xs), axis=0) if background is None else np.asarray(background)
    all_cols = np.arange(xs[0].shape[1])
    pair = pairwise_costs(xs, all_cols) if len(xs) > 1 else None

    def one(idx: list[int]) -> MotionTemplate:
        sub = None if pair is None else pair[np.ix_(idx, idx)]
        t = fit_template(label, [xs[i] for i in idx], delta=delta, iterations=iterations, pair=sub)
        if features == "key":
            t.columns = key_columns(t, bg)
        return t

    tmpl = one(list(range(len(xs))))
    g = np.arange(len(xs)) if groups is None else np.asarray(groups)
    uniq = list(dict.fromkeys(g.tolist()))
    if calibrate and len(uniq) >= 2:
        costs = np.full(len(xs), np.inf)
        for grp in uniq:
            out = np.flatnonzero(g == grp)
            t = one([i for i in range(len(xs)) if g[i] != grp])
            table = t.table()
            for i in out:
                costs[i] = clip_min_costs(frame_codes(xs[i]), np.array([0, len(xs[i])]), table)[0]
        tmpl.example_costs = costs
        neg = None
        if negatives:
            lengths = [len(x) for x in negatives]
            neg = clip_min_costs(
                frame_codes(np.concatenate(negatives)), np.concatenate([[0], np.cumsum(lengths)]), tmpl.table()
            )
        tmpl.threshold = calibrate_threshold(costs, neg, margin)
    else:
        tmpl.threshold = float((1 + margin) * 0.08)
    return tmpl
