"""What ``cleaners.mdm`` and ``mocapflow clean`` leave for one clip: the digression map at the
input frames and the edits as tables, the change report, the cleaned BVH, the heatmap and the
before/after plot (:func:`clean_and_write_clip`)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from mocapflow.framework.errors import ConfigError

from .plots import PAPER_SCORE


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "clip"


def mdm_table(
    res: Any, motion: Any, mdm_in: np.ndarray, clip_id: int, threshold: float, cue: np.ndarray | None = None
) -> pa.Table:
    """Map rows at the input frames: clip_id, frame, joint, joint_name, value, flagged, cue
    (the cue that flagged the nearest analysis cell, null where none did)."""
    cols = res.texture.joint_index
    t = motion.n_frames
    vals = mdm_in[:, cols]  # (T, m)
    frame = np.repeat(np.arange(t, dtype=np.int32), len(cols))
    joint = np.tile(cols.astype(np.int32), t)
    names = np.tile(np.array(res.texture.joints, dtype=object), t)
    flagged = vals.reshape(-1) > threshold
    if cue is not None:
        x = np.rint(np.arange(t) * (res.texture.fps / motion.fps)).astype(np.int64).clip(0, len(cue) - 1)
        cues = cue[x].reshape(-1)
        cues = np.where(flagged, cues, None)
    else:
        cues = np.full(len(flagged), None, dtype=object)
    return pa.table(
        {
            "clip_id": pa.array(np.full(t * len(cols), clip_id, np.int32)),
            "frame": pa.array(frame),
            "joint": pa.array(joint),
            "joint_name": pa.array(names.tolist(), pa.string()),
            "value": pa.array(vals.reshape(-1).astype(np.float32)),
            "flagged": pa.array(flagged),
            "cue": pa.array(cues.tolist(), pa.string()),
        }
    )


def glitches(out: Any, motion: Any) -> list[dict[str, Any]]:
    """The edits above :data:`.calibrated.constants.GLITCH_DEG` named as capture glitches: per
    joint and run of input frames, its time span, largest edit, deciding detector and the
    smallest conformal p-value of its flagged analysis cells (calibrated mode)."""
    from .calibrated.constants import GLITCH_DEG

    ed = out.edits
    if not ed.num_rows or getattr(out, "pvalue", None) is None:
        return []
    deg = ed["edit_deg"].to_numpy()
    big = deg > GLITCH_DEG
    if not big.any():
        return []
    fr, jn, cu = ed["frame"].to_numpy()[big], np.array(ed["joint_name"].to_pylist(), object)[big], deg[big]
    cue = np.array(ed["cue"].to_pylist(), object)[big]
    joints = list(out.analysis.joints)
    r = out.analysis.texture.fps / motion.fps
    found = []
    for name in sorted(set(jn.tolist())):
        sel = np.flatnonzero(jn == name)
        f = fr[sel]
        order = np.argsort(f)
        cuts = np.flatnonzero(np.diff(f[order]) > 1) + 1
        for part in np.split(order, cuts):
            a, b = int(f[part].min()), int(f[part].max())
            c = joints.index(name) if name in joints else None
            lo, hi = int(np.floor(a * r)), int(np.ceil(b * r)) + 1
            p = float(out.pvalue[lo:hi, c].min()) if c is not None and hi > lo else None
            found.append(
                {
                    "joint": name,
                    "from_s": round(a / motion.fps, 3),
                    "to_s": round(b / motion.fps, 3),
                    "max_edit_deg": round(float(cu[sel][part].max()), 2),
                    "detector": next((x for x in cue[sel][part] if x), None),
                    "p_value": None if p is None else float(f"{p:.3g}"),
                }
            )
    return found


def change_report(out: Any, motion: Any, top: int = 10) -> dict[str, Any]:
    """What the cleaner changed and why: flagged analysis cells per joint and cue, the
    largest input edits, the calibration (JSON-friendly, deterministic)."""
    joints = out.analysis.joints
    per_joint: dict[str, dict[str, int]] = {}
    for f, c in zip(*np.nonzero(out.flags), strict=True):
        d = per_joint.setdefault(joints[c], {})
        name = out.cue[f, c] or "mdm"
        d[name] = d.get(name, 0) + 1
    ed = out.edits
    largest = []
    if ed.num_rows:
        deg = ed["edit_deg"].to_numpy()
        order = np.argsort(-deg, kind="stable")[:top]
        fr, jn, cu = ed["frame"].to_pylist(), ed["joint_name"].to_pylist(), ed["cue"].to_pylist()
        largest = [
            {
                "frame": fr[i],
                "time_s": round(fr[i] / motion.fps, 3),
                "joint": jn[i],
                "cue": cu[i],
                "edit_deg": round(float(deg[i]), 2),
            }
            for i in order
        ]
    n_cells = int(motion.n_frames * len(out.analysis.texture.joint_index))
    return {
        "glitches": glitches(out, motion),
        "flagged_per_joint": dict(sorted(per_joint.items())),
        "edited_share": round(ed.num_rows / max(n_cells, 1), 6),
        "max_edit_deg": round(float(ed["edit_deg"].to_numpy().max()), 2) if ed.num_rows else 0.0,
        "largest_edits": largest,
        "calibration": out.calibration.summary() if out.calibration is not None else None,
    }


def decision_words(mode: str, level: float) -> tuple[str, str]:
    """What the map's value is (colour bar: name, units) and what flags a cell, by mode."""
    if mode == "paper":
        return PAPER_SCORE, f"MDM > {level:g}"
    return (
        "calibrated: 0.5 x S / threshold (dimensionless): S = largest detector\nevidence in per-joint "
        "robust units of clean words like the take",
        "conformal p-value <= false_alarm_rate (value > 0.5)",
    )


def clean_and_write_clip(
    cleaner: Any, motion: Any, context: Any, clip_id: int, out_dir: Path | None, registries: Any = None
) -> dict[str, Any]:
    """Clean one clip (:meth:`.cleaner.MDMCleaner.clean`) and write its BVH, heatmap and
    before/after plot into ``out_dir`` (the BVH with the ``formats.bvh`` of ``registries``) (None: nothing written); returns the tables, the
    cleaned motion, the analysis seconds and the summary."""
    from .paper.repair import map_to_input
    from .plots import mdm_heatmap

    p = cleaner.params
    out = cleaner.clean(motion, context)
    res = out.analysis
    edits = out.edits.set_column(0, "clip_id", pa.array(np.full(out.edits.num_rows, clip_id, np.int32)))
    level = p.threshold if p.mode == "paper" else 0.5
    mdm_in = map_to_input(out.map_result(), motion)
    score, rule = decision_words(p.mode, level)
    files = {}
    if out_dir is not None:
        stem = _safe(motion.name or f"clip{clip_id}")
        if p.heatmaps:
            mdm_heatmap(
                out.value,
                res.joints,
                out_dir / f"{stem}.mdm.png",
                res.texture.fps,
                level,
                title=f"{motion.name}: movement digression map ({p.mode})",
                score=score,
                rule=rule,
            )
            files["heatmap"] = f"{stem}.mdm.png"
            if edits.num_rows:
                from .plots import before_after_plot

                before_after_plot(motion, out.cleaned, edits, out_dir / f"{stem}.edits.png")
                files["before_after"] = f"{stem}.edits.png"
        if p.write_bvh:
            if registries is None:
                raise ConfigError(f"{cleaner.key()}: write_bvh needs the registries (a format is another package's)")
            registries["formats"].get("bvh")().write(out.cleaned, out_dir / f"{stem}.clean.bvh")
            files["bvh"] = f"{stem}.clean.bvh"
    table = mdm_table(res, motion, mdm_in, clip_id, level, out.cue)
    return {
        "mdm": table,
        "edits": edits,
        "cleaned": out.cleaned,
        "seconds": res.seconds,
        "summary": {
            "clip": motion.name,
            "mode": p.mode,
            "dtw": res.n_dtw,
            # counts in input cells (frames at the take's rate x texture joints)
            "input_cells": int(motion.n_frames * len(res.texture.joint_index)),
            "flagged_cells": int(table["flagged"].to_numpy().sum()),
            "edited_cells": edits.num_rows,
            "decided_by": rule,
            **change_report(out, motion),
            **files,
        },
    }
