"""Per-performer offsets from skin markers to the joint centres of the prior.

A control point of a marker set is the mean of its markers (:mod:`.reconstruct_markers`);
the joint it stands for sits a constant vector away **in the frame of its segment** (the
pelvis for the root, the distal forearm for a wrist, the shank for an ankle). Each segment
frame is made of the take's markers on that segment (:data:`SEGMENTS`): ``x`` along the
difference of two marker groups, ``y`` along a second difference made orthogonal to ``x``,
``z = x × y``; origin the control point. The calibrated control point of frame ``t`` is ``c_t + R_t o``.

The offset ``o`` is estimated without ground-truth joints, from the markers of a
calibration window (the take's own first :data:`CALIBRATION_SECONDS`, or a calibration take
of the same performer) and the performer's skeleton (its bone lengths): the joint lies
on the line from the proximal joint's landmark (the *anchor*: the elbow marker for a wrist,
the knee marker for an ankle) through the control point, one skeleton bone length
(elbow-wrist, knee-ankle) from the anchor. The median of that point in the segment frame
over the window is ``o``. This puts the control
point where the skeleton's joint is by *definition* (a CMU ASF ``lwrist`` joint starts the
distal half of the forearm, 9 cm before the wrist bar) as well as where the skin is.
The root (pelvis frame from the pelvis markers) is put where the skeleton has it relative
to its hips: each hip centre is the centre of the sphere the knee marker moves on in the
pelvis frame (a functional joint centre: least squares over the window; it needs hip motion
there, else the whole take's, else the root keeps the markers' mean, reported), and the root sits the rest pose's
root - mid-hip vector (:func:`root_from_hips`) from their midpoint, the pelvis markers' frame
taken for the skeleton's root frame. The head is not calibrated: a head point moved by a
rule (one head bone below the head markers, or a neck-head bone from the C7/clavicle
markers) lost against the markers' mean (measured). A control point whose segment or anchor markers a set lacks keeps a zero offset
(reported as such).

Measured (CMU 135_02, its AMC as truth, calibrated on the first 10 s, evaluated on the
rest): docs/knn.md, "How the reconstruction's default was chosen".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from mocapflow.framework import DataError
from mocapflow.framework.markers import Markers

#: Seconds at the start of a take that calibrate it (the whole take when shorter).
CALIBRATION_SECONDS = 10.0
#: Fewest frames with every calibration marker seen that a calibration accepts.
MIN_CALIBRATION_FRAMES = 10

Groups = tuple[tuple[str, ...], tuple[str, ...]]


@dataclass(frozen=True)
class Segment:
    """How one control point is calibrated: ``x``/``y`` axes as (plus labels, minus labels)
    mean differences (an empty minus group: the control point itself), the ``anchor``
    labels (the proximal joint's landmark) and the skeleton bone (canonical parent, joint)
    whose length separates the anchor from the joint. ``hips``: the root's rule instead (module
    doc): ``anchor`` the left and right knee markers, ``bone`` the canonical hips."""

    x: Groups
    y: Groups
    anchor: tuple[str, ...]
    bone: tuple[str, str]
    hips: bool = False


def _flip(label: str) -> str:
    if label.startswith("L"):
        return "R" + label[1:]
    return label


def _mirror(seg: Segment) -> Segment:
    def f(g: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(_flip(x) for x in g)

    return Segment(
        (f(seg.x[0]), f(seg.x[1])),
        (f(seg.y[0]), f(seg.y[1])),
        f(seg.anchor),
        (seg.bone[0].replace("l", "r", 1), seg.bone[1].replace("l", "r", 1)),
    )


def _limbs(wrist: Segment | None, ankle: Segment | None) -> dict[str, Segment]:
    out: dict[str, Segment] = {}
    if wrist is not None:
        out["lwrist"], out["rwrist"] = wrist, _mirror(wrist)
    if ankle is not None:
        out["lankle"], out["rankle"] = ankle, _mirror(ankle)
    return out


#: Per marker set, the calibrated control points (module doc); the sets of
#: :data:`.reconstruct_markers.MARKER_SETS`.
SEGMENTS: dict[str, dict[str, Segment]] = {
    "vicon": {
        "root": Segment(
            (("LFWT", "LBWT"), ("RFWT", "RBWT")),
            (("LFWT", "RFWT"), ("LBWT", "RBWT")),
            ("LKNE", "RKNE"),
            ("lhip", "rhip"),
            True,
        ),
        **_limbs(
            Segment((("LWRA",), ("LWRB",)), (("LELB",), ()), ("LELB",), ("lelbow", "lwrist")),
            Segment((("LKNE",), ()), (("LSHN",), ()), ("LKNE",), ("lknee", "lankle")),
        ),
    },
    "opensim": _limbs(
        Segment((("L.Wrist.Lat",), ("L.Wrist.Med",)), (("L.Elbow",), ()), ("L.Elbow",), ("lelbow", "lwrist")),
        None,
    ),
    "isb": {
        "root": Segment(
            (("L_IAS", "L_IPS"), ("R_IAS", "R_IPS")),
            (("L_IAS", "R_IAS"), ("L_IPS", "R_IPS")),
            ("L_FLE", "R_FLE"),
            ("lhip", "rhip"),
            True,
        ),
        **_limbs(
            Segment((("L_RSP",), ()), (("L_HLE", "L_HME"), ()), ("L_HLE", "L_HME"), ("lelbow", "lwrist")),
            Segment((("L_FLE", "L_FME"), ()), (("L_TTC",), ()), ("L_FLE", "L_FME"), ("lknee", "lankle")),
        ),
    },
}


@dataclass(frozen=True)
class Calibration:
    """Offsets (P, 3) metres in each control point's segment frame, per control point of
    ``points``; ``calibrated`` (P,) whether a point was estimated (else zero), ``frames``
    the calibration frames used, ``source`` what they came from, ``axes`` per point what its
    segment frame's x and y point along ("" if not calibrated)."""

    points: tuple[str, ...]
    offsets: np.ndarray
    calibrated: np.ndarray
    frames: int
    source: str
    axes: tuple[str, ...] = ()

    def rows(self) -> list[dict[str, Any]]:
        """One row per control point: offsets in cm along the segment axes."""
        return [
            {
                "point": p,
                "x_cm": float(o[0] * 100),
                "y_cm": float(o[1] * 100),
                "z_cm": float(o[2] * 100),
                "norm_cm": float(np.linalg.norm(o) * 100),
                "calibrated": bool(c),
            }
            for p, o, c in zip(self.points, self.offsets, self.calibrated, strict=True)
        ]

    def describe(self) -> str:
        parts = [
            f"{r['point']} ({r['x_cm']:+.1f}, {r['y_cm']:+.1f}, {r['z_cm']:+.1f}) |{r['norm_cm']:.1f}|"
            + (f" [{a}]" if a else "")
            if r["calibrated"]
            else f"{r['point']} not calibrated"
            for r, a in zip(self.rows(), self.axes or ("",) * len(self.points), strict=True)
        ]
        return f"offsets from {self.source} ({self.frames} frames), cm in the segment frame: " + "; ".join(parts)


def _keys(markers: Markers) -> dict[str, int]:
    return {lb.rsplit(":", 1)[-1].strip().lower(): i for i, lb in enumerate(markers.labels)}


def _mean(pos: np.ndarray, keys: dict[str, int], labels: tuple[str, ...]) -> np.ndarray:
    return cast("np.ndarray", np.mean(pos[:, [keys[x.lower()] for x in labels]], axis=1))


def segment_frames(pos: np.ndarray, keys: dict[str, int], seg: Segment, centre: np.ndarray) -> np.ndarray:
    """Rotation (T, 3, 3) of a segment, its columns the segment's x, y, z axes (module doc);
    NaN where a marker is missing or the axes are degenerate."""

    def axis(g: Groups) -> np.ndarray:
        plus = _mean(pos, keys, g[0])
        return cast("np.ndarray", plus - (_mean(pos, keys, g[1]) if g[1] else centre))

    x, y = axis(seg.x), axis(seg.y)
    with np.errstate(invalid="ignore", divide="ignore"):
        x = x / np.linalg.norm(x, axis=-1, keepdims=True)
        y = y - np.sum(y * x, axis=-1, keepdims=True) * x
        y = y / np.linalg.norm(y, axis=-1, keepdims=True)
    z = np.cross(x, y)
    rot = np.stack([x, y, z], axis=-1)
    bad = ~np.isfinite(rot).all(axis=(1, 2)) | (np.abs(np.linalg.det(np.nan_to_num(rot)) - 1) > 1e-3)
    rot[bad] = np.nan
    return rot


def _segments_of(set_name: str, keys: dict[str, int], points: tuple[str, ...]) -> dict[str, Segment]:
    """The set's segments whose every marker the take has."""
    out = {}
    for p, seg in SEGMENTS.get(set_name, {}).items():
        labels = (*seg.x[0], *seg.x[1], *seg.y[0], *seg.y[1], *seg.anchor)
        if p in points and all(x.lower() in keys for x in labels):
            out[p] = seg
    return out


def calibrate(
    markers: Markers,
    centres: np.ndarray,
    set_name: str,
    points: tuple[str, ...],
    lengths: dict[str, float],
    seconds: float = CALIBRATION_SECONDS,
    source: str | None = None,
    root_offset: np.ndarray | None = None,
) -> Calibration:
    """Offsets of ``points`` from the first ``seconds`` of a take (module doc).

    markers : the take's markers, y up (as the control points)
    centres : (T, P, 3) the control points (marker means, NaN where unseen), metres
    lengths : skeleton bone length per canonical joint (from its canonical parent), metres
    root_offset : (3,) the skeleton's root - mid-hip vector (:func:`root_from_hips`); None:
        the root is not calibrated
    """
    keys = _keys(markers)
    total = len(centres)
    n = total if not np.isfinite(seconds) else min(total, max(1, int(round(seconds * markers.fps))))
    segs = _segments_of(set_name, keys, points)
    offsets = np.zeros((len(points), 3))
    done = np.zeros(len(points), bool)
    used, notes = n, []
    for p, seg in segs.items():
        i = points.index(p)
        if seg.hips:
            if root_offset is None:
                continue
            hips = _hip_centres(markers.positions[:n], keys, seg, centres[:n, i], lengths)
            if hips is None and n < total:  # e.g. a T-pose first: the whole take
                hips = _hip_centres(markers.positions, keys, seg, centres[:, i], lengths)
                if hips is not None:
                    notes.append(f"{p}: the whole take, no hip motion in the first seconds")
            if hips is None:
                notes.append(f"{p}: no hip motion")
                continue
            offsets[i] = hips + np.asarray(root_offset, np.float64)
            done[i] = True
            continue
        bone = float(lengths.get(seg.bone[1], np.nan))
        if not np.isfinite(bone) or bone <= 0:
            continue
        local = _rule_offsets(markers.positions[:n], keys, seg, centres[:n, i], bone)
        ok = np.isfinite(local).all(axis=1)
        if ok.sum() < MIN_CALIBRATION_FRAMES and n < total:  # the window is occluded: the whole take
            local = _rule_offsets(markers.positions, keys, seg, centres[:, i], bone)
            ok = np.isfinite(local).all(axis=1)
            notes.append(f"{p}: the whole take, the first seconds lack its markers")
        if ok.sum() < MIN_CALIBRATION_FRAMES:
            labels = ", ".join(sorted(set(seg.anchor + seg.x[0] + seg.x[1] + seg.y[0] + seg.y[1])))
            raise DataError(
                f"markers {markers.name!r}: {int(ok.sum())} of its {total} frames see every marker that calibrates "
                f"{p} ({labels}); need >= {MIN_CALIBRATION_FRAMES} (give a longer take or a calibration take, "
                "or turn calibration off)"
            )
        offsets[i] = np.median(local[ok], axis=0)
        done[i] = True
        used = min(used, int(ok.sum()))
    axes = tuple(_axes(segs[p]) if done[i] else "" for i, p in enumerate(points))
    what = source or f"the first {n / markers.fps:.1f} s of {markers.name!r}"
    if notes:
        what += f" ({'; '.join(notes)})"
    return Calibration(points, offsets, done, used, what, axes)


#: A hip centre fit is kept when the knee marker's distances to it scatter less than this (m)
#: and the sphere's radius is within this factor of the thigh bone.
HIP_FIT_RESIDUAL, HIP_FIT_RADIUS = 0.02, 1.5


def _hip_centres(
    pos: np.ndarray, keys: dict[str, int], seg: Segment, centre: np.ndarray, lengths: dict[str, float]
) -> np.ndarray | None:
    """Midpoint (3,) in the pelvis frame of the two functional hip centres: the centre of the
    sphere each knee marker moves on in the pelvis frame (linear least squares); None when
    a fit is ill-posed (too little hip motion, a poor sphere)."""
    rot = segment_frames(pos, keys, seg, centre)
    out = []
    for label, hip in zip(seg.anchor, seg.bone, strict=True):
        knee = hip.replace("hip", "knee")
        thigh = float(lengths.get(knee, np.nan))
        local = np.einsum("tij,ti->tj", rot, pos[:, keys[label.lower()]] - centre)
        local = local[np.isfinite(local).all(axis=1)]
        if len(local) < MIN_CALIBRATION_FRAMES or not np.isfinite(thigh):
            return None
        a = np.c_[2 * local, np.ones(len(local))]
        sol, *_ = np.linalg.lstsq(a, (local**2).sum(1), rcond=None)
        c = sol[:3]
        r2 = sol[3] + c @ c
        if not r2 > 0:
            return None
        r = float(np.sqrt(r2))
        spread = np.abs(np.linalg.norm(local - c, axis=1) - r).mean()
        if spread > HIP_FIT_RESIDUAL or not thigh / HIP_FIT_RADIUS < r < thigh * HIP_FIT_RADIUS:
            return None
        if np.linalg.svd(local - local.mean(0), compute_uv=False)[-1] / np.sqrt(len(local)) < 0.01:
            return None  # the knee marker moved in a plane at best: no sphere
        out.append(c)
    return cast("np.ndarray", np.mean(out, axis=0))


def root_from_hips(rest: dict[str, np.ndarray]) -> np.ndarray | None:
    """The skeleton's root - mid-hip vector (3,) in the pelvis frame's axes (left, forward,
    down) from canonical rest positions (``root``, ``lhip``, ``rhip``: the rest pose stands
    y up); None if a joint is missing."""
    if any(j not in rest or not np.isfinite(rest[j]).all() for j in ("root", "lhip", "rhip")):
        return None
    left = rest["lhip"] - rest["rhip"]
    left = left / np.linalg.norm(left)
    up = np.array([0.0, 1.0, 0.0]) - left[1] * left
    up = up / np.linalg.norm(up)
    forward = np.cross(left, up)
    v = rest["root"] - (rest["lhip"] + rest["rhip"]) / 2
    return np.array([v @ left, v @ forward, -(v @ up)])


def _rule_offsets(pos: np.ndarray, keys: dict[str, int], seg: Segment, centre: np.ndarray, bone: float) -> np.ndarray:
    """Per frame (T, 3): the joint by the module's rule, in the segment frame; NaN where unseen."""
    rot = segment_frames(pos, keys, seg, centre)
    anchor = _mean(pos, keys, seg.anchor)
    d = centre - anchor
    with np.errstate(invalid="ignore", divide="ignore"):
        joint = anchor + bone * d / np.linalg.norm(d, axis=-1, keepdims=True)
    return cast("np.ndarray", np.einsum("tij,ti->tj", rot, joint - centre))


def _axes(seg: Segment) -> str:
    def diff(g: Groups) -> str:
        def one(labels: tuple[str, ...]) -> str:
            return labels[0] if len(labels) == 1 else "(" + "+".join(labels) + ")"

        return one(g[0]) + "-" + one(g[1]) if g[1] else "to " + "+".join(g[0])

    return f"x {diff(seg.x)}, y {diff(seg.y)}"


def apply_offsets(markers: Markers, centres: np.ndarray, set_name: str, calibration: Calibration) -> np.ndarray:
    """Control points (T, P, 3) moved by the calibration's offsets in each frame's segment
    frame; where a segment marker is unseen the offset vector is interpolated from the
    nearest frames that see it (the control point's own gaps stay NaN: fill them afterwards)."""
    keys = _keys(markers)
    out = np.array(centres, np.float64)
    segs = _segments_of(set_name, keys, calibration.points)
    for i, p in enumerate(calibration.points):
        if not calibration.calibrated[i]:
            continue
        if p not in segs:
            raise DataError(f"markers {markers.name!r}: lack the markers of {p}'s segment that the calibration used")
        rot = segment_frames(markers.positions, keys, segs[p], out[:, i])
        vec = np.einsum("tij,j->ti", rot, calibration.offsets[i])
        seen = np.isfinite(vec).all(axis=1)
        if seen.any() and not seen.all():  # a segment marker unseen: the offset vector interpolated
            t = np.arange(len(vec))
            for a in range(3):
                vec[:, a] = np.interp(t, t[seen], vec[seen, a])
        out[:, i] = out[:, i] + vec
    return out
