"""``mocapflow reconstruct``: a skeleton take (BVH/AMC) from a marker take or a take's end effectors.

    mocapflow reconstruct take.c3d --prior runs/reconstruct/prior --skeleton 16.asf -o take.bvh
    mocapflow reconstruct take.trc --marker-set opensim --prior "data/**/*.amc" --skeleton s.bvh -o out.amc
    mocapflow reconstruct 16_15.amc --prior runs/reconstruct/prior -o 16_15_recon.bvh
    mocapflow reconstruct take.c3d --calibration rom.c3d --prior P --skeleton 16.asf -o take.bvh

The input is a C3D/TRC marker take (a marker set maps its labels to the 6 control points,
:mod:`.reconstruct_markers`) or a BVH/AMC take whose end effectors, head and root are the
control points. A marker take's control points are moved onto the joint centres by
offsets calibrated per performer (:mod:`.reconstruct_calibrate`; ``--calibration``: ``self``,
the default, from the take's first 10 s; a calibration take of the same performer; ``off``),
printed per control point in cm in its segment frame. The output skeleton (``--skeleton``: ASF, or the skeleton of a BVH/AMC
file; default for a skeleton take: its own) gives the bone lengths the prior is retargeted
to. ``--prior`` is a prior store (a ``reconstruction_prior`` step's folder or its
``prior`` subfolder, memory-mapped) or motion files (a glob; built in memory). The take is
reconstructed at its own rate and written atomically.
"""

from __future__ import annotations

import argparse
import glob
import sys
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from mocapflow.framework import Motion
    from mocapflow.framework.commands import CommandContext
    from mocapflow.framework.markers import Markers
    from mocapflow.framework.registry import Registries
    from mocapflow.framework.skeleton import Skeleton

    from .reconstruct import Reconstruction
    from .reconstruct_prior import PriorStore


class ReconstructCommand:
    """``mocapflow reconstruct INPUT --prior PRIOR -o OUT``: full-body motion from 6 control points."""

    name = "reconstruct"
    help = "full-body motion (BVH/AMC) from a marker take (C3D/TRC) or a take's end effectors"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("input", help="C3D/TRC marker take, or a BVH/AMC take (its end effectors are used)")
        parser.add_argument("--prior", required=True, help="prior store folder, or a glob of motion files")
        parser.add_argument("-o", "--out", required=True, help="output take (.bvh or .amc)")
        parser.add_argument("--skeleton", help="output skeleton: .asf, or a .bvh/.amc take (default: the input's)")
        parser.add_argument("--marker-set", default="auto", help="vicon, opensim, isb or auto (default)")
        parser.add_argument(
            "--calibration",
            default="self",
            metavar="TAKE|self|off",
            help="marker offsets to the joint centres: 'self' (default) from the take's first 10 s, a "
            "calibration marker take (C3D/TRC) of the same performer, or 'off' (the marker means)",
        )
        from mocapflow.framework.options import int_at_least

        parser.add_argument(
            "-k", type=int_at_least(2), default=128, help="neighbours of the local model (default 128; at least 2)"
        )
        parser.add_argument(
            "--confidence",
            metavar="FILE.csv",
            help="also write the per-frame confidence (frame, time_s, confidence, novelty, misfit_cm, reach_cm, limit)",
        )

    @classmethod
    def run(cls, args: argparse.Namespace, ctx: CommandContext) -> int:
        import numpy as np

        from mocapflow.framework import Motion
        from mocapflow.framework.errors import ConfigError
        from mocapflow.framework.output_paths import refuse_dataset_path

        from .reconstruct import PosePrior, ReconstructParams, reconstruct
        from .reconstruct_calibrate import root_from_hips
        from .reconstruct_markers import calibrated_control, control_from_motion, read_skeleton
        from .reconstruct_prior import PriorStore, build_store, skeleton_view
        from .retarget import positions_to_motion

        reg = ctx.registries(["formats"])  # honours --block; third parties' readers too
        src, out = Path(args.input), refuse_dataset_path(args.out, "--out")
        if not src.is_file():
            raise ConfigError(f"{src}: no such file")
        if out.suffix.lower() not in (".bvh", ".amc"):
            raise ConfigError(f"--out {out}: expected a .bvh or .amc file name")
        conf_out = refuse_dataset_path(args.confidence, "--confidence") if args.confidence else None
        if conf_out is not None and conf_out.suffix.lower() != ".csv":
            raise ConfigError(f"--confidence {conf_out}: expected a .csv file name")
        skeleton_take: Motion | None = None
        markers = None
        if src.suffix.lower() in (".c3d", ".trc"):
            markers = _read_markers(src, reg)
            fps = markers.fps
        else:
            skeleton_take = reg.motion_format(src).read(src)
            control, heading = control_from_motion(skeleton_take)
            fps, what = skeleton_take.fps, "end effectors, head and root"
        if args.skeleton:
            skeleton = read_skeleton(Path(args.skeleton), reg)
        elif skeleton_take is not None:
            skeleton = skeleton_take.skeleton
        else:
            raise ConfigError("a marker take needs --skeleton (an .asf, .bvh or .amc of the performer's skeleton)")

        t0 = time.perf_counter()
        store = _open_prior(args.prior, reg, PriorStore, build_store)
        # any skeleton: the prior seen on the canonical joints this skeleton has (spine rule, composite bones)
        skeleton, view, lengths = skeleton_view(store, skeleton)
        joints = view.joints
        calibration = None
        if markers is None and args.calibration not in ("self", "off"):
            raise ConfigError(f"--calibration {args.calibration}: a calibration take is for a marker take (C3D/TRC)")
        if markers is not None:
            cal_take = None
            if args.calibration not in ("self", "off"):
                cal_path = Path(args.calibration)
                if not cal_path.is_file():
                    raise ConfigError(f"--calibration {cal_path}: no such file (a C3D/TRC take, 'self' or 'off')")
                cal_take = _read_markers(cal_path, reg)
            by_joint = None if args.calibration == "off" else dict(zip(joints, lengths, strict=True))
            rest = Motion(skeleton, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, skeleton.n_joints, 1)), fps)
            hips = ("root", "lhip", "rhip")
            root_offset = root_from_hips(dict(zip(hips, rest.canonical_positions(hips)[0], strict=True)))
            control, heading, set_name, mapping, calibration = calibrated_control(
                markers, args.marker_set, by_joint, cal_take, root_offset
            )
            what = f"marker set {set_name}: " + "; ".join(f"{p} = {'+'.join(v)}" for p, v in mapping.items())
        prior = PosePrior.build(view, lengths)
        t1 = time.perf_counter()
        rec = reconstruct(control, prior, ReconstructParams(k=args.k), root_heading=heading, fps=fps)
        world = rec.positions
        t2 = time.perf_counter()
        motion = positions_to_motion(
            skeleton, world, prior.joints, fps, name=out.stem, metadata={"reconstructed_from": str(src)}
        )
        reg.motion_format(out, writing=True).write_atomic(motion, out)
        fit = (
            np.linalg.norm(
                motion.canonical_positions(("root", "head", "lwrist", "rwrist", "lankle", "rankle")) - control, axis=-1
            )
            * 100
        )
        print(f"{src}: {len(control)} frames at {fps:g} Hz; control points from {what}")
        print(f"skeleton {skeleton.name or out.stem}: {len(joints)} pose joints; spine " + _spine_text(skeleton))
        if markers is not None:
            print(calibration.describe() if calibration is not None else "offsets: none (--calibration off)")
        print(f"prior: {len(store.clips)} takes, {len(prior.poses)} frames, ready in {t1 - t0:.1f} s")
        print(f"reconstructed in {t2 - t1:.1f} s ({len(control) / max(t2 - t1, 1e-9):.0f} frames/s)")
        print(f"control points on the output skeleton: mean {fit.mean():.1f} cm, max {fit.max():.1f} cm off")
        low = np.flatnonzero(rec.confidence < 0.5)
        print(
            f"confidence: mean {rec.confidence.mean():.2f}, {len(low)} of {len(rec.confidence)} frames below 0.5"
            + (f" (first at frame {int(low[0])})" if len(low) else "")
        )
        if len(low) > 0.25 * len(rec.confidence):
            print(
                f"warning: {len(low) / len(rec.confidence):.0%} of the frames have a confidence below 0.5: the prior "
                "holds few poses like these (see --confidence for which frames)",
                file=sys.stderr,
            )
        print(f"wrote {out}")
        if conf_out is not None:
            _write_confidence(conf_out, rec, fps)
            print(f"wrote {conf_out}")
        return 0


def _write_confidence(path: Path, rec: Reconstruction, fps: float) -> None:
    """The per-frame confidence as CSV, written atomically (:func:`~mocapflow.framework.workspace.atomic_path`)."""
    import numpy as np

    from mocapflow.framework.workspace import atomic_path

    n = len(rec.confidence)
    cols = np.column_stack(
        [np.arange(n), np.arange(n) / fps, rec.confidence, rec.novelty, rec.misfit * 100, rec.reach * 100, rec.limit]
    )
    with atomic_path(path) as tmp:
        np.savetxt(
            tmp,
            cols,
            fmt=["%d", "%.6f", "%.4f", "%.4f", "%.3f", "%.3f", "%.4f"],
            delimiter=",",
            header="frame,time_s,confidence,novelty,misfit_cm,reach_cm,limit",
            comments="",
        )


def _spine_text(skeleton: Skeleton) -> str:
    """``root > chest (Spine) > ...``: the spine joints the rule found, with the skeleton's names."""
    chain = ("root", "lowerback", "upperback", "chest", "neck", "head")
    return " > ".join(f"{j} ({skeleton.names[skeleton.canonical[j]]})" for j in chain if j in skeleton.canonical)


def _read_markers(path: Path, reg: Registries) -> Markers:
    from mocapflow.framework.errors import ConfigError

    for _, cls in reg.by_kind["formats"]:
        if path.suffix.lower() in cls.extensions and cls.produces == "markers":
            return cast("Markers", cls().read(path))
    raise ConfigError(f"{path}: no registered marker reader for {path.suffix!r} files")


def _open_prior(
    spec: str, reg: Registries, store_cls: type[PriorStore], build: Callable[[Iterable[Motion]], PriorStore]
) -> PriorStore:
    from mocapflow.framework.errors import ConfigError

    p = Path(spec)
    for folder in (p, p / "prior"):
        if (folder / "clips.json").is_file():
            return store_cls.load(folder)
    files = sorted(Path(f) for f in glob.glob(spec, recursive=True) if Path(f).is_file())
    if not files:
        raise ConfigError(f"--prior {spec}: neither a prior store (clips.json) nor motion files")
    return build(reg.motion_format(f).read(f) for f in files)
