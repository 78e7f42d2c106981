"""The 31 boolean relational features of Müller, Röder, Clausen 2005 (Table 1).

Three feature sets: lower body F_l (11 features, ids ``L1..L11``), upper body F_u
(``U1..U12``) and mixed F_m (``M1..M8``), in the order of the paper's Table 1. Each
feature is a generic primitive of :mod:`.relational_primitives` applied to canonical joints
(metres, y up) and thresholded relative to the body size of the clip's skeleton (humerus
length ``hl``, shoulder width ``sw``, hip width ``hw`` from
:func:`mocapflow.framework.normalize.body_measures`). The exact definitions and thresholds
are tabulated in ``docs/relational-features.md``.

Every threshold is a pair ``(threshold, strict)``: ``threshold`` is the single decision
value (the paper's where it gives one, e.g. 120 degrees for "bent" and one humerus length
for "hand in front"); ``strict`` is the switch-on value used only with ``hysteresis=True``
(switch on past ``strict``, off when ``threshold`` fails), which removes flicker at the cost
of slightly shorter "on" runs.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework.components import FeatureSet, Params
from mocapflow.framework.errors import ConfigError
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.normalize import body_measures

from . import relational_primitives as prim

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.database import MotionDatabase
    from mocapflow.framework.datasets import Dataset, StepOutput
    from mocapflow.framework.motion import Motion

Pair = tuple[float, float]

#: Joints substituted when a skeleton lacks one (positions are NaN there).
_FALLBACK = {"ltoes": "lankle", "rtoes": "rankle", "lfingers": "lwrist", "rfingers": "rwrist",
             "headtop": "head", "chest": "upperback", "neck": "head"}

#: Feature sets in Table 1 order: (set name, feature-id prefix, number of features).
SETS: tuple[tuple[str, str, int], ...] = (("lower", "L", 11), ("upper", "U", 12), ("mixed", "M", 8))


@dataclass(frozen=True)
class FeatureDef:
    """One boolean feature: ``value(ctx) >= threshold`` (or ``<`` when ``below``).

    ``param`` names the :class:`RelationalFeatures.Params` threshold pair and ``unit`` the
    body measure it is multiplied by (``hl``, ``sw``, ``hw``, ``deg`` or ``hl/s``).
    """

    id: str
    name: str
    description: str
    param: str
    unit: str
    below: bool
    value: Callable[[_Frames], np.ndarray]
    definition: str
    # for unit "deg" value() returns the cosine of the angle (cheaper than acos)


class _Frames:
    """Canonical joint trajectories (float32, fallbacks applied) of concatenated clips."""

    def __init__(self, positions: np.ndarray, fps: float, offsets: np.ndarray) -> None:
        self.positions = positions
        self.fps = fps
        self.offsets = offsets
        self._cache: dict[str, np.ndarray] = {}
        self._min_y: np.ndarray | None = None

    def __call__(self, joint: str) -> np.ndarray:
        if joint not in self._cache:
            p = np.ascontiguousarray(self.positions[:, CANONICAL_JOINTS.index(joint)], dtype=np.float32)
            if joint in _FALLBACK and np.isnan(p).any():
                p = np.where(np.isnan(p), self(_FALLBACK[joint]), p)
            self._cache[joint] = p
        return self._cache[joint]

    def min_y(self) -> np.ndarray:
        """Height of the lowest joint per frame (the floor the feet stand on)."""
        if self._min_y is None:
            self._min_y = prim.min_height(self.positions)
        return self._min_y

    def speed(self, joint: str, reference: str | None = None) -> np.ndarray:
        ref = None if reference is None else self(reference)
        return prim.speed(self(joint), self.fps, self.offsets, ref)


_UP = np.array([0.0, 1.0, 0.0], dtype=np.float32)
_O = np.zeros(3, dtype=np.float32)


def _side(r: str) -> str:
    return "right" if r == "r" else "left"


def _defs() -> tuple[FeatureDef, ...]:
    out: list[FeatureDef] = []

    def add(set_id: str, name: str, desc: str, param: str, unit: str, below: bool, fn, definition: str) -> None:
        n = sum(d.id[0] == set_id for d in out) + 1
        out.append(FeatureDef(f"{set_id}{n}", name, desc, param, unit, below, fn, definition))

    # ---- F_l: lower body -----------------------------------------------------------
    # right foot: plane (root, lankle, lhip) as in the paper's F^r; left foot mirrored
    # with the point order swapped so that the normal still points forward.
    add("L", "rfoot_front", "right foot in front", "foot_front", "hl", False,
        lambda f: prim.plane_distance(f("root"), f("lankle"), f("lhip"), f("rtoes")),
        "plane(root, lankle, lhip) -> rtoes")
    add("L", "lfoot_front", "left foot in front", "foot_front", "hl", False,
        lambda f: prim.plane_distance(f("root"), f("rhip"), f("rankle"), f("ltoes")),
        "plane(root, rhip, rankle) -> ltoes")
    for s, o in (("r", "l"), ("l", "r")):
        add("L", f"{s}foot_raised", f"{_side(s)} foot raised", "foot_raised", "hl", False,
            lambda f, s=s: f(f"{s}toes")[:, 1] - f.min_y(),
            f"height of {s}toes above the lowest joint of the frame")
    for s in "rl":
        add("L", f"{s}foot_fast", f"{_side(s)} foot fast", "foot_fast", "hl/s", False,
            lambda f, s=s: f.speed(f"{s}toes"), f"speed of {s}toes")
    for s in "rl":
        add("L", f"{s}knee_bent", f"{_side(s)} knee bent", "bent_angle", "deg", True,
            lambda f, s=s: prim.cos_between(f(f"{s}knee"), f(f"{s}hip"), f(f"{s}knee"), f(f"{s}ankle")),
            f"angle({s}knee->{s}hip, {s}knee->{s}ankle)")
    for s, o in (("r", "l"), ("l", "r")):
        add("L", f"{s}leg_sideways", f"{_side(s)} leg sideways", "leg_sideways", "hl", False,
            lambda f, s=s, o=o: prim.normal_plane_distance(f(f"{o}hip"), f(f"{s}hip"), f(f"{s}hip"), f(f"{s}ankle")),
            f"nplane(normal {o}hip->{s}hip, through {s}hip) -> {s}ankle")
    add("L", "legs_crossed", "legs crossed", "crossed", "hw", False,
        lambda f: prim.normal_plane_distance(f("rhip"), f("lhip"), f("lankle"), f("rankle")),
        "nplane(normal rhip->lhip, through lankle) -> rankle")

    # ---- F_u: upper body -----------------------------------------------------------
    add("U", "rhand_front", "right hand in front", "hand_front", "hl", False,
        lambda f: prim.plane_distance(f("root"), f("lshoulder"), f("rshoulder"), f("rwrist")),
        "plane(root, lshoulder, rshoulder) -> rwrist")
    add("U", "lhand_front", "left hand in front", "hand_front", "hl", False,
        lambda f: prim.plane_distance(f("root"), f("lshoulder"), f("rshoulder"), f("lwrist")),
        "plane(root, lshoulder, rshoulder) -> lwrist")
    for s in "rl":
        add("U", f"{s}hand_raised", f"{_side(s)} hand raised", "hand_raised", "hl", False,
            lambda f, s=s: prim.normal_plane_distance(f("chest"), f("neck"), f("neck"), f(f"{s}wrist")),
            f"nplane(normal chest->neck, through neck) -> {s}wrist")
    for s, o in (("r", "l"), ("l", "r")):
        add("U", f"{s}arm_sideways", f"{_side(s)} arm sideways", "arm_sideways", "hl", False,
            lambda f, s=s, o=o: prim.normal_plane_distance(f(f"{o}shoulder"), f(f"{s}shoulder"), f(f"{s}shoulder"),
                                                           f(f"{s}wrist")),
            f"nplane(normal {o}shoulder->{s}shoulder, through {s}shoulder) -> {s}wrist")
    for s in "rl":
        add("U", f"{s}elbow_bent", f"{_side(s)} elbow bent", "bent_angle", "deg", True,
            lambda f, s=s: prim.cos_between(f(f"{s}elbow"), f(f"{s}shoulder"), f(f"{s}elbow"), f(f"{s}wrist")),
            f"angle({s}elbow->{s}shoulder, {s}elbow->{s}wrist)")
    for s in "rl":
        add("U", f"{s}hand_fast", f"{_side(s)} hand fast", "hand_fast", "hl/s", False,
            lambda f, s=s: f.speed(f"{s}wrist", "root"), f"speed of {s}wrist relative to root")
    add("U", "arms_crossed", "arms crossed", "crossed", "sw", False,
        lambda f: prim.normal_plane_distance(f("rshoulder"), f("lshoulder"), f("lwrist"), f("rwrist")),
        "nplane(normal rshoulder->lshoulder, through lwrist) -> rwrist")
    add("U", "hands_touching", "hands touching", "touch_hands", "hl", True,
        lambda f: prim.segment_segment_distance(f("rwrist"), f("rfingers"), f("lwrist"), f("lfingers")),
        "distance(segment rwrist-rfingers, segment lwrist-lfingers)")

    # ---- F_m: mixed ---------------------------------------------------------------
    legs = (("lhip", "lknee"), ("lknee", "lankle"), ("rhip", "rknee"), ("rknee", "rankle"))
    for s in "rl":
        add("M", f"{s}hand_leg", f"{_side(s)} hand touching any leg", "touch_leg", "hl", True,
            lambda f, s=s: np.minimum.reduce([prim.point_segment_distance(f(f"{s}wrist"), f(a), f(b)) for a, b in legs]),
            f"min distance({s}wrist, segments hip-knee and knee-ankle of both legs)")
    for s in "rl":
        add("M", f"{s}hand_head", f"{_side(s)} hand touching head or neck", "touch_head", "hl", True,
            lambda f, s=s: prim.point_segment_distance(f(f"{s}wrist"), f("neck"), f("headtop")),
            f"distance({s}wrist, segment neck-headtop)")
    for s in "rl":
        add("M", f"{s}hand_hip", f"{_side(s)} hand touching hip area", "touch_hip", "hl", True,
            lambda f, s=s: prim.point_segment_distance(f(f"{s}wrist"), f("lhip"), f("rhip")),
            f"distance({s}wrist, segment lhip-rhip)")
    add("M", "torso_bent", "torso bent", "torso_bent_angle", "deg", True,
        lambda f: np.fmin(prim.cos_between(f("root"), f("neck"), f("lhip"), f("lknee")),
                          prim.cos_between(f("root"), f("neck"), f("rhip"), f("rknee"))),
        "max(angle(root->neck, lhip->lknee), angle(root->neck, rhip->rknee))")
    add("M", "root_fast", "root fast", "root_fast", "hl/s", False,
        lambda f: f.speed("root"), "speed of root")
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


def _unit_scale(unit: str, measures: Mapping[str, np.ndarray]) -> np.ndarray | float:
    return {"hl": measures["humerus_length"], "hl/s": measures["humerus_length"], "sw": measures["shoulder_width"],
            "hw": measures["hip_width"], "deg": 1.0}[unit]


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
    t = positions.shape[0]
    offsets = np.array([0, t]) if offsets is None else np.asarray(offsets, dtype=np.int64)
    frames = _Frames(positions, fps, offsets)
    m = {k: np.asarray(measures[k], dtype=np.float32) for k in ("humerus_length", "shoulder_width", "hip_width")}
    out = np.zeros((t, len(FEATURES)), dtype=bool)
    on = np.zeros_like(out) if params.hysteresis else None
    if t == 0:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        for i, d in enumerate(FEATURES):
            value = d.value(frames)
            base, strict = getattr(params, d.param)
            if d.unit == "deg":  # value is a cosine: angle < theta iff cos > cos(theta)
                base, strict, below = np.cos(np.radians(base)), np.cos(np.radians(strict)), not d.below
            else:
                scale = _unit_scale(d.unit, m)
                base, strict, below = base * scale, strict * scale, d.below
            out[:, i] = prim.threshold(value, base, below)
            if on is not None:
                on[:, i] = prim.threshold(value, strict, below)
    if on is not None:
        out = prim.hysteresis(on & out, out, offsets)
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
        out = super().run(inputs, ctx)
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


__all__ = ["FEATURES", "FEATURE_IDS", "FEATURE_NAMES", "SETS", "SET_SLICES", "FeatureDef", "RelationalFeatures",
           "feature_column", "feature_set_of", "relational_features", "set_codes"]
