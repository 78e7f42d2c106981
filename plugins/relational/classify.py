"""``analyses.classify``: label clips with the best-matching motion template (Müller & Röder 2006).

For each clip and each template of a ``matchers.template`` step, the least subsequence-DTW
cost of the template inside the clip (mean local cost over the template, don't-care cells
ignored; :mod:`mocapflow.plugins.relational.template_model`). The clip gets the label of the
cheapest template (a template too short to span the clip scores at a penalty,
:func:`classify_clips`); ``confidence = (c2 - c1) / c2`` is the relative margin to the
runner-up (0: a tie); a clip with no runner-up is labelled ``unknown`` (confidence 0),
``within_threshold`` whether ``c1`` is below
the winning template's retrieval threshold. With clip names matching the templates'
``label_pattern`` the true label and ``correct`` are filled in, so accuracy is one query::

    mocapflow sql runs/templates "SELECT avg(correct::INT) FROM classify WHERE held_out"
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework.components import Analysis
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import PipelineError

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput

    from .template_model import MotionTemplate


#: Cost charged per clip frame a template cannot span (``analyses.classify``): a template of
#: K frames covers at most ``K / COVER`` frames (the steps compress it 2x at most); chosen by
#: nested leave-one-actor-out in ``benchmarks/templates.py`` (docs/templates.md).
SPAN_PENALTY = 0.2
#: Label of a clip with no real competitor (fewer than two templates with a finite score).
UNKNOWN = "unknown"


def span_fraction(lengths: np.ndarray, clip_frames: np.ndarray) -> np.ndarray:
    """(n_clips, n_templates) share of each clip a template of ``lengths`` frames can span:
    ``min(1, K / (COVER x n))`` (:mod:`.template_cutoff`'s rule)."""
    from .template_cutoff import COVER

    n = np.maximum(np.asarray(clip_frames, np.float64), 1.0)
    return np.minimum(1.0, np.asarray(lengths, np.float64)[None, :] / (COVER * n[:, None]))


def classify_clips(
    templates: list[MotionTemplate], bits: np.ndarray, offsets: np.ndarray, penalty: float = SPAN_PENALTY
) -> np.ndarray:
    """Per clip of ``bits`` (N, 31) split at ``offsets`` and per template the score, (n_clips,
    n_templates): the least subsequence-DTW cost on all 31 features where the template can
    span the clip (``K >= COVER x`` its frames, the rival check's rule of :mod:`.template_cutoff`);
    a template that spans only a share ``f`` of it scores ``f x cost + (1 - f) x penalty``
    (the frames it cannot reach charged ``penalty`` each), so a clip longer than every
    template (a slow performer) is still labelled by its best-fitting templates, which
    compete with each other (inf: no path fits at all)."""
    from .template_cutoff import _all_columns
    from .template_model import clip_min_costs, frame_codes

    codes = frame_codes(bits)
    out = np.empty((len(offsets) - 1, len(templates)))
    for i, t in enumerate(templates):
        out[:, i] = clip_min_costs(codes, offsets, _all_columns(t).table())
    f = span_fraction(np.array([t.n_frames for t in templates]), np.diff(offsets))
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(out), f * out + (1.0 - f) * float(penalty), np.inf)


def decide(costs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best template, its score, the runner-up and the confidence ``(c2 - c1) / c2`` per row.

    Without a real competitor (no second finite score) the best is -1 (label ``unknown``)
    and the confidence 0: a clip is never won by default."""
    n = costs.shape[1]
    rows = np.arange(len(costs))
    order = np.argsort(costs, axis=1, kind="stable")
    best = order[:, 0].copy() if n else np.full(len(costs), -1)
    c1 = costs[rows, best] if n else np.full(len(costs), np.inf)
    second = order[:, 1].copy() if n > 1 else np.full(len(costs), -1)
    c2 = costs[rows, second] if n > 1 else np.full(len(costs), np.inf)
    real = np.isfinite(c1) & np.isfinite(c2)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf = np.where(real & (c2 > 0), (c2 - c1) / np.where(c2 > 0, c2, 1.0), 0.0)
    best[~real] = -1
    second[~np.isfinite(c2)] = -1
    return best, np.where(real, c1, np.inf), second, conf


class TemplateClassifier(Analysis):
    """Label every clip with its best-matching motion template and a confidence.

    Inputs: ``templates`` (a ``matchers.template`` step), ``features`` (a
    ``features.relational`` dataset) and ``motions`` (clip names). Output table: ``clip_id,
    name, label, cost, runner_up, runner_up_cost, confidence, within_threshold,
    true_label, correct, held_out`` (``held_out``: the clip was not a training example).
    """

    name = "classify"
    version = "1"
    inputs = {"templates": True, "features": True, "motions": True}

    class Params(BaseParams):
        clips: str = Field(".", description="regular expression: classify the clips whose names match")

    params: Params

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        from .labels import labels_of
        from .template import _clip_layout
        from .template_model import load_templates

        tds, fds = inputs["templates"], inputs["features"]
        if tds.producer != "matchers.template" or fds.producer != "features.relational":
            raise PipelineError(
                f"analyses.classify needs templates=matchers.template and features=features.relational, "
                f"got {tds.producer} and {fds.producer}"
            )
        templates, meta = load_templates(tds.path)
        clips = inputs["motions"].table("clips", columns=["clip_id", "name"])
        name_of = dict(zip(clips["clip_id"].to_pylist(), clips["name"].to_pylist(), strict=True))
        bits, clip_ids, offsets = _clip_layout(fds.features())
        names = [name_of.get(int(c), str(c)) for c in clip_ids]
        rx = re.compile(self.params.clips)
        keep = np.array([bool(rx.search(n)) for n in names], bool)
        sel = np.flatnonzero(keep)
        lengths = np.diff(offsets)[sel]
        sub_off = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
        sub_bits = np.concatenate([bits[offsets[i] : offsets[i + 1]] for i in sel]) if len(sel) else bits[:0]
        costs = classify_clips(templates, sub_bits, sub_off)
        best, c1, second, conf = decide(costs)
        labels = [t.label for t in templates]
        truth = labels_of(
            inputs["motions"],
            [clip_ids[i] for i in sel],
            [names[i] for i in sel],
            meta.get("label_pattern", r"(?P<label>$^)"),
        )
        train = re.compile(meta.get("train", "$^"))
        held = [not bool(train.search(names[i])) for i in sel]
        thr = np.array([t.threshold for t in templates])
        table = pa.table(
            {
                "clip_id": pa.array([int(clip_ids[i]) for i in sel], pa.int32()),
                "name": pa.array([names[i] for i in sel], pa.string()),
                "label": pa.array([labels[b] if b >= 0 else UNKNOWN for b in best], pa.string()),
                "cost": pa.array([float(c) if np.isfinite(c) else None for c in c1], pa.float64()),
                "runner_up": pa.array([labels[s] if s >= 0 else None for s in second], pa.string()),
                "runner_up_cost": pa.array(
                    [float(costs[r, s]) if s >= 0 and np.isfinite(costs[r, s]) else None for r, s in enumerate(second)],
                    pa.float64(),
                ),
                "confidence": pa.array([float(x) for x in conf], pa.float64()),
                "within_threshold": pa.array(
                    [bool(b >= 0 and c <= thr[b]) for b, c in zip(best, c1, strict=True)], pa.bool_()
                ),
                "true_label": pa.array(truth, pa.string()),
                "correct": pa.array(
                    [None if t is None else bool(b >= 0 and labels[b] == t) for t, b in zip(truth, best, strict=True)],
                    pa.bool_(),
                ),
                "held_out": pa.array(held, pa.bool_()),
            }
        )
        known = [
            (t, ok) for t, ok, h in zip(truth, table["correct"].to_pylist(), held, strict=True) if t is not None and h
        ]
        summary = {
            "clips": len(sel),
            "templates": len(templates),
            "held_out_accuracy": round(float(np.mean([ok for _, ok in known])), 4) if known else None,
            "unknown": int((best < 0).sum()),
        }
        return StepOutput({"data": table}, summary)


__all__ = ["SPAN_PENALTY", "UNKNOWN", "TemplateClassifier", "classify_clips", "decide", "span_fraction"]
