"""Evaluation harness of the MDM cleaner (Aristidou 2018 §6, Tables 1 and 2): ``analyses.clean_eval``.

The protocol (docs/cleaning.md): held-out test clips (>= :data:`MIN_FRAMES` frames) corrupted
at ``density`` by :func:`.error_injection.inject_at_density` (seed ``seed + position``),
analysed against the ``local``, ``small`` and ``large`` contexts of clean clips; detection
scored per cell, (word, joint) and word against cells moved > :data:`MIN_ANGLE` degrees
for ``mdm``, ``mdm[paper]`` and three baselines (rotation limits, derivative, either);
repair by eq. 2 (``||log(q^-1 q̂)||^2``: global per frame, and on the erroneous cells)
before and after, and what the cleaner does to the uncorrupted clip.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any, ClassVar, Literal

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Analysis, Params, ParamsOf
from mocapflow.framework.motion import Motion

from .error_injection import PROTOCOL_KINDS, inject_at_density
from .scores import RotationBaselines, _log_norm_sq, _ratios, scores, source_glitches

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.datasets import Dataset, StepOutput

#: What ``held_out`` names per category: the clip name before '_' (subject) or after it (trial).
GROUP_BY: dict[str, str] = {"locomotion": "subject", "dance": "trial"}
#: Test clips have at least this many frames at 24 fps.
MIN_FRAMES = 60
#: Ground truth: cells the injection moved more than this, degrees.
MIN_ANGLE = 10.0


class CleaningEvaluationParams(Params):
    density: float = Field(
        default=0.125,
        gt=0,
        lt=1,
        description="share of the source words of a test clip given an error (the paper: ~0.125, §6)",
    )
    held_out: dict[str, tuple[str, ...]] = Field(
        default_factory=lambda: {"locomotion": ("07", "16", "35"), "dance": ("06", "07", "10", "11")},
        description="per category, the subjects (locomotion) or trials (dance) whose clips are the test clips; "
        "the defaults were never used while tuning the cleaner (tuned on subjects 02 and 49, trials "
        "01, 02, 04, 05); empty = the n_test longest clips",
    )
    n_test: int = Field(default=40, ge=1, description="at most this many test clips per category (the longest)")
    small_size: int = Field(default=8, ge=1, description="other clips in the small-scale context (paper: 5-10)")
    large_size: int = Field(default=25, ge=1, description="other clips in the large-scale context (paper: 20-30)")
    contexts: tuple[Literal["local", "small", "large"], ...] = Field(
        default=("local", "small"), description="contexts to evaluate"
    )
    seed: int = Field(default=0, description="seed of the error injection (clip k gets seed + k)")
    paper: bool = Field(default=True, description="also score mode 'paper' on the same analyses (rows 'mdm[paper]')")
    cleaner: Annotated[dict[str, Any], ParamsOf("cleaners.mdm")] = Field(
        default_factory=dict, description="parameters of cleaners.mdm"
    )


class CleaningEvaluation(Analysis):
    """Tables ``data`` (detection), ``repair`` (eq. 2, clean takes) and ``kinds`` (per error
    kind) of the protocol (module doc), per category, context and method."""

    name = "clean_eval"
    inputs: ClassVar[Mapping[str, bool]] = {"locomotion": False, "dance": False}
    Params: ClassVar[type[Params]] = CleaningEvaluationParams
    params: CleaningEvaluationParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        rows, rep, kinds = [], [], []
        for category in ("locomotion", "dance"):
            if inputs.get(category) is None:
                continue
            r1, r2, r3 = evaluate_category(
                category,
                inputs[category].motions().motions,
                self.params,
                log=ctx.log.info,
                progress=lambda it, n, d: ctx.progress(it, total=n, desc=d),
            )
            rows += r1
            rep += r2
            kinds += r3
        empty = pa.table({"category": pa.array([], pa.string())})
        tabs = {
            name: pa.Table.from_pylist(v) if v else empty
            for name, v in (("data", rows), ("repair", rep), ("kinds", kinds))
        }
        return StepOutput(tabs, {"rows": rows, "repair": rep})


def protocol_clips(clips: list[Motion], joints: Sequence[str], fps: float) -> tuple[list[Motion], tuple[str, ...]]:
    """The category's clips at the analysis rate, longest first, and the texture joints
    every clip maps."""
    from ..paper.motion_words import motion_texture

    joints = tuple(j for j in joints if all(j in c.skeleton.canonical for c in clips))
    clips = [c if abs(c.fps - fps) < 1e-9 else motion_texture(c, joints, fps).motion for c in clips]
    return sorted(clips, key=lambda c: (-c.n_frames, c.name)), joints


def clip_key(name: str, by: str) -> str:
    """Subject (before the first '_') or trial (after it) of a CMU-style clip name."""
    head, _, tail = name.partition("_")
    return head if by == "subject" else tail


@dataclass(frozen=True)
class CorruptedClip:
    """A test clip: ``bad`` = ``clean`` with ``errors``; ``truth`` (T, m) the erroneous texture
    cells; ``others`` the clips a context may hold (not itself nor a dance partner's take)."""

    index: int
    clean: Motion
    others: list[Motion]
    bad: Motion
    truth: np.ndarray
    errors: list[Any]
    clean_texture: Any


def test_indices(clips: list[Motion], p: CleaningEvaluationParams, category: str) -> list[int]:
    """Positions in ``clips`` (longest first) of the category's test clips."""
    held = p.held_out.get(category, ())
    by = GROUP_BY.get(category, "subject")
    idx = [i for i, c in enumerate(clips) if c.n_frames >= MIN_FRAMES and (not held or clip_key(c.name, by) in held)]
    return idx[: p.n_test]


def corrupted_clips(
    clips: list[Motion], p: CleaningEvaluationParams, joints: Sequence[str], fps: float, category: str = "locomotion"
) -> Iterator[CorruptedClip]:
    """The test clips of :func:`test_indices`, each corrupted by :func:`inject_at_density`
    with seed ``seed + position``."""
    from ..paper.motion_words import motion_texture

    for i in test_indices(clips, p, category):
        clean = clips[i]
        bad, mask, errors = inject_at_density(clean, p.density, PROTOCOL_KINDS, seed=p.seed + i, min_angle=MIN_ANGLE)
        tex = motion_texture(clean, joints, fps)
        trial = clip_key(clean.name, "trial")
        others = [
            c
            for k, c in enumerate(clips)
            if k != i and not (category == "dance" and clip_key(c.name, "trial") == trial)
        ]
        yield CorruptedClip(i, clean, others, bad, mask[:, tex.joint_index], errors, tex)


def context_clips(context: str, others: list[Motion], p: CleaningEvaluationParams) -> list[Motion]:
    """The clips searched besides the test clip itself for a context of the protocol."""
    return {"local": [], "small": others[: p.small_size], "large": others[: p.large_size]}[context]


def _glitch_part(clean: np.ndarray, other: np.ndarray, glitch: np.ndarray) -> float:
    """The share of :func:`_eq2`'s global figure that lies on the source-glitch cells."""
    cell = _log_norm_sq(clean, other)
    return float((cell * glitch).sum(1).mean()) if len(cell) else 0.0


def _input_mask(mask: np.ndarray, texture: Any, motion: Motion) -> np.ndarray:
    """An analysis-rate (T, m) mask at the input frames and skeleton joints, (T_in, J)."""
    out = np.zeros((motion.n_frames, motion.n_joints), bool)
    x = np.rint(np.arange(motion.n_frames) * (texture.fps / motion.fps)).astype(np.int64).clip(0, len(mask) - 1)
    out[:, texture.joint_index] = mask[x]
    return out


def _eq2(clean: np.ndarray, other: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Eq. 2 of a whole clip (per-frame sum over joints, mean over frames) and on its erroneous cells (mean)."""
    cell = _log_norm_sq(clean, other)
    return float(cell.sum(1).mean()), float(cell[truth].mean()) if truth.any() else float("nan")


def evaluate_category(
    category: str, clips: list[Motion], p: CleaningEvaluationParams, log: Any = print, progress: Any = None
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """Run the protocol (module doc) on one category's clips; returns (rows, repair rows, kind rows)."""
    import time

    from ..cleaner import MDMCleaner, MDMParams, clean_motion
    from ..paper.motion_words import motion_texture, source_word_starts

    cleaner = MDMCleaner(MDMParams(**{"write_bvh": False, "heatmaps": False, **p.cleaner}))
    cp = cleaner.params
    methods = {"mdm": cleaner}
    if p.paper and cp.mode != "paper":
        methods["mdm[paper]"] = cleaner.clone(mode="paper", threshold=0.5)
    clips, joints = protocol_clips(clips, cp.joints, cp.fps)
    textures = [motion_texture(c, joints, cp.fps).q for c in clips]
    counts: dict[tuple[str, str], dict[str, int]] = {}
    times: dict[str, list[float]] = {}
    repair: dict[tuple[str, str], list[dict[str, Any]]] = {}
    kinds: dict[tuple[str, str, str, str], dict[str, float]] = {}
    cases = list(corrupted_clips(clips, p, joints, cp.fps, category))
    it = progress(cases, len(cases), f"clean_eval {category}") if progress else cases
    for case in it:
        i, truth = case.index, case.truth
        starts = source_word_starts(len(truth), cp.source_length, cp.source_step)
        base = RotationBaselines([t for k, t in enumerate(textures) if k != i])
        q_bad = motion_texture(case.bad, joints, cp.fps).q
        lim, der = base.limits(q_bad), base.derivative(q_bad)
        glitch = source_glitches(case.clean_texture.q)
        moved = (quat.geodesic_angle(case.clean_texture.q, q_bad) > 1e-6) | (glitch & ~truth)
        for name, flags in (("baseline_a_limits", lim), ("baseline_b_derivative", der), ("baseline_c_both", lim | der)):
            _add(counts, (name, "-"), scores(flags, truth, starts, cp.source_length, moved))
        for context in p.contexts:
            ctx = context_clips(context, case.others, p)
            t0 = time.perf_counter()
            # one analysis (texture, KNN, T̄) per context; the methods differ only in decision and repair
            analysis = cleaner.analyse(case.bad, ctx)
            for method, cl in methods.items():
                out = clean_motion(cl, case.bad, ctx, analysis=analysis)
                if method == "mdm":
                    times.setdefault(context, []).append(time.perf_counter() - t0)
                _add(counts, (method, context), scores(out.flags, truth, starts, cp.source_length, moved))
                clean_run = clean_motion(
                    cl,
                    case.clean,
                    ctx,
                    calibration=out.calibration
                    if out.calibration is not None and out.calibration.source == "context"
                    else None,
                )
                g0, e0 = _eq2(case.clean_texture.q, analysis.texture.q, truth)
                g1, e1 = _eq2(case.clean_texture.q, out.repaired, truth)
                n_in = case.clean.n_frames * len(case.clean_texture.joint_index)
                # the same with the source's own glitches left out (source_glitches)
                g0n = g0 - _glitch_part(case.clean_texture.q, analysis.texture.q, glitch)
                g1n = g1 - _glitch_part(case.clean_texture.q, out.repaired, glitch)
                ce = clean_run.edits
                gl_in = _input_mask(glitch, case.clean_texture, case.clean)
                outside = ~gl_in[ce["frame"].to_numpy(), ce["joint"].to_numpy()] if ce.num_rows else np.zeros(0, bool)
                repair.setdefault((method, context), []).append(
                    {
                        "global_before": g0,
                        "global_after": g1,
                        "cells_before": e0,
                        "cells_after": e1,
                        "clean_edited_share": clean_run.edits.num_rows / max(n_in, 1),
                        "clean_max_edit_deg": float(clean_run.edits["edit_deg"].to_numpy().max())
                        if clean_run.edits.num_rows
                        else 0.0,
                        "global_before_ng": g0n,
                        "global_after_ng": g1n,
                        "glitch_cells": int(glitch.sum()),
                        "clean_max_edit_deg_ng": float(ce["edit_deg"].to_numpy()[outside].max())
                        if outside.any()
                        else 0.0,
                        # the clean-take edits outside the source's own glitches, over the cells outside them
                        "clean_edited_share_ng": int(outside.sum()) / max(n_in - int(gl_in.sum()), 1),
                        "clean_glitch_edits": int((~outside).sum()),
                    }
                )
                _kind_rows(kinds, category, method, context, case, out)
            log(f"clean_eval {category} clip {case.clean.name} context {context}: {times[context][-1]:.2f} s")
    n = len(cases)
    rows = []
    for (method_name, context_name), c in counts.items():
        sec = float(np.mean(times[context_name])) if context_name in times else float("nan")
        rows.append(
            {
                "category": category,
                "method": method_name,
                "context": context_name,
                **_ratios(c),
                **c,
                "seconds_per_clip": sec,
                "n_clips": n,
            }
        )
    rep = []
    for (method_name, context_name), vals in repair.items():
        col = {k: np.array([v[k] for v in vals]) for k in vals[0]}
        rep.append(
            {
                "category": category,
                "method": method_name,
                "context": context_name,
                "n_clips": len(vals),
                "global_before": float(col["global_before"].mean()),
                "global_after": float(col["global_after"].mean()),
                "share_global_lower": float(np.mean(col["global_after"] < col["global_before"])),
                # the same target counted the other way: a clip left exactly as it was (its errors
                # missed, nothing edited) is no failure of "do no harm"
                "share_global_not_higher": float(np.mean(col["global_after"] <= col["global_before"])),
                "share_global_unchanged": float(np.mean(col["global_after"] == col["global_before"])),
                "cells_before": float(np.nanmean(col["cells_before"])),
                "cells_after": float(np.nanmean(col["cells_after"])),
                "clean_edited_share": float(col["clean_edited_share"].mean()),
                "clean_edited_share_max": float(col["clean_edited_share"].max()),
                "clean_edited_share_ng": float(col["clean_edited_share_ng"].mean()),
                "clean_edited_share_max_ng": float(col["clean_edited_share_ng"].max()),
                "clean_max_edit_deg": float(col["clean_max_edit_deg"].max()),
                "global_before_ng": float(col["global_before_ng"].mean()),
                "global_after_ng": float(col["global_after_ng"].mean()),
                "share_global_lower_ng": float(np.mean(col["global_after_ng"] < col["global_before_ng"])),
                "share_global_not_higher_ng": float(np.mean(col["global_after_ng"] <= col["global_before_ng"])),
                "glitch_cells": int(col["glitch_cells"].sum()),
                "clean_max_edit_deg_ng": float(col["clean_max_edit_deg_ng"].max()),
                "clean_glitch_edits": int(col["clean_glitch_edits"].sum()),
            }
        )
    kind_rows = [
        {"category": key[0], "method": key[1], "context": key[2], "kind": key[3], **val} for key, val in kinds.items()
    ]
    return rows, rep, kind_rows


def _kind_rows(
    acc: dict[tuple[str, str, str, str], dict[str, float]],
    category: str,
    method: str,
    context: str,
    case: CorruptedClip,
    out: Any,
) -> None:
    """Per error kind: errors injected, found (a flagged cell among its erroneous cells), and eq. 2 on its cells."""
    col = {int(j): c for c, j in enumerate(case.clean_texture.joint_index)}
    for e in case.errors:
        cols = [col[j] for j in e.joints if j in col]
        t = case.truth[e.start : e.end][:, cols]
        if not t.any():
            continue
        r = acc.setdefault(
            (category, method, context, e.kind),
            {"errors": 0, "found": 0, "cells": 0, "cells_flagged": 0, "eq2_before": 0.0, "eq2_after": 0.0},
        )
        r["errors"] += 1
        r["found"] += int((out.flags[e.start : e.end][:, cols] & t).any())
        r["cells"] += int(t.sum())
        r["cells_flagged"] += int((out.flags[e.start : e.end][:, cols] & t).sum())
        q0 = case.clean_texture.q[e.start : e.end][:, cols][t]
        r["eq2_before"] += float(_log_norm_sq(q0, out.analysis.texture.q[e.start : e.end][:, cols][t]).sum())
        r["eq2_after"] += float(_log_norm_sq(q0, out.repaired[e.start : e.end][:, cols][t]).sum())


def _add(acc: dict[tuple[str, str], dict[str, int]], key: tuple[str, str], c: Mapping[str, int]) -> None:
    cur = acc.setdefault(key, {k: 0 for k in c})
    for k, v in c.items():
        cur[k] += v
