"""The 31 boolean relational features of Müller, Röder, Clausen 2005 (Table 1).

Three feature sets: lower body F_l (11 features, ids ``L1..L11``), upper body F_u
(``U1..U12``) and mixed F_m (``M1..M8``), in the order of the paper's Table 1. Each
feature is a generic primitive of :mod:`.relational_primitives` applied to canonical joints
(metres, y up) and thresholded relative to the body size of the clip's skeleton (humerus
length ``hl``, shoulder width ``sw``, hip width ``hw`` from
:func:`mocapflow.plugins.relational.body.body_measures`). The exact definitions and thresholds
are tabulated in ``docs/relational-features.md``.

The table :data:`FEATURES` is the single definition: it is compiled into a small program
(op code + joint indices per feature) that one numba kernel interprets in a single pass over
the frames (``_relational_kernels.feature_bits``, about 0.6 s per million frames on one
core); ``tests/naive/relational.py`` evaluates the same table with plain NumPy geometry.

Every threshold is a pair ``(threshold, strict)``: ``threshold`` is the single decision
value (the paper's where it gives one, e.g. 120 degrees for "bent" and one humerus length
for "hand in front"); ``strict`` is the switch-on value used only with ``hysteresis=True``
(switch on past ``strict``, off when ``threshold`` fails), which removes flicker at the cost
of slightly shorter "on" runs.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework.components import FeatureSet, Params
from mocapflow.framework.errors import ConfigError, DataError
from mocapflow.framework.joints import CANONICAL_JOINTS
from .body import body_measures

from . import primitives as prim

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.database import MotionDatabase
    from mocapflow.framework.datasets import Dataset, StepOutput
    from mocapflow.framework.motion import Motion

#: Joints substituted when a skeleton lacks one (positions are NaN there).
_FALLBACK = {"ltoes": "lankle", "rtoes": "rankle", "lfingers": "lwrist", "rfingers": "rwrist",
             "headtop": "head", "chest": "upperback", "neck": "head"}

#: Feature sets in Table 1 order: (set name, feature-id prefix, number of features).
SETS: tuple[tuple[str, str, int], ...] = (("lower", "L", 11), ("upper", "U", 12), ("mixed", "M", 8))


#: Operations of the feature program, matching the kernel op codes.
OPS: tuple[str, ...] = ("plane", "nplane", "point_segment", "segment_segment", "cos", "height", "speed")


@dataclass(frozen=True)
class FeatureDef:
    """One boolean feature: a primitive applied to canonical joints, then thresholded.

    ``op`` (one of :data:`OPS`) is applied to each tuple of joints in ``terms`` and the
    minimum over the terms is taken (several terms: "touching any leg", "torso bent").
    The feature is ``value >= threshold`` (``below``: ``value < threshold``) where the
    threshold is the :class:`RelationalFeatures.Params` pair named ``param`` times the
    body measure ``unit`` (``hl`` humerus length, ``sw`` shoulder width, ``hw`` hip width,
    ``hl/s``; ``deg`` thresholds an angle, computed as its cosine).

    Joints per op: ``plane (p1, p2, p3, q)``; ``nplane (a, b, anchor, q)`` with normal
    ``a -> b``; ``point_segment (q, a, b)``; ``segment_segment (a0, a1, b0, b1)``;
    ``cos (a0, a1, b0, b1)``: angle between ``a0 -> a1`` and ``b0 -> b1``; ``height (q)``
    above the lowest joint of the frame; ``speed (q[, reference])``.
    """

    id: str
    name: str
    description: str
    param: str
    unit: str
    below: bool
    op: str
    terms: tuple[tuple[str, ...], ...]

    @property
    def definition(self) -> str:
        """Human-readable definition (as in docs/relational-features.md)."""
        if self.op == "cos":
            body = ", ".join(f"angle({a}->{b}, {c}->{d})" for a, b, c, d in self.terms)
            return body if len(self.terms) == 1 else f"max({body})"
        if self.op == "speed":
            t = self.terms[0]
            return f"speed({t[0]})" + (f" relative to {t[1]}" if len(t) > 1 else "")
        if self.op == "height":
            return f"height({self.terms[0][0]}) above the lowest joint"
        body = "; ".join(", ".join(t) for t in self.terms)
        return f"{self.op}({body})" if len(self.terms) == 1 else f"min {self.op}({body})"


def _side(r: str) -> str:
    return "right" if r == "r" else "left"


def _defs() -> tuple[FeatureDef, ...]:
    out: list[FeatureDef] = []

    def add(set_id: str, name: str, desc: str, param: str, unit: str, below: bool, op: str,
            *terms: tuple[str, ...]) -> None:
        n = sum(d.id[0] == set_id for d in out) + 1
        out.append(FeatureDef(f"{set_id}{n}", name, desc, param, unit, below, op, tuple(terms)))

    # ---- F_l: lower body -----------------------------------------------------------
    # right foot: plane (root, lankle, lhip) as in the paper's F^r; left foot mirrored
    # with two points swapped so that the normal still points forward.
    add("L", "rfoot_front", "right foot in front", "foot_front", "hl", False, "plane", ("root", "lankle", "lhip", "rtoes"))
    add("L", "lfoot_front", "left foot in front", "foot_front", "hl", False, "plane", ("root", "rhip", "rankle", "ltoes"))
    for s in "rl":
        add("L", f"{s}foot_raised", f"{_side(s)} foot raised", "foot_raised", "hl", False, "height", (f"{s}toes",))
    for s in "rl":
        add("L", f"{s}foot_fast", f"{_side(s)} foot fast", "foot_fast", "hl/s", False, "speed", (f"{s}toes",))
    for s in "rl":
        add("L", f"{s}knee_bent", f"{_side(s)} knee bent", "bent_angle", "deg", True, "cos",
            (f"{s}knee", f"{s}hip", f"{s}knee", f"{s}ankle"))
    for s, o in (("r", "l"), ("l", "r")):
        add("L", f"{s}leg_sideways", f"{_side(s)} leg sideways", "leg_sideways", "hl", False, "nplane",
            (f"{o}hip", f"{s}hip", f"{s}hip", f"{s}ankle"))
    add("L", "legs_crossed", "legs crossed", "crossed", "hw", False, "nplane", ("rhip", "lhip", "lankle", "rankle"))

    # ---- F_u: upper body -----------------------------------------------------------
    add("U", "rhand_front", "right hand in front", "hand_front", "hl", False, "plane",
        ("root", "lshoulder", "rshoulder", "rwrist"))
    add("U", "lhand_front", "left hand in front", "hand_front", "hl", False, "plane",
        ("root", "lshoulder", "rshoulder", "lwrist"))
    for s in "rl":
        add("U", f"{s}hand_raised", f"{_side(s)} hand raised", "hand_raised", "hl", False, "nplane",
            ("chest", "neck", "neck", f"{s}wrist"))
    for s, o in (("r", "l"), ("l", "r")):
        add("U", f"{s}arm_sideways", f"{_side(s)} arm sideways", "arm_sideways", "hl", False, "nplane",
            (f"{o}shoulder", f"{s}shoulder", f"{s}shoulder", f"{s}wrist"))
    for s in "rl":
        add("U", f"{s}elbow_bent", f"{_side(s)} elbow bent", "bent_angle", "deg", True, "cos",
            (f"{s}elbow", f"{s}shoulder", f"{s}elbow", f"{s}wrist"))
    for s in "rl":
        add("U", f"{s}hand_fast", f"{_side(s)} hand fast", "hand_fast", "hl/s", False, "speed", (f"{s}wrist", "root"))
    add("U", "arms_crossed", "arms crossed", "crossed", "sw", False, "nplane", ("rshoulder", "lshoulder", "lwrist", "rwrist"))
    add("U", "hands_touching", "hands touching", "touch_hands", "hl", True, "segment_segment",
        ("rwrist", "rfingers", "lwrist", "lfingers"))

    # ---- F_m: mixed ---------------------------------------------------------------
    legs = (("lhip", "lknee"), ("lknee", "lankle"), ("rhip", "rknee"), ("rknee", "rankle"))
    for s in "rl":
        add("M", f"{s}hand_leg", f"{_side(s)} hand touching any leg", "touch_leg", "hl", True, "point_segment",
            *((f"{s}wrist", a, b) for a, b in legs))
    for s in "rl":
        add("M", f"{s}hand_head", f"{_side(s)} hand touching head or neck", "touch_head", "hl", True, "point_segment",
            (f"{s}wrist", "neck", "headtop"))
    for s in "rl":
        add("M", f"{s}hand_hip", f"{_side(s)} hand touching hip area", "touch_hip", "hl", True, "point_segment",
            (f"{s}wrist", "lhip", "rhip"))
    # the paper takes the larger of the two spine-thigh angles, i.e. the smaller cosine
    add("M", "torso_bent", "torso bent", "torso_bent_angle", "deg", True, "cos",
        ("root", "neck", "lhip", "lknee"), ("root", "neck", "rhip", "rknee"))
    add("M", "root_fast", "root fast", "root_fast", "hl/s", False, "speed", ("root",))
    return tuple(out)


FEATURES: tuple[FeatureDef, ...] = _defs()
FEATURE_IDS: tuple[str, ...] = tuple(d.id for d in FEATURES)
FEATURE_NAMES: tuple[str, ...] = tuple(d.name for d in FEATURES)
#: Column slice of each feature set in the 31-column output.
SET_SLICES: dict[str, slice] = {}
_start = 0
for _name, _prefix, _n in SETS:
    SET_SLICES[_name] = slice(_start, _start + _n)
    _start += _n
assert _start == len(FEATURES) == 31


def feature_column(key: str) -> int:
    """Column (0..30) of a feature given its id (``"L3"``, case-insensitive) or name (``"rfoot_raised"``)."""
    k = key.strip()
    for i, d in enumerate(FEATURES):
        if k.upper() == d.id or k.lower() == d.name:
            return i
    raise ConfigError(f"unknown relational feature {key!r}; known: {', '.join(FEATURE_IDS)} or names like {FEATURE_NAMES[0]!r}")


def feature_set_of(column: int) -> str:
    """Name of the feature set (``lower``, ``upper``, ``mixed``) holding a column."""
    for name, sl in SET_SLICES.items():
        if sl.start <= column < sl.stop:
            return name
    raise ConfigError(f"feature column {column} out of range 0..30")


def relational_features(positions: np.ndarray, fps: float, measures: Mapping[str, np.ndarray | float],
                        params: RelationalFeatures.Params | None = None,
                        offsets: np.ndarray | None = None) -> np.ndarray:
    """The 31 features of concatenated clips, vectorised over all frames.

    Parameters
    ----------
    positions : ndarray of shape (T, 25, 3), metres
        Canonical positions (:data:`~mocapflow.framework.joints.CANONICAL_JOINTS` order).
    fps : float
        Frame rate (speeds are in humerus lengths per second).
    measures : mapping
        ``humerus_length``, ``shoulder_width``, ``hip_width`` in metres: scalars or arrays
        of shape (T,) (one value per frame when clips come from several skeletons).
    params : RelationalFeatures.Params, optional
    offsets : ndarray of int, shape (n_clips + 1,), optional
        Clip offsets; speeds and hysteresis never cross a clip boundary.

    Returns
    -------
    ndarray of bool, shape (T, 31)
        Columns in Table 1 order (:data:`FEATURE_IDS`).
    """
    params = params or RelationalFeatures.Params()
    pos = np.asarray(positions)
    if pos.ndim != 3 or pos.shape[1:] != (len(CANONICAL_JOINTS), 3):
        raise DataError(f"positions must be (T, {len(CANONICAL_JOINTS)}, 3) canonical joints, got {pos.shape}")
    if pos.dtype not in (np.float32, np.float64):
        pos = pos.astype(np.float64)
    t = pos.shape[0]
    offsets = np.array([0, t]) if offsets is None else np.asarray(offsets, dtype=np.int64)
    starts = prim.clip_starts(offsets, t)
    units = ("deg", "hl", "sw", "hw")
    scale = np.ones((t, 4), dtype=np.float32)
    for k, key in ((1, "humerus_length"), (2, "shoulder_width"), (3, "hip_width")):
        scale[:, k] = np.asarray(measures[key], dtype=np.float32)
    thr = np.empty(len(FEATURES), np.float32)
    strict = np.empty_like(thr)
    below = np.empty(len(FEATURES), bool)
    unit = np.empty(len(FEATURES), np.int64)
    for i, d in enumerate(FEATURES):
        a, b = getattr(params, d.param)
        if d.unit == "deg":  # the value is a cosine: angle < theta iff cos > cos(theta)
            thr[i], strict[i], below[i] = np.cos(np.radians(a)), np.cos(np.radians(b)), not d.below
        else:
            thr[i], strict[i], below[i] = a, b, d.below
        unit[i] = units.index(d.unit.removesuffix("/s"))
    out = np.zeros((t, len(FEATURES)), dtype=bool)
    on = np.zeros_like(out)
    if t:
        from ._feature_kernels import feature_bits

        feature_bits(np.ascontiguousarray(pos), starts, float(fps), *_program(), unit, scale, thr, strict, below, out, on)
    if params.hysteresis:
        out = prim.hysteresis(on & out, out, offsets)
    return out


def _program() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The feature table as arrays for the kernel: op codes, joint indices, term counts, fallbacks."""
    ops = np.array([OPS.index(d.op) for d in FEATURES], dtype=np.int64)
    joints = np.full((len(FEATURES), 4, 4), -1, dtype=np.int64)
    for i, d in enumerate(FEATURES):
        for k, term in enumerate(d.terms):
            joints[i, k, :len(term)] = [CANONICAL_JOINTS.index(j) for j in term]
    n_terms = np.array([len(d.terms) for d in FEATURES], dtype=np.int64)
    fallback = np.full(len(CANONICAL_JOINTS), -1, dtype=np.int64)
    for j, f in _FALLBACK.items():
        fallback[CANONICAL_JOINTS.index(j)] = CANONICAL_JOINTS.index(f)
    return ops, joints, n_terms, fallback


def feature_values(positions: np.ndarray, fps: float, starts: np.ndarray) -> np.ndarray:
    """Raw (unthresholded) values of the 31 features, shape (T, 31) float32.

    Distances in metres, speeds in m/s, angles as cosines. One compiled pass over the
    frames: the kernel interprets the feature table, so :data:`FEATURES` is the single
    definition. ``starts`` (bool, (T,)) marks each clip's first frame (speeds stay inside
    clips).
    """
    from ._feature_kernels import feature_values as kernel

    out = np.empty((positions.shape[0], len(FEATURES)), dtype=np.float32)
    if len(out):
        kernel(np.ascontiguousarray(positions), np.asarray(starts, bool), float(fps), *_program(), out)
    return out


def set_codes(bits: np.ndarray, feature_set: str) -> np.ndarray:
    """Integer code of each frame's feature vector within one set (bit ``i`` = i-th feature).

    Parameters
    ----------
    bits : ndarray of shape (T, 31), bool or 0/1
    feature_set : {"lower", "upper", "mixed"}

    Returns
    -------
    ndarray of int32, shape (T,)
    """
    sl = SET_SLICES[feature_set]
    b = np.asarray(bits[:, sl]) > 0.5
    return (b.astype(np.int32) << np.arange(b.shape[1], dtype=np.int32)).sum(axis=1, dtype=np.int32)


class RelationalFeatures(FeatureSet):
    """The 31 boolean relational features of Müller et al. 2005, Table 1 (F_l, F_u, F_m).

    Output columns are 0/1 float32 in the order of :data:`FEATURE_IDS`. As a pipeline step
    it also writes a ``codes`` table (``clip_id, frame, lower, upper, mixed``: each set's
    feature vector as an integer, bit ``i`` = the set's ``i``-th feature).
    """

    name = "relational"
    version = "1"

    class Params(Params):
        hysteresis: bool = Field(False, description="two-threshold switching (on past 'strict', off when 'threshold' fails) against flicker")
        foot_front: tuple[float, float] = Field((0.0, 0.1), description="offset of the foot plane (root, ankle, hip) to the front, humerus lengths (paper: 0)")
        foot_raised: tuple[float, float] = Field((1.0, 1.2), description="toes height above the lowest joint, humerus lengths")
        foot_fast: tuple[float, float] = Field((2.0, 2.5), description="toes speed, humerus lengths per second")
        bent_angle: tuple[float, float] = Field((120.0, 110.0), description="knee/elbow bent below this angle, degrees (paper: 120)")
        leg_sideways: tuple[float, float] = Field((0.8, 1.0), description="ankle beyond its hip along the hip axis, humerus lengths (hip widths vary too much across skeletons)")
        crossed: tuple[float, float] = Field((0.0, 0.1), description="right ankle/wrist past the left one along the hip/shoulder axis, hip/shoulder widths")
        hand_front: tuple[float, float] = Field((1.0, 1.2), description="offset of the body plane (root, shoulders) to the front, humerus lengths (paper: 1)")
        hand_raised: tuple[float, float] = Field((0.0, 0.2), description="wrist above the neck along chest->neck, humerus lengths (paper: neck height)")
        arm_sideways: tuple[float, float] = Field((1.0, 1.2), description="wrist beyond its shoulder along the shoulder axis, humerus lengths")
        hand_fast: tuple[float, float] = Field((2.0, 2.5), description="wrist speed relative to the root, humerus lengths per second")
        touch_hands: tuple[float, float] = Field((0.5, 0.4), description="hand segments closer than this, humerus lengths (epsilon)")
        touch_leg: tuple[float, float] = Field((0.5, 0.4), description="wrist closer than this to a leg bone, humerus lengths")
        touch_head: tuple[float, float] = Field((0.7, 0.55), description="wrist closer than this to the neck-headtop segment, humerus lengths")
        touch_hip: tuple[float, float] = Field((0.7, 0.55), description="wrist closer than this to the hip segment, humerus lengths")
        torso_bent_angle: tuple[float, float] = Field((120.0, 110.0), description="torso bent when both spine-thigh angles are below this, degrees (paper: 120)")
        root_fast: tuple[float, float] = Field((2.0, 2.5), description="root speed, humerus lengths per second")

    @property
    def dim(self) -> int:
        return len(FEATURES)

    def transform_bits(self, data: Motion | MotionDatabase) -> np.ndarray:
        """Boolean features ``(n_frames, 31)`` of one clip or a whole database, vectorised."""
        from mocapflow.framework.motion import Motion

        motions = [data] if isinstance(data, Motion) else list(data.motions)
        if not motions:
            return np.zeros((0, self.dim), dtype=bool)
        fps = {m.fps for m in motions}
        if len(fps) != 1:
            raise ConfigError(f"clips have different frame rates {sorted(fps)}; resample them (formats.load fps)")
        lengths = np.array([m.n_frames for m in motions], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(lengths)])
        cache: dict[int, dict[str, float]] = {}
        per_clip = []
        for m in motions:
            key = id(m.skeleton)
            if key not in cache:
                cache[key] = body_measures(m.skeleton)
            per_clip.append(cache[key])
        measures = {k: np.repeat([c[k] for c in per_clip], lengths) for k in ("humerus_length", "shoulder_width", "hip_width")}
        pos = np.concatenate([m.canonical_positions() for m in motions], axis=0)
        return relational_features(pos, fps.pop(), measures, self.params, offsets)

    def transform_motion(self, motion: Motion) -> np.ndarray:
        return self.transform_bits(motion).astype(np.float32)

    def transform(self, data: Motion | MotionDatabase) -> np.ndarray:
        return self.transform_bits(data).astype(np.float32)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.steps import run_features

        out = run_features(self, inputs, ctx)
        data = out.tables["data"]
        from mocapflow.framework.datasets import fixed_list_to_numpy

        bits = fixed_list_to_numpy(data["features"]) > 0.5
        cols = {"clip_id": data["clip_id"], "frame": data["frame"]}
        for name, _, _ in SETS:
            cols[name] = pa.array(set_codes(bits, name))
        out.tables["codes"] = pa.table(cols)
        out.summary.update({"features": len(FEATURES), "frames": data.num_rows,
                            "fraction_on": {FEATURE_IDS[i]: round(float(v), 4) for i, v in enumerate(bits.mean(0))} if len(bits) else {}})
        return out

    feature_ids: ClassVar[tuple[str, ...]] = FEATURE_IDS


__all__ = ["FEATURES", "FEATURE_IDS", "FEATURE_NAMES", "OPS", "SETS", "SET_SLICES", "FeatureDef", "RelationalFeatures",
           "feature_column", "feature_set_of", "feature_values", "relational_features", "set_codes"]
