"""``mocapflow clean``: clean one take from the command line. Imports nothing numerical at
module level (the command is registered for ``mocapflow --help``); the work is
:func:`.outputs.clean_and_write_clip`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

_OUTPUT_KINDS = (".bvh", ".amc")


def write_cleaned(motion: Any, dest: Path, regs: Any) -> list[Path]:
    """Write the cleaned take with the registered writer for ``dest``'s extension (BVH, or AMC
    with its ASF beside it), atomically, creating the folder. Returns the files written."""
    writer = regs.motion_format(dest, writing=True)
    dest.parent.mkdir(parents=True, exist_ok=True)
    writer.write_atomic(motion, dest)
    return [dest, dest.with_suffix(".asf")] if dest.suffix.lower() == ".amc" else [dest]


class CleanCommand:
    """``mocapflow clean TAKE --context FILES... --output CLEAN.bvh --report DIR``."""

    name = "clean"
    help = "detect and repair capture errors of a take by self-similarity (MDM, Aristidou 2018)"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("take", help="motion file to clean (.amc, .bvh...)")
        parser.add_argument(
            "--context", nargs="*", default=[], metavar="FILE", help="similar clean takes to search too"
        )
        parser.add_argument(
            "--output",
            required=True,
            metavar="CLEAN.bvh",
            help="cleaned take (.bvh, or .amc with its .asf written beside it)",
        )
        parser.add_argument(
            "--report",
            metavar="DIR",
            help="write mdm.parquet, edits.parquet, heatmap and before/after PNGs, summary.json (what changed and why)",
        )
        parser.add_argument(
            "--mode",
            choices=("calibrated", "paper"),
            default=None,
            help="calibrated (default): detector fitted on the context; paper: MDM > threshold",
        )
        parser.add_argument(
            "--false-alarm-rate",
            type=float,
            default=None,
            metavar="R",
            help="calibrated: share of the (frame, joint) cells of a clean take flagged (default 0.002)",
        )
        parser.add_argument(
            "--false-alarm",
            type=float,
            default=None,
            help="deprecated, ignored: use --false-alarm-rate (a share of cells)",
        )
        parser.add_argument("--threshold", type=float, default=None, help="paper: MDM threshold (default 0.5)")

    @classmethod
    def run(cls, args: argparse.Namespace, ctx: Any = None) -> int:
        import pyarrow.parquet as pq

        from mocapflow.framework.commands import context_of
        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.output_paths import refuse_dataset_path
        from mocapflow.framework.workspace import atomic_path

        dest = refuse_dataset_path(args.output, "--output")
        if args.report:
            refuse_dataset_path(args.report, "--report", directory=True)
        if dest.suffix.lower() not in _OUTPUT_KINDS:
            raise ConfigError(
                f"--output {args.output}: the cleaned take is written as .bvh or .amc, "
                f"not {dest.suffix or 'a file without extension'!r}"
            )
        regs = (ctx if ctx is not None else context_of(args)).registries()
        cleaner_cls = regs["cleaners"].get("mdm")
        take = regs.motion_format(args.take).read(args.take)
        if dest.suffix.lower() == ".amc" and take.skeleton.meta.get("format") != "asf":
            raise ConfigError(
                f"--output {args.output}: AMC needs an ASF skeleton; {args.take} is not ASF/AMC, write .bvh"
            )
        context = [regs.motion_format(p).read(p) for p in args.context]
        params: dict[str, Any] = {"write_bvh": False, "heatmaps": bool(args.report)}
        for key in ("mode", "threshold"):
            if getattr(args, key, None) is not None:
                params[key] = getattr(args, key)
        if getattr(args, "false_alarm", None) is not None:
            import sys

            print(
                "mocapflow clean: --false-alarm is deprecated and ignored (removed next release); "
                "use --false-alarm-rate R (the share of a clean take's (frame, joint) cells flagged)",
                file=sys.stderr,
            )
        if getattr(args, "false_alarm_rate", None) is not None:
            if not 0.0 < args.false_alarm_rate < 1.0:
                raise ConfigError(f"--false-alarm-rate {args.false_alarm_rate}: a share of cells, in (0, 1)")
            params["calibrated"] = {"false_alarm_rate": args.false_alarm_rate}
        cleaner = cleaner_cls(params)
        report = Path(args.report) if args.report else None
        if report is not None:
            report.mkdir(parents=True, exist_ok=True)
        from .outputs import clean_and_write_clip

        out = clean_and_write_clip(cleaner, take, context, 0, report, regs)
        write_cleaned(out["cleaned"], dest, regs)
        if report is not None:
            for name in ("mdm", "edits"):
                with atomic_path(report / f"{name}.parquet") as tmp:
                    pq.write_table(out[name], tmp)
            with atomic_path(report / "summary.json") as tmp:
                tmp.write_text(json.dumps(out["summary"], indent=2))
        s = out["summary"]
        cal = s.get("calibration")
        print(
            f"{take.name}: {s['flagged_cells']} input frames x joints flagged ({s['decided_by']}), "
            f"{s['edited_cells']} edited, of {s['input_cells']} at {take.fps:g} fps "
            f"(largest edit {s['max_edit_deg']:.1f} deg) in {out['seconds']:.2f} s -> {dest}"
            + (
                f"; {cal['fallback']}: decided on the null shipped with the package"
                if cal and cal.get("fallback")
                else ""
            ),
            flush=True,
        )
        return 0
