"""The generalization protocol of the cleaner (``benchmarks/cleaning.py loso``; docs/cleaning.md).

One *run* = one held-out take at its own frame rate, errors injected at that rate
(:func:`inject_native`: the kinds of :data:`SWEEP_KINDS`, magnitudes and durations drawn
from :data:`SWEEP_RANGES`, durations counted in frames at 24 fps), cleaned exactly as
``mocapflow clean`` does (``cleaner.clean(take, context)`` on the input-rate take and
context), and scored twice against the injected cells (moved > :data:`MIN_ANGLE` degrees):

* on the flags (analysis rate, the truth sampled at the analysis frames);
* on the cells the output take changes by >= :data:`CHANGED_DEG` degrees, at the input rate
  (words of 15 x 24-fps frames every 5, converted to input frames).

Headline (word, joint) recall / precision count only errors of >= 15 degrees lasting >= 2
frames at 24 fps (:func:`strict`); the other injected cells are "don't care" (neither a hit
nor a false alarm). Each injected error also gets its own row (kind, measured peak angle,
duration, (word, joint) pairs hit by the flags and by the output, residual after / before)
for the sweep. :func:`bootstrap` gives 95 % intervals by resampling runs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.motion import Motion

from .error_injection import inject_at_density

#: Error kinds of the sweep; ``ramp`` is the family no design was tuned on.
SWEEP_KINDS: tuple[str, ...] = ("spike", "flip", "offset", "freeze", "noise", "swap", "ramp")
UNTUNED: tuple[str, ...] = ("ramp",)
#: (duration in 24-fps frames, magnitude in degrees) per kind (noise: per-frame sd).
SWEEP_RANGES: dict[str, tuple[tuple[int, int], tuple[float, float]]] = {
    "spike": ((1, 4), (10.0, 90.0)),
    "flip": ((1, 3), (150.0, 175.0)),
    "offset": ((1, 40), (10.0, 90.0)),
    "freeze": ((1, 40), (0.0, 0.0)),
    "noise": ((1, 40), (5.0, 30.0)),
    "swap": ((1, 40), (0.0, 0.0)),
    "ramp": ((1, 40), (10.0, 90.0)),
}
#: Injected cells moved more than this (degrees) are an error's cells; errors peaking below
#: :data:`TRUTH_DEG` are reported apart, never required nor counted as false alarms.
MIN_ANGLE = 5.0
#: Cells the injection moved at least this much are the truth; cells it moved less (but at
#: least :data:`CHANGED_DEG`) are "don't care".
TRUTH_DEG = 10.0
CHANGED_DEG = 1.0
#: Rates of the printed rate curve (set ``false_alarm_rate`` vs measured flagged share).
CURVE_RATES: tuple[float, ...] = (1e-4, 3e-4, 1e-3, 3e-3, 1e-2)


def inject_native(
    motion: Motion, seed: int, density: float = 0.125, family: str = "A"
) -> tuple[Motion, np.ndarray, list[dict[str, Any]]]:
    """Errors at ``density`` of the words, written at the take's own rate (a 24-fps frame is
    ``fps / 24`` input frames): family ``A`` (:data:`SWEEP_KINDS`) or ``B``
    (:mod:`.injection_b`). Returns the corrupted take, the (T, J) mask of cells moved
    > :data:`MIN_ANGLE` and one dict per error (kind, joints, input span, 24-fps duration,
    measured peak angle)."""
    r = max(1, int(round(motion.fps / 24.0)))
    if family == "B":
        from .injection_b import inject_b

        bad, mask, errors = inject_b(motion, seed, density, min_angle=MIN_ANGLE)
    else:
        ranges = {k: ((d0 * r, d1 * r), m) for k, ((d0, d1), m) in SWEEP_RANGES.items()}
        bad, mask, errors = inject_at_density(
            motion,
            density,
            SWEEP_KINDS,
            seed=seed,
            min_angle=MIN_ANGLE,
            ranges=ranges,
            word_length=15 * r,
            word_step=5 * r,
            margin=4 * r,
        )
    ang = np.rad2deg(quat.geodesic_angle(bad.rotations, motion.rotations))
    out = []
    for e in errors:
        cells = np.zeros(mask.shape, bool)
        cells[e.start : e.end, list(e.joints)] = mask[e.start : e.end, list(e.joints)]
        peak = float(ang[e.start : e.end, list(e.joints)].max())
        out.append(
            {
                "kind": e.kind,
                "start": e.start,
                "end": e.end,
                "dur24": (e.end - e.start) / r,
                "peak": peak,
                "cells": cells,
            }
        )
    return bad, mask, out


def _wj(mask: np.ndarray, starts: np.ndarray, n: int) -> np.ndarray:
    return np.array([mask[s : s + n].any(0) for s in starts], bool).reshape(len(starts), mask.shape[1])


def _counts(flag: np.ndarray, truth: np.ndarray, dc: np.ndarray, starts: np.ndarray, n: int) -> dict[str, int]:
    jf, jt, jd = _wj(flag, starts, n), _wj(truth, starts, n), _wj(dc, starts, n)
    return {
        "tp": int((jf & jt).sum()),
        "fn": int((~jf & jt).sum()),
        "fp": int((jf & ~jt & ~jd).sum()),
        "cell_tp": int((flag & truth).sum()),
        "cell_fp": int((flag & ~truth & ~dc).sum()),
    }


def _starts(t: int, n: int, step: int) -> np.ndarray:
    from ..paper.motion_words import source_word_starts

    return source_word_starts(t, n, step)


def score_run(clean: Motion, bad: Motion, errors: list[dict[str, Any]], out: Any, clean_out: Any) -> dict[str, Any]:
    """Counts of one run (module doc): ``flags`` / ``output`` (word, joint) and cell counts,
    eq. 2 global and on the erroneous cells, the clean take's edits, one row per error."""
    tex = out.analysis.texture
    cols = np.asarray(tex.joint_index)
    r = clean.fps / tex.fps
    ri = max(1, int(round(r)))
    err0 = np.rad2deg(quat.geodesic_angle(clean.rotations[:, cols], bad.rotations[:, cols]))
    truth_in = err0 >= TRUTH_DEG
    dc_in = (err0 >= CHANGED_DEG) & ~truth_in
    x = np.rint(np.arange(len(out.flags)) * r).astype(np.int64).clip(0, clean.n_frames - 1)
    s24 = _starts(len(out.flags), 15, 5)
    sin = _starts(clean.n_frames, 15 * ri, 5 * ri)
    changed = np.rad2deg(quat.geodesic_angle(bad.rotations[:, cols], out.cleaned.rotations[:, cols]))
    err1 = np.rad2deg(quat.geodesic_angle(clean.rotations[:, cols], out.cleaned.rotations[:, cols]))
    anyerr = truth_in | dc_in
    rec: dict[str, Any] = {
        "flags": _counts(out.flags, truth_in[x], dc_in[x], s24, 15),
        "output": _counts(changed >= CHANGED_DEG, truth_in, dc_in, sin, 15 * ri),
        "eq2_before": float((np.deg2rad(err0 / 2) ** 2).sum(1).mean()),
        "eq2_after": float((np.deg2rad(err1 / 2) ** 2).sum(1).mean()),
        "cells_before": float((np.deg2rad(err0[anyerr] / 2) ** 2).mean()) if anyerr.any() else 0.0,
        "cells_after": float((np.deg2rad(err1[anyerr] / 2) ** 2).mean()) if anyerr.any() else 0.0,
    }
    # the native-rate edges: input frames within one 24-fps frame of an error, on its joints, holding none
    near = np.zeros_like(anyerr)
    for e in errors:
        j = e["cells"][:, cols].any(0)
        lo, hi = max(0, e["start"] - ri), min(clean.n_frames, e["end"] + ri)
        near[lo : e["start"], j] = True
        near[e["end"] : hi, j] = True
    near &= ~anyerr
    rec["edge_max_deg"] = float(changed[near].max(initial=0.0))
    rows = []
    for e in errors:
        c = e["cells"][:, cols]
        if not c.any():
            continue
        jt = _wj(c, sin, 15 * ri)
        jt24 = _wj(c[x], s24, 15)
        rows.append(
            {
                "kind": e["kind"],
                "peak": e["peak"],
                "dur24": e["dur24"],
                "big": bool(e["peak"] >= TRUTH_DEG),
                "wj": int(jt.sum()),
                "hit_output": int((jt & _wj(changed >= CHANGED_DEG, sin, 15 * ri)).sum()),
                "wj24": int(jt24.sum()),
                "hit_flags": int((jt24 & _wj(out.flags & c[x], s24, 15)).sum()),
                "residual": float(err1[c].mean() / max(err0[c].mean(), 1e-9)),
            }
        )
    rec["errors"] = rows
    if clean_out is not None:
        ch = np.rad2deg(quat.geodesic_angle(clean.rotations[:, cols], clean_out.cleaned.rotations[:, cols]))
        rec["clean_share"] = float((ch >= CHANGED_DEG).mean())
        rec["clean_edited"] = float((ch > 1e-4).mean())
        rec["clean_max_deg"] = float(ch.max(initial=0.0))
        rec["clean_big"] = int((ch > 15.0).sum())
        # the clean take's changed (word, joint) pairs: false alarms of the same protocol
        rec["clean_fp"] = int(_wj(ch >= CHANGED_DEG, sin, 15 * ri).sum())
        rec["clean_pairs"] = int(len(sin) * len(cols))
        if clean_out.stat is not None:
            null = clean_out.calibration
            st = clean_out.stat
            rec["curve"] = [float((st > max(null.take_threshold(a, st), 1e-9)).mean()) for a in CURVE_RATES]
            rec["null_source"] = null.source
    return rec


def bootstrap(num: np.ndarray, den: np.ndarray, n_boot: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """Ratio of sums of per-run ``num`` / ``den`` and its 95 % interval over runs resampled."""
    num, den = np.asarray(num, float), np.asarray(den, float)
    if den.sum() <= 0:
        return float("nan"), float("nan"), float("nan")
    idx = np.random.default_rng(seed).integers(0, len(num), (n_boot, len(num)))
    b = num[idx].sum(1) / np.maximum(den[idx].sum(1), 1e-12)
    return float(num.sum() / den.sum()), float(np.quantile(b, 0.025)), float(np.quantile(b, 0.975))
