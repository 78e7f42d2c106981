"""``analyses.classify``: label clips with the best-matching motion template (Müller & Röder 2006).

For each clip and each template of a ``matchers.template`` step, the least subsequence-DTW
cost of the template inside the clip (mean local cost over the template, don't-care cells
ignored; :mod:`mocapflow.plugins.relational.template_model`). The clip gets the label of the
cheapest template; ``confidence = (c2 - c1) / c2`` is the relative margin to the runner-up
(0: a tie, 1: only one template fits at all), ``within_threshold`` whether ``c1`` is below
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

from mocapflow.framework.components import Analysis, Params
from mocapflow.framework.errors import PipelineError

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput


def classify_clips(templates, bits: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Per clip of ``bits`` (N, 31) split at ``offsets`` and per template the least cost on all
    31 features, (n_clips, n_templates) (inf: no path fits). A template competes for a clip
    only if its path can span the clip (``K >= COVER x`` the clip's frames, as the rival
    check of :mod:`.template_cutoff`: a short template fitting a part of a long motion does
    not label it); a clip no template can span keeps every template's cost."""
    from .template_cutoff import COVER, _all_columns
    from .template_model import clip_min_costs, frame_codes

    codes = frame_codes(bits)
    out = np.empty((len(offsets) - 1, len(templates)))
    for i, t in enumerate(templates):
        out[:, i] = clip_min_costs(codes, offsets, _all_columns(t).table())
    lengths = np.array([t.n_frames for t in templates])
    can = lengths[None, :] >= COVER * np.diff(offsets)[:, None]
    return np.where(can | ~can.any(axis=1, keepdims=True), out, np.inf)


def decide(costs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Best template, its cost, the runner-up and the confidence ``(c2 - c1) / c2`` per row."""
    n = costs.shape[1]
    order = np.argsort(costs, axis=1, kind="stable")
    best = order[:, 0]
    c1 = costs[np.arange(len(costs)), best]
    second = order[:, 1] if n > 1 else np.full(len(costs), -1)
    c2 = costs[np.arange(len(costs)), second] if n > 1 else np.full(len(costs), np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        conf = np.where(np.isinf(c2) & np.isfinite(c1), 1.0, np.where(c2 > 0, (c2 - c1) / c2, 0.0))
    conf = np.where(np.isfinite(c1), np.nan_to_num(conf, nan=0.0), 0.0)
    return best, c1, second, conf


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

    class Params(Params):
        clips: str = Field(".", description="regular expression: classify the clips whose names match")

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
        best, c1, second, conf = decide(costs) if len(templates) else (np.zeros(len(sel), int),) * 4
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
                "label": pa.array(
                    [labels[b] if np.isfinite(c) else None for b, c in zip(best, c1, strict=True)], pa.string()
                ),
                "cost": pa.array([float(c) if np.isfinite(c) else None for c in c1], pa.float64()),
                "runner_up": pa.array([labels[s] if s >= 0 else None for s in second], pa.string()),
                "runner_up_cost": pa.array(
                    [float(costs[r, s]) if s >= 0 and np.isfinite(costs[r, s]) else None for r, s in enumerate(second)],
                    pa.float64(),
                ),
                "confidence": pa.array([float(x) for x in conf], pa.float64()),
                "within_threshold": pa.array(
                    [bool(np.isfinite(c) and c <= thr[b]) for b, c in zip(best, c1, strict=True)], pa.bool_()
                ),
                "true_label": pa.array(truth, pa.string()),
                "correct": pa.array(
                    [
                        None if t is None else (np.isfinite(c) and labels[b] == t)
                        for t, b, c in zip(truth, best, c1, strict=True)
                    ],
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
        }
        return StepOutput({"data": table}, summary)


__all__ = ["TemplateClassifier", "classify_clips", "decide"]
