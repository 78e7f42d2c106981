"""Built-in plugin: the MDM cleaner, its evaluation harness and ``mocapflow clean``."""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "clip"


def mdm_table(res: Any, motion: Any, mdm_in: np.ndarray, clip_id: int, threshold: float,
              cue: np.ndarray | None = None) -> pa.Table:
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
    return pa.table({
        "clip_id": pa.array(np.full(t * len(cols), clip_id, np.int32)),
        "frame": pa.array(frame),
        "joint": pa.array(joint),
        "joint_name": pa.array(names.tolist(), pa.string()),
        "value": pa.array(vals.reshape(-1).astype(np.float32)),
        "flagged": pa.array(flagged),
        "cue": pa.array(cues.tolist(), pa.string()),
    })


def change_report(out: Any, motion: Any, top: int = 10) -> dict[str, Any]:
    """What the cleaner changed and why: flagged analysis cells per joint and cue, the
    largest input edits, the calibration (JSON-friendly, deterministic)."""
    joints = out.analysis.joints
    per_joint: dict[str, dict[str, int]] = {}
    for f, c in zip(*np.nonzero(out.flags)):
        d = per_joint.setdefault(joints[c], {})
        name = out.cue[f, c] or "mdm"
        d[name] = d.get(name, 0) + 1
    ed = out.edits
    largest = []
    if ed.num_rows:
        deg = ed["edit_deg"].to_numpy()
        order = np.argsort(-deg, kind="stable")[:top]
        fr, jn, cu = ed["frame"].to_pylist(), ed["joint_name"].to_pylist(), ed["cue"].to_pylist()
        largest = [{"frame": fr[i], "time_s": round(fr[i] / motion.fps, 3), "joint": jn[i], "cue": cu[i],
                    "edit_deg": round(float(deg[i]), 2)} for i in order]
    n_cells = int(motion.n_frames * len(out.analysis.texture.joint_index))
    return {"flagged_per_joint": dict(sorted(per_joint.items())),
            "edited_share": round(ed.num_rows / max(n_cells, 1), 6),
            "max_edit_deg": round(float(ed["edit_deg"].to_numpy().max()), 2) if ed.num_rows else 0.0,
            "largest_edits": largest,
            "calibration": out.calibration.summary() if out.calibration is not None else None}


def clean_clip(cleaner: Any, motion: Any, context: Any, clip_id: int, out_dir: Path | None) -> dict[str, Any]:
    """Analyse and repair one clip; write its BVH, heatmap and before/after plot into ``out_dir``."""
    from .plots import mdm_heatmap
    from .repair import map_to_input

    p = cleaner.params
    out = cleaner.clean(motion, context)
    res = out.analysis
    edits = out.edits.set_column(0, "clip_id", pa.array(np.full(out.edits.num_rows, clip_id, np.int32)))
    level = p.threshold if p.mode == "paper" else 0.5
    mdm_in = map_to_input(out.map_result(), motion)
    files = {}
    if out_dir is not None:
        stem = _safe(motion.name or f"clip{clip_id}")
        if p.heatmaps:
            mdm_heatmap(out.value, res.joints, out_dir / f"{stem}.mdm.png", res.texture.fps, level,
                        title=f"{motion.name}: movement digression map ({p.mode})")
            files["heatmap"] = f"{stem}.mdm.png"
            if edits.num_rows:
                from .edit_plots import before_after_plot

                before_after_plot(motion, out.cleaned, edits, out_dir / f"{stem}.edits.png")
                files["before_after"] = f"{stem}.edits.png"
        if p.write_bvh:
            from mocapflow.framework.plugins import load_registries

            # through the registry: a format is another package's component
            load_registries()["formats"].get("bvh")().write(out.cleaned, out_dir / f"{stem}.clean.bvh")
            files["bvh"] = f"{stem}.clean.bvh"
    return {
        "mdm": mdm_table(res, motion, mdm_in, clip_id, level, out.cue),
        "edits": edits,
        "cleaned": out.cleaned,
        "seconds": res.seconds,
        "summary": {"clip": motion.name, "mode": p.mode, "dtw": res.n_dtw,
                    "flagged_cells": int(out.flags.sum()), "edited_cells": edits.num_rows,
                    **change_report(out, motion), **files},
    }


def _plugin_manager(args: argparse.Namespace, pm: Any = None) -> Any:
    """The plugin manager the CLI built (passed in, or left on ``args`` as ``plugin_manager``);
    without one, one built with the CLI's own ``--block`` / ``--no-entry-points`` switches."""
    pm = pm if pm is not None else getattr(args, "plugin_manager", None)
    if pm is not None:
        return pm
    from mocapflow.framework.plugins import get_plugin_manager

    return get_plugin_manager(entry_points=not getattr(args, "no_entry_points", False),
                              blocked=list(getattr(args, "block", None) or []))


def _read_motion(path: str, regs: Any) -> Any:
    from mocapflow.framework.errors import ConfigError

    ext = Path(path).suffix.lower()
    for _, cls in regs["formats"]:
        if ext in getattr(cls, "extensions", ()):
            return cls().read(path)
    raise ConfigError(f"{path}: no registered reader for {ext!r} files")


_OUTPUT_KINDS = (".bvh", ".amc")


def _atomic(dest: Path, write: Any) -> None:
    """Write through ``write(tmp_path)`` into a temporary file beside ``dest``, then rename."""
    from mocapflow.framework.datasets import atomic_path

    with atomic_path(dest) as tmp:
        write(tmp)


def write_cleaned(motion: Any, dest: Path, regs: Any) -> list[Path]:
    """Write the cleaned take with the registered writer for the extension of ``dest`` (BVH,
    or AMC with its ASF beside it), atomically, creating the folder. Returns the files written."""
    from mocapflow.framework.errors import ConfigError

    ext = dest.suffix.lower()
    writers = [cls for _, cls in regs["formats"] if ext in cls.extensions and cls.can_write()]
    if not writers:
        raise ConfigError(f"{dest}: no registered writer for {ext!r} files")
    dest.parent.mkdir(parents=True, exist_ok=True)
    writers[0]().write_atomic(motion, dest)
    return [dest, dest.with_suffix(".asf")] if ext == ".amc" else [dest]


class CleanCommand:
    """``mocapflow clean TAKE --context FILES... --output CLEAN.bvh --report DIR``."""

    name = "clean"
    help = "detect and repair capture errors of a take by self-similarity (MDM, Aristidou 2018)"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("take", help="motion file to clean (.amc, .bvh...)")
        parser.add_argument("--context", nargs="*", default=[], metavar="FILE", help="similar clean takes to search too")
        parser.add_argument("--output", required=True, metavar="CLEAN.bvh",
                            help="cleaned take (.bvh, or .amc with its .asf written beside it)")
        parser.add_argument("--report", metavar="DIR", help="write mdm.parquet, edits.parquet, heatmap and "
                            "before/after PNGs, summary.json (what changed and why)")
        parser.add_argument("--mode", choices=("calibrated", "paper"), default=None,
                            help="calibrated (default): detector fitted on the context; paper: MDM > threshold")
        parser.add_argument("--false-alarm", type=float, default=None,
                            help="calibrated: share of clean (word, joint) pairs that may be flagged (default 0.004)")
        parser.add_argument("--threshold", type=float, default=None, help="paper: MDM threshold (default 0.5)")
        parser.add_argument("--two-stage", action="store_true", help="local search first, context only around distinct words")
        parser.add_argument("--normalization", choices=("mean", "median", "spread", "texture", "none"), default=None,
                            help="paper: scale of the MDM differences (mean = the paper)")

    @classmethod
    def run(cls, args: argparse.Namespace, pm: Any = None) -> int:
        import pyarrow.parquet as pq

        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.plugins import build_registries

        dest = Path(args.output)
        if dest.suffix.lower() not in _OUTPUT_KINDS:
            raise ConfigError(f"--output {args.output}: the cleaned take is written as .bvh or .amc, "
                              f"not {dest.suffix or 'a file without extension'!r}")
        regs = build_registries(_plugin_manager(args, pm))
        cleaner_cls = regs["cleaners"].get("mdm")
        take = _read_motion(args.take, regs)
        if dest.suffix.lower() == ".amc" and take.skeleton.meta.get("format") != "asf":
            raise ConfigError(f"--output {args.output}: AMC needs an ASF skeleton; {args.take} is not ASF/AMC, write .bvh")
        context = [_read_motion(p, regs) for p in args.context]
        params: dict[str, Any] = {"write_bvh": False, "heatmaps": bool(args.report), "two_stage": args.two_stage}
        for key in ("mode", "threshold", "normalization", "false_alarm"):
            if getattr(args, key, None) is not None:
                params[key] = getattr(args, key)
        cleaner = cleaner_cls(params)
        report = Path(args.report) if args.report else None
        if report is not None:
            report.mkdir(parents=True, exist_ok=True)
        out = clean_clip(cleaner, take, context, 0, report)
        write_cleaned(out["cleaned"], dest, regs)
        if report is not None:
            _atomic(report / "mdm.parquet", lambda t: pq.write_table(out["mdm"], t))
            _atomic(report / "edits.parquet", lambda t: pq.write_table(out["edits"], t))
            _atomic(report / "summary.json", lambda t: t.write_text(json.dumps(out["summary"], indent=2)))
        s = out["summary"]
        print(f"{take.name}: {s['flagged_cells']} cells flagged, {s['edited_cells']} input cells edited "
              f"(largest {s['max_edit_deg']:.1f} deg) in {out['seconds']:.2f} s -> {dest}", flush=True)
        return 0
