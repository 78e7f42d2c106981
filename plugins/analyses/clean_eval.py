"""Evaluation harness of the MDM cleaner (Aristidou 2018 §6, Tables 1 and 2): ``analyses.clean_eval``.

Protocol
--------
For each category (input slots ``locomotion`` and ``dance``, motions datasets ingested at
24 fps), the ``n_test`` longest clips are test clips. Each is corrupted by
:func:`.error_injection.inject_errors` (every error kind ``per_kind`` times, seed
``seed + clip position``) and analysed against three contexts (§6 "Context
determination"): ``local`` (the clip alone), ``small`` (plus ``small_size`` other clips of
the category) and ``large`` (plus up to ``large_size`` others), and ``large_two_stage`` (the
large context through the two-stage scheme of §5). Context clips are clean.

Detection is scored on the texture joints against the ground-truth mask, per (frame,
joint) cell and per word (a source word - 15 frames every 5 - is erroneous when any of
its cells is, detected when any of its cells is flagged): recall TP/(TP+FN), precision
TP/(TP+FP). Baselines, with limits learned from the clean clips of the category other
than the test clip: (a) joint-rotation limits (per joint, the range of each component of
the rotation vector), (b) a threshold on the rotation derivative (per joint, the largest
clean frame-to-frame angle), (c) either. Repair (eq. 2, Table 2): ``||log(q^-1 q̂)||^2``
summed over joints per frame (global) and per cell (per joint) on erroneous frames/cells,
average and maximum, for the corrupted input and for the repaired clip.
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Analysis, Params
from mocapflow.framework.motion import Motion
from mocapflow.plugins.cleaners.cues import rotation_vectors

from .error_injection import ERROR_KINDS, inject_errors


def _log_norm_sq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """||log(a^-1 b)||^2 per quaternion pair (half-angle convention of eq. 1/2)."""
    return np.arccos(np.clip(np.abs(np.sum(a * b, -1)), 0.0, 1.0)) ** 2


class RotationBaselines:
    """Baselines (a) limits and (b) derivative thresholds, learned from clean rotations.

    Parameters
    ----------
    clean : list of ndarray (T, m, 4)
        Clean textures (same joints, same frame rate).
    """

    def __init__(self, clean: list[np.ndarray]) -> None:
        rv = np.concatenate([rotation_vectors(q) for q in clean], 0)
        self.low_ = rv.min(0)
        self.high_ = rv.max(0)
        speed = np.concatenate([quat.geodesic_angle(q[1:], q[:-1]) for q in clean if len(q) > 1], 0)
        self.max_speed_ = speed.max(0)

    def limits(self, q: np.ndarray) -> np.ndarray:
        rv = rotation_vectors(q)
        return np.any((rv < self.low_) | (rv > self.high_), axis=-1)

    def derivative(self, q: np.ndarray) -> np.ndarray:
        out = np.zeros(q.shape[:2], bool)
        if len(q) > 1:
            fast = quat.geodesic_angle(q[1:], q[:-1]) > self.max_speed_
            out[1:] |= fast
            out[:-1] |= fast
        return out


def scores(flagged: np.ndarray, truth: np.ndarray, starts: np.ndarray, n: int) -> dict[str, float]:
    """Cell and word precision/recall counts of ``flagged`` against ``truth`` (T, m)."""
    tp = int((flagged & truth).sum())
    fp = int((flagged & ~truth).sum())
    fn = int((~flagged & truth).sum())
    wt = np.array([truth[s:s + n].any() for s in starts], bool)
    wf = np.array([flagged[s:s + n].any() for s in starts], bool)
    return {"tp": tp, "fp": fp, "fn": fn, "word_tp": int((wt & wf).sum()), "word_fp": int((~wt & wf).sum()),
            "word_fn": int((wt & ~wf).sum())}


def _ratios(c: Mapping[str, int]) -> dict[str, float]:
    def div(a: int, b: int) -> float:
        return float(a) / b if b else float("nan")

    return {"recall": div(c["tp"], c["tp"] + c["fn"]), "precision": div(c["tp"], c["tp"] + c["fp"]),
            "word_recall": div(c["word_tp"], c["word_tp"] + c["word_fn"]),
            "word_precision": div(c["word_tp"], c["word_tp"] + c["word_fp"])}


def repair_errors(clean: np.ndarray, other: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """Eq. 2 between clean and another texture on erroneous frames (global) and cells (per joint)."""
    cell = _log_norm_sq(clean, other)
    frames = truth.any(1)
    glob = cell.sum(1)[frames]
    per = cell[truth]
    nan = float("nan")
    return {"global_avg": float(glob.mean()) if len(glob) else nan, "global_max": float(glob.max()) if len(glob) else nan,
            "joint_avg": float(per.mean()) if len(per) else nan, "joint_max": float(per.max()) if len(per) else nan}


class CleaningEvaluationParams(Params):
    n_test: int = Field(default=4, ge=1, description="test clips per category (the longest ones)")
    small_size: int = Field(default=8, ge=1, description="other clips in the small-scale context (paper: 5-10)")
    large_size: int = Field(default=25, ge=1, description="other clips in the large-scale context (paper: 20-30)")
    contexts: tuple[Literal["local", "small", "large", "large_two_stage"], ...] = Field(
        default=("local", "small", "large", "large_two_stage"),
        description="contexts to evaluate; large_two_stage = the large context through the §5 two-stage scheme")
    kinds: tuple[str, ...] = Field(default=ERROR_KINDS, description="error kinds injected")
    per_kind: int = Field(default=1, ge=1, description="errors of each kind per test clip")
    min_angle: float = Field(default=10.0, gt=0, description="ground truth: cells moved more than this, degrees")
    seed: int = Field(default=0, description="seed of the error injection")
    repair_context: str = Field(default="small", description="context whose detection is repaired for eq. 2")
    also_normalizations: tuple[str, ...] = Field(default=("mean", "spread", "texture"),
                                                  description="MDM row normalisations also scored (rows 'mdm[<name>]')")
    cleaner: dict[str, Any] = Field(default_factory=dict, description="parameters of cleaners.mdm")


class CleaningEvaluation(Analysis):
    """Precision/recall of the MDM cleaner and three baselines on injected errors (Table 1),
    and the repair error of eq. 2 (Table 2). Tables ``data`` (one row per category, context
    and method) and ``repair`` (one row per category and stage)."""

    name = "clean_eval"
    inputs: ClassVar[Mapping[str, bool]] = {"locomotion": False, "dance": False}
    Params: ClassVar[type[Params]] = CleaningEvaluationParams

    def run(self, inputs, ctx):
        from mocapflow.framework.datasets import StepOutput

        rows, rep = [], []
        for category in ("locomotion", "dance"):
            if inputs.get(category) is None:
                continue
            r1, r2 = evaluate_category(category, inputs[category].motions().motions, self.params, log=ctx.log.info)
            rows += r1
            rep += r2
        data = pa.Table.from_pylist(rows) if rows else pa.table({"category": pa.array([], pa.string())})
        repair = pa.Table.from_pylist(rep) if rep else pa.table({"category": pa.array([], pa.string())})
        return StepOutput({"data": data, "repair": repair}, {"rows": rows, "repair": rep})


def protocol_clips(clips: list[Motion], joints: Sequence[str], fps: float) -> tuple[list[Motion], tuple[str, ...]]:
    """The category's clips at the analysis rate, longest first (the first ``n_test`` are the
    test clips), and the texture joints every clip maps."""
    from mocapflow.plugins.cleaners.motion_words import motion_texture

    joints = tuple(j for j in joints if all(j in c.skeleton.canonical for c in clips))
    clips = [c if abs(c.fps - fps) < 1e-9 else motion_texture(c, joints, fps).motion for c in clips]
    return sorted(clips, key=lambda c: -c.n_frames), joints


@dataclass(frozen=True)
class CorruptedClip:
    """One test clip of the protocol: ``bad`` is ``clean`` with the injected ``errors``;
    ``truth`` (T, m) marks the erroneous cells on the texture joints."""

    index: int
    clean: Motion
    others: list[Motion]
    bad: Motion
    truth: np.ndarray
    errors: list
    clean_texture: Any


def corrupted_clips(clips: list[Motion], p: CleaningEvaluationParams, joints: Sequence[str],
                    fps: float) -> Iterator[CorruptedClip]:
    """The ``n_test`` first of :func:`protocol_clips`, each corrupted with seed ``seed + position``."""
    from mocapflow.plugins.cleaners.motion_words import motion_texture

    for i in range(min(p.n_test, len(clips))):
        clean = clips[i]
        bad, mask, errors = inject_errors(clean, p.kinds, p.per_kind, seed=p.seed + i, min_angle=p.min_angle)
        tex = motion_texture(clean, joints, fps)
        yield CorruptedClip(i, clean, [c for k, c in enumerate(clips) if k != i], bad, mask[:, tex.joint_index],
                            errors, tex)


def context_clips(context: str, others: list[Motion], p: CleaningEvaluationParams) -> list[Motion]:
    """The clips searched besides the test clip itself for a context of the protocol."""
    return {"local": [], "small": others[: p.small_size], "large": others[: p.large_size],
            "large_two_stage": others[: p.large_size]}[context]


def evaluate_category(category: str, clips: list[Motion], p: CleaningEvaluationParams,
                      log: Any = print) -> tuple[list[dict], list[dict]]:
    """Run the protocol (module doc) on one category's clips; returns (rows, repair rows)."""
    import time

    from mocapflow.plugins.cleaners.mdm import MDMCleaner, MDMParams, digression_from_outer
    from mocapflow.plugins.cleaners.motion_words import motion_texture, source_word_starts
    from mocapflow.plugins.cleaners.repair import repair_texture

    cleaner = MDMCleaner(MDMParams(**{"write_bvh": False, "heatmaps": False, **p.cleaner}))
    cp = cleaner.params
    two_stage = cleaner.clone(two_stage=True)
    clips, joints = protocol_clips(clips, cp.joints, cp.fps)
    textures = [motion_texture(c, joints, cp.fps).q for c in clips]
    counts: dict[tuple[str, str], dict[str, int]] = {}
    times: dict[str, list[float]] = {}
    rep_before: list[dict[str, float]] = []
    rep_after: list[dict[str, float]] = []
    for case in corrupted_clips(clips, p, joints, cp.fps):
        i, clean, bad, truth, tex_clean = case.index, case.clean, case.bad, case.truth, case.clean_texture
        starts = source_word_starts(len(truth), cp.source_length, cp.source_step)
        base = RotationBaselines([t for k, t in enumerate(textures) if k != i])
        q_bad = motion_texture(bad, joints, cp.fps).q
        lim, der = base.limits(q_bad), base.derivative(q_bad)
        for name, flags in (("baseline_a_limits", lim), ("baseline_b_derivative", der), ("baseline_c_both", lim | der)):
            _add(counts, (name, "-"), scores(flags, truth, starts, cp.source_length))
        for context in p.contexts:
            ctx_clips = context_clips(context, case.others, p)
            t0 = time.perf_counter()
            res = (two_stage if context == "large_two_stage" else cleaner).analyse(bad, ctx_clips)
            times.setdefault(context, []).append(time.perf_counter() - t0)
            _add(counts, ("mdm", context), scores(res.mdm > cp.threshold, truth, starts, cp.source_length))
            for norm in p.also_normalizations:
                # same KNN and T̄, another row scale: only the last step of §3.4 differs
                alt = digression_from_outer(res.texture.q, np.zeros((0, 4, 4)), np.zeros((0,), np.int64),
                                            cp.model_copy(update={"normalization": norm}), difference=res.difference,
                                            spread=res.spread)[3]
                _add(counts, (f"mdm[{norm}]", context), scores(alt > cp.threshold, truth, starts, cp.source_length))
            if context == p.repair_context:
                new, _ = repair_texture(res, cp.threshold, cp.savgol_window, cp.savgol_order)
                rep_before.append(repair_errors(tex_clean.q, res.texture.q, truth))
                rep_after.append(repair_errors(tex_clean.q, new, truth))
            log(f"clean_eval {category} clip {clean.name} context {context}: {times[context][-1]:.2f} s")
    rows = []
    for (method, context), c in counts.items():
        sec = float(np.mean(times[context])) if context in times else float("nan")
        rows.append({"category": category, "method": method, "context": context, **_ratios(c), **c,
                     "seconds_per_clip": sec, "n_clips": min(p.n_test, len(clips))})
    rep = []
    for stage, vals in (("corrupted", rep_before), ("repaired", rep_after)):
        if vals:
            rep.append({"category": category, "stage": stage,
                        **{k: float(np.nanmean([v[k] for v in vals])) for k in vals[0] if k.endswith("avg")},
                        **{k: float(np.nanmax([v[k] for v in vals])) for k in vals[0] if k.endswith("max")}})
    return rows, rep


def _add(acc: dict, key: tuple[str, str], c: Mapping[str, int]) -> None:
    cur = acc.setdefault(key, {k: 0 for k in c})
    for k, v in c.items():
        cur[k] += v
