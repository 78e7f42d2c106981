"""The control signal of a reconstruction from a marker take or a skeleton take.

A marker set maps each control point (canonical joint: root, head, wrists, ankles) to the
markers whose mean stands for it; a control point may list alternatives, the first whose
markers the take has wins. Labels match case-insensitively after any ``subject:`` prefix.
Skin markers sit centimetres off the joint centres the prior is made of (the ankle marker
is on the lateral malleolus; a CMU ASF wrist joint starts the distal half of the forearm,
9 cm before the wrist bar the WRA/WRB markers straddle): :func:`calibrated_control` moves
each control point by an offset calibrated per performer (:mod:`.reconstruct_calibrate`).

Built-in sets (:data:`MARKER_SETS`), covering the marker takes of the development corpus:

==========  =========================================  =====================================
set         takes                                      control points
==========  =========================================  =====================================
``vicon``   Vicon Plug-in-Gait style: CMU and HDM05    root: LFWT RFWT LBWT RBWT; head: LFHD
            C3D (``LFHD``, ``LWRA``, ``LANK``...)      RFHD LBHD RBHD; wrist: WRA WRB; ankle:
                                                       ANK (or ANK HEE)
``opensim`` OpenSim gait TRC (``R.ASIS``,              root: R.ASIS L.ASIS V.Sacral; head:
            ``L.Wrist.Lat``, ``R.Heel``...)            R.Temple L.Temple; wrist: Wrist.Med
                                                       Wrist.Lat; ankle: Ankle.Lat Ankle.Med
                                                       (or Heel)
``isb``     ISB anatomical names (Qualisys sample:     root: L_IAS R_IAS L_IPS R_IPS; head:
            ``L_IAS``, ``L_FAL``, ``L_RSP``...)        L_HDF R_HDF L_HDB R_HDB; wrist: RSP
                                                       USP (or RSP UHE); ankle: FAL TAM
==========  =========================================  =====================================

Each set also names the left pelvis markers (``vicon``: LFWT LBWT; ``opensim``: L.ASIS;
``isb``: L_IAS L_IPS; right: the same with R): the root's heading is the facing of the
left-right pelvis axis, as the hips give it for a skeleton take. ``auto`` picks the first
set whose every control point the take has.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, cast

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import Analysis, DataError, Motion, Params, StepContext, StepOutput
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.markers import Markers, to_y_up
from mocapflow.framework.normalize import facing_angles

from .reconstruct import DEFAULT_MARKERS
from .reconstruct_calibrate import Calibration

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.skeleton import Skeleton

#: What a marker set locates: the control points, and the pelvis sides that give the root's heading.
CONTROL: tuple[str, ...] = (*DEFAULT_MARKERS, "lhip", "rhip")

MarkerSet = dict[str, tuple[tuple[str, ...], ...]]


def _sides(left: tuple[tuple[str, ...], ...]) -> tuple[tuple[tuple[str, ...], ...], tuple[tuple[str, ...], ...]]:
    """Left alternatives as given, right with L->R swapped in the first letter of a label
    ('LWRA' -> 'RWRA') or after a side prefix ('L.Wrist' -> 'R.Wrist', 'L_RSP' -> 'R_RSP')."""

    def flip(label: str) -> str:
        return "R" + label[1:] if label.startswith("L") else label

    return left, tuple(tuple(flip(x) for x in alt) for alt in left)


def _set(
    root: tuple[tuple[str, ...], ...],
    head: tuple[tuple[str, ...], ...],
    wrist: tuple[tuple[str, ...], ...],
    ankle: tuple[tuple[str, ...], ...],
    pelvis: tuple[tuple[str, ...], ...],
) -> MarkerSet:
    lw, rw = _sides(wrist)
    la, ra = _sides(ankle)
    lp, rp = _sides(pelvis)
    return {"root": root, "head": head, "lwrist": lw, "rwrist": rw, "lankle": la, "rankle": ra, "lhip": lp, "rhip": rp}


#: Built-in marker sets (module doc).
MARKER_SETS: dict[str, MarkerSet] = {
    "vicon": _set(
        (("LFWT", "RFWT", "LBWT", "RBWT"),),
        (("LFHD", "RFHD", "LBHD", "RBHD"),),
        (("LWRA", "LWRB"),),
        (("LANK",), ("LANK", "LHEE")),
        (("LFWT", "LBWT"),),
    ),
    "opensim": _set(
        (("R.ASIS", "L.ASIS", "V.Sacral"),),
        (("R.Temple", "L.Temple"),),
        (("L.Wrist.Med", "L.Wrist.Lat"),),
        (("L.Ankle.Lat", "L.Ankle.Med"), ("L.Heel",)),
        (("L.ASIS",),),
    ),
    "isb": _set(
        (("L_IAS", "R_IAS", "L_IPS", "R_IPS"),),
        (("L_HDF", "R_HDF", "L_HDB", "R_HDB"),),
        (("L_RSP", "L_USP"), ("L_RSP", "L_UHE")),
        (("L_FAL", "L_TAM"),),
        (("L_IAS", "L_IPS"),),
    ),
}


def _key(label: str) -> str:
    return label.rsplit(":", 1)[-1].strip().lower()


def resolve_marker_set(markers: Markers, name: str = "auto") -> tuple[str, dict[str, tuple[str, ...]]]:
    """The set to use and, per control point, the take's labels it averages."""
    have = {_key(lb): lb for lb in markers.labels}
    names = list(MARKER_SETS) if name == "auto" else [name]
    if name != "auto" and name not in MARKER_SETS:
        raise DataError(f"unknown marker set {name!r}; known: {', '.join(MARKER_SETS)} (or auto)")
    missing: dict[str, list[str]] = {}
    for n in names:
        chosen, lacking = {}, []
        for point in CONTROL:
            alt = next((a for a in MARKER_SETS[n][point] if all(_key(x) in have for x in a)), None)
            if alt is None:
                lacking.append(f"{point} ({' or '.join('+'.join(a) for a in MARKER_SETS[n][point])})")
            else:
                chosen[point] = tuple(have[_key(x)] for x in alt)
        if not lacking:
            return n, chosen
        missing[n] = lacking
    detail = "; ".join(f"{n}: no {', '.join(v)}" for n, v in missing.items())
    raise DataError(f"markers {markers.name!r}: no marker set fits ({detail})")


def fill_gaps(x: np.ndarray, what: str) -> np.ndarray:
    """Linear interpolation over NaN frames of each trajectory (T, M, 3), held at the ends."""
    out = np.array(x, np.float64)
    t = np.arange(len(out))
    for m in range(out.shape[1]):
        ok = np.isfinite(out[:, m]).all(1)
        if not ok.any():
            raise DataError(f"{what}: control point {m} is never seen")
        if not ok.all():
            for a in range(3):
                out[:, m, a] = np.interp(t, t[ok], out[ok, m, a])
    return out


def control_from_markers(
    markers: Markers, marker_set: str = "auto"
) -> tuple[np.ndarray, np.ndarray, str, dict[str, Any]]:
    """Control points (T, 6, 3) y-up metres (:data:`~.reconstruct.DEFAULT_MARKERS` order),
    the root's heading (T,) radians from the pelvis sides, the set used and its label
    mapping; gaps are interpolated. Uncalibrated: the marker means."""
    control, heading, name, mapping, _ = calibrated_control(markers, marker_set, None)
    return control, heading, name, mapping


def _centres(y_up: Markers, mapping: dict[str, tuple[str, ...]]) -> np.ndarray:
    return np.stack([np.mean(y_up.select(list(mapping[p])).positions, axis=1) for p in CONTROL], 1)


def calibrated_control(
    markers: Markers,
    marker_set: str = "auto",
    lengths: Mapping[str, float] | None = None,
    calibration_take: Markers | None = None,
    root_offset: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, str, dict[str, Any], Calibration | None]:
    """:func:`control_from_markers` with each control point moved by its offset to the joint
    centre (:mod:`.reconstruct_calibrate`), estimated from the first seconds of the take or
    of ``calibration_take`` (the same performer and marker set) with the skeleton's bone
    ``lengths`` (canonical joint -> metres); ``lengths=None``: no calibration (the marker
    means); ``root_offset`` the skeleton's root - mid-hip vector
    (:func:`~.reconstruct_calibrate.root_from_hips`; None: the root keeps the pelvis markers'
    mean). Also returns the calibration."""
    from .reconstruct_calibrate import apply_offsets, calibrate

    y_up = to_y_up(markers)
    name, mapping = resolve_marker_set(y_up, marker_set)
    pos = _centres(y_up, mapping)
    what = f"markers {markers.name!r}"
    heading = facing_angles(fill_gaps(pos, what), CONTROL)
    points = tuple(DEFAULT_MARKERS)
    cal = None
    if lengths is not None:
        if calibration_take is None:
            cal = calibrate(y_up, pos[:, : len(points)], name, points, dict(lengths), root_offset=root_offset)
        else:
            c_up = to_y_up(calibration_take)
            try:
                _, c_map = resolve_marker_set(c_up, name)
            except DataError as e:
                raise DataError(f"calibration take {calibration_take.name!r}: {e}") from None
            cal = calibrate(
                c_up,
                _centres(c_up, c_map)[:, : len(points)],
                name,
                points,
                dict(lengths),
                seconds=float("inf"),
                source=f"calibration take {calibration_take.name!r}",
                root_offset=root_offset,
            )
        pos = np.concatenate([apply_offsets(y_up, pos[:, : len(points)], name, cal), pos[:, len(points) :]], 1)
    pos = fill_gaps(pos, what)
    return pos[:, : len(points)], heading, name, mapping, cal


def control_from_motion(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Control points (T, 6, 3) of a skeleton take (its canonical end effectors, head and
    root) and the root's heading (T,) from its hips."""
    idx = motion.skeleton.canonical_indices(CONTROL)
    if (idx < 0).any():
        missing = [p for p, i in zip(CONTROL, idx, strict=True) if i < 0]
        raise DataError(f"motion {motion.name!r}: its skeleton has no joint for {missing}")
    pos = motion.canonical_positions(CONTROL)
    return pos[:, : len(DEFAULT_MARKERS)], facing_angles(pos, CONTROL)


def dataset_markers(ds: Dataset) -> list[tuple[int, Markers]]:
    """(clip_id, Markers) of every take of a ``formats.load_markers`` dataset."""
    clips = ds.table("clips").to_pylist()
    data = ds.table("data")
    ids = data.column("clip_id").to_numpy()
    flat = data.column("positions").combine_chunks()
    values = flat.values.to_numpy(zero_copy_only=False).astype(np.float64)
    offsets = flat.offsets.to_numpy()
    out = []
    for c in clips:
        rows = np.flatnonzero(ids == c["clip_id"])
        m = int(c["n_markers"])
        pos = np.concatenate([values[offsets[r] : offsets[r + 1]] for r in rows]) if len(rows) else np.zeros(0)
        meta = {"up_axis": c["up_axis"] or "+y", "path": c["path"], "format": c["format"]}
        out.append(
            (int(c["clip_id"]), Markers(tuple(c["labels"]), pos.reshape(len(rows), m, 3), c["fps"], c["name"], meta))
        )
    return out


class ReconstructMarkersParams(Params):
    skeleton: str = Field(..., description="the performer's skeleton: an .asf, or a .bvh/.amc take (pipeline-relative)")
    marker_set: str = Field("auto", description=f"marker set: {', '.join(MARKER_SETS)} or auto")
    k: int = Field(128, ge=2, description="neighbours of the local linear model")


FIT = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("marker_set", pa.string()),
        ("n_frames", pa.int32()),
        ("fit_mean_cm", pa.float64()),
        ("fit_max_cm", pa.float64()),
        ("frames_per_s", pa.float64()),
        ("confidence_mean", pa.float64()),
        ("confidence_min", pa.float64()),
        ("low_confidence_share", pa.float64()),
    ]
)


OFFSETS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("point", pa.string()),
        ("x_cm", pa.float64()),
        ("y_cm", pa.float64()),
        ("z_cm", pa.float64()),
        ("norm_cm", pa.float64()),
        ("calibrated", pa.bool_()),
    ]
)


class ReconstructMarkers(Analysis):
    """Full-body motion of marker takes (a ``formats.load_markers`` dataset) on the
    performer's skeleton, with a ``reconstruction_prior``: what ``mocapflow reconstruct`` does.

    Tables: ``data``/``clips``/``skeletons`` (the reconstructions, exportable as BVH/AMC) and
    ``fit`` (per take: how far the output's control joints are from the (calibrated) control
    points, cm) and ``offsets`` (per take and control point: the calibrated offset from the
    marker mean to the joint centre, cm in the segment frame, :mod:`.reconstruct_calibrate`;
    self-calibrated from each take's first seconds).
    """

    name = "reconstruct_markers"
    inputs: ClassVar[Mapping[str, bool]] = {"prior": True, "markers": True}
    Params = ReconstructMarkersParams
    params: ReconstructMarkersParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.motion_tables import motions_to_tables

        from .reconstruct import PosePrior, ReconstructParams, reconstruct
        from .reconstruct_calibrate import root_from_hips
        from .reconstruct_prior import skeleton_view
        from .reconstruct_steps import CONFIDENCE, confidence_table, open_prior
        from .retarget import positions_to_motion

        p = self.params
        skeleton = read_skeleton(ctx.resolve(p.skeleton), ctx.registries)
        store = open_prior(inputs["prior"])
        # any skeleton: the prior seen on the canonical joints this skeleton has (spine rule, composite bones)
        skeleton, view, lengths = skeleton_view(store, skeleton)
        prior = PosePrior.build(view, lengths)
        rest = Motion(skeleton, np.zeros((1, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (1, skeleton.n_joints, 1)), 30.0)
        motions, ids, rows = [], [], []
        by_joint = dict(zip(prior.joints, prior.lengths, strict=True))
        hips = ("root", "lhip", "rhip")
        root_offset = root_from_hips(dict(zip(hips, rest.canonical_positions(hips)[0], strict=True)))
        offset_rows: list[dict[str, Any]] = []
        confidences: list[pa.Table] = []
        for cid, mk in dataset_markers(inputs["markers"]):
            control, heading, set_name, _, cal = calibrated_control(mk, p.marker_set, by_joint, None, root_offset)
            if cal is not None:
                offset_rows += [{"clip_id": cid, "name": mk.name, **r} for r in cal.rows()]
            t0 = time.perf_counter()
            rec = reconstruct(control, prior, ReconstructParams(k=p.k), root_heading=heading, fps=mk.fps)
            world = rec.positions
            confidences.append(confidence_table(cid, rec))
            seconds = time.perf_counter() - t0
            m = positions_to_motion(
                skeleton, world, prior.joints, mk.fps, name=mk.name, metadata={"reconstructed_from": mk.name}
            )
            fit = np.linalg.norm(m.canonical_positions(DEFAULT_MARKERS) - control, axis=-1) * 100
            motions.append(m)
            ids.append(cid)
            rows.append(
                {
                    "clip_id": cid,
                    "name": mk.name,
                    "marker_set": set_name,
                    "n_frames": mk.n_frames,
                    "fit_mean_cm": float(fit.mean()) if fit.size else 0.0,
                    "fit_max_cm": float(fit.max()) if fit.size else 0.0,
                    "frames_per_s": mk.n_frames / max(seconds, 1e-9),
                    "confidence_mean": float(rec.confidence.mean()) if len(rec.confidence) else 0.0,
                    "confidence_min": float(rec.confidence.min()) if len(rec.confidence) else 0.0,
                    "low_confidence_share": float((rec.confidence < 0.5).mean()) if len(rec.confidence) else 0.0,
                }
            )
        tables = motions_to_tables(motions, ids)
        tables["fit"] = pa.Table.from_pylist(rows, schema=FIT)
        tables["offsets"] = pa.Table.from_pylist(offset_rows, schema=OFFSETS)
        tables["confidence"] = pa.concat_tables(confidences) if confidences else CONFIDENCE.empty_table()
        return StepOutput(tables, {"takes": len(rows), "prior_frames": len(prior.poses), "skeleton": skeleton.name})


def read_skeleton(path: Path, reg: Any) -> Skeleton:
    from mocapflow.framework.errors import ConfigError

    if not path.is_file():
        raise ConfigError(f"skeleton {path}: no such file")
    for _, cls in reg.by_kind["formats"]:  # a skeleton file (ASF) read as it is
        if path.suffix.lower() in cls.extensions and cls.produces == "skeleton":
            return cast("Skeleton", cls().read(path))
    return cast("Skeleton", reg.motion_format(path).read(path).skeleton)
