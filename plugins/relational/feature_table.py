"""The table of the 31 relational features (Müller, Röder, Clausen 2005, Table 1).

:data:`FEATURES` is the single definition of every feature (primitive, joints, threshold key,
unit); :mod:`.features` compiles it into the program its kernel interprets, and
``tests/naive/relational.py`` evaluates it with plain NumPy geometry. :data:`THRESHOLDS`
holds the decision values (docs/relational-features.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from mocapflow.framework.errors import ConfigError

#: Joints substituted when a skeleton lacks one (positions are NaN there).
_FALLBACK = {
    "ltoes": "lankle",
    "rtoes": "rankle",
    "lfingers": "lwrist",
    "rfingers": "rwrist",
    "headtop": "head",
    "chest": "upperback",
    "neck": "head",
}

#: Feature sets in Table 1 order: (set name, feature-id prefix, number of features).
SETS: tuple[tuple[str, str, int], ...] = (("lower", "L", 11), ("upper", "U", 12), ("mixed", "M", 8))


#: Decision thresholds per ``FeatureDef.param``, in the unit of the feature (docs/relational-features.md).
THRESHOLDS: dict[str, float] = {
    "foot_front": 0.0,
    "foot_raised": 1.0,
    "foot_fast": 2.0,
    "bent_angle": 120.0,
    "leg_sideways": 0.8,
    "crossed": 0.0,
    "hand_front": 1.0,
    "hand_raised": 0.0,
    "arm_sideways": 1.0,
    "hand_fast": 2.0,
    "touch_hands": 0.5,
    "touch_leg": 0.5,
    "touch_head": 0.7,
    "touch_hip": 0.7,
    "torso_bent_angle": 120.0,
    "root_fast": 2.0,
}

#: Operations of the feature program, matching the kernel op codes.
OPS: tuple[str, ...] = ("plane", "nplane", "point_segment", "segment_segment", "cos", "height", "speed")


@dataclass(frozen=True)
class FeatureDef:
    """One boolean feature: a primitive applied to canonical joints, then thresholded.

    ``op`` (one of :data:`OPS`) is applied to each tuple of joints in ``terms`` and the
    minimum over the terms is taken (several terms: "touching any leg", "torso bent").
    The feature is ``value >= threshold`` (``below``: ``value < threshold``) where the
    threshold is the :data:`THRESHOLDS` value named ``param`` times the
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

    def add(
        set_id: str, name: str, desc: str, param: str, unit: str, below: bool, op: str, *terms: tuple[str, ...]
    ) -> None:
        n = sum(d.id[0] == set_id for d in out) + 1
        out.append(FeatureDef(f"{set_id}{n}", name, desc, param, unit, below, op, tuple(terms)))

    # ---- F_l: lower body -----------------------------------------------------------
    # right foot: plane (root, lankle, lhip) as in the paper's F^r; left foot mirrored
    # with two points swapped so that the normal still points forward.
    add(
        "L",
        "rfoot_front",
        "right foot in front",
        "foot_front",
        "hl",
        False,
        "plane",
        ("root", "lankle", "lhip", "rtoes"),
    )
    add(
        "L",
        "lfoot_front",
        "left foot in front",
        "foot_front",
        "hl",
        False,
        "plane",
        ("root", "rhip", "rankle", "ltoes"),
    )
    for s in "rl":
        add("L", f"{s}foot_raised", f"{_side(s)} foot raised", "foot_raised", "hl", False, "height", (f"{s}toes",))
    for s in "rl":
        add("L", f"{s}foot_fast", f"{_side(s)} foot fast", "foot_fast", "hl/s", False, "speed", (f"{s}toes",))
    for s in "rl":
        add(
            "L",
            f"{s}knee_bent",
            f"{_side(s)} knee bent",
            "bent_angle",
            "deg",
            True,
            "cos",
            (f"{s}knee", f"{s}hip", f"{s}knee", f"{s}ankle"),
        )
    for s, o in (("r", "l"), ("l", "r")):
        add(
            "L",
            f"{s}leg_sideways",
            f"{_side(s)} leg sideways",
            "leg_sideways",
            "hl",
            False,
            "nplane",
            (f"{o}hip", f"{s}hip", f"{s}hip", f"{s}ankle"),
        )
    add("L", "legs_crossed", "legs crossed", "crossed", "hw", False, "nplane", ("rhip", "lhip", "lankle", "rankle"))

    # ---- F_u: upper body -----------------------------------------------------------
    add(
        "U",
        "rhand_front",
        "right hand in front",
        "hand_front",
        "hl",
        False,
        "plane",
        ("root", "lshoulder", "rshoulder", "rwrist"),
    )
    add(
        "U",
        "lhand_front",
        "left hand in front",
        "hand_front",
        "hl",
        False,
        "plane",
        ("root", "lshoulder", "rshoulder", "lwrist"),
    )
    for s in "rl":
        add(
            "U",
            f"{s}hand_raised",
            f"{_side(s)} hand raised",
            "hand_raised",
            "hl",
            False,
            "nplane",
            ("chest", "neck", "neck", f"{s}wrist"),
        )
    for s, o in (("r", "l"), ("l", "r")):
        add(
            "U",
            f"{s}arm_sideways",
            f"{_side(s)} arm sideways",
            "arm_sideways",
            "hl",
            False,
            "nplane",
            (f"{o}shoulder", f"{s}shoulder", f"{s}shoulder", f"{s}wrist"),
        )
    for s in "rl":
        add(
            "U",
            f"{s}elbow_bent",
            f"{_side(s)} elbow bent",
            "bent_angle",
            "deg",
            True,
            "cos",
            (f"{s}elbow", f"{s}shoulder", f"{s}elbow", f"{s}wrist"),
        )
    for s in "rl":
        add("U", f"{s}hand_fast", f"{_side(s)} hand fast", "hand_fast", "hl/s", False, "speed", (f"{s}wrist", "root"))
    add(
        "U",
        "arms_crossed",
        "arms crossed",
        "crossed",
        "sw",
        False,
        "nplane",
        ("rshoulder", "lshoulder", "lwrist", "rwrist"),
    )
    add(
        "U",
        "hands_touching",
        "hands touching",
        "touch_hands",
        "hl",
        True,
        "segment_segment",
        ("rwrist", "rfingers", "lwrist", "lfingers"),
    )

    # ---- F_m: mixed ---------------------------------------------------------------
    legs = (("lhip", "lknee"), ("lknee", "lankle"), ("rhip", "rknee"), ("rknee", "rankle"))
    for s in "rl":
        add(
            "M",
            f"{s}hand_leg",
            f"{_side(s)} hand touching any leg",
            "touch_leg",
            "hl",
            True,
            "point_segment",
            *((f"{s}wrist", a, b) for a, b in legs),
        )
    for s in "rl":
        add(
            "M",
            f"{s}hand_head",
            f"{_side(s)} hand touching head or neck",
            "touch_head",
            "hl",
            True,
            "point_segment",
            (f"{s}wrist", "neck", "headtop"),
        )
    for s in "rl":
        add(
            "M",
            f"{s}hand_hip",
            f"{_side(s)} hand touching hip area",
            "touch_hip",
            "hl",
            True,
            "point_segment",
            (f"{s}wrist", "lhip", "rhip"),
        )
    # the paper takes the larger of the two spine-thigh angles, i.e. the smaller cosine
    add(
        "M",
        "torso_bent",
        "torso bent",
        "torso_bent_angle",
        "deg",
        True,
        "cos",
        ("root", "neck", "lhip", "lknee"),
        ("root", "neck", "rhip", "rknee"),
    )
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
    raise ConfigError(
        f"unknown relational feature {key!r}; known: {', '.join(FEATURE_IDS)} or names like {FEATURE_NAMES[0]!r}"
    )


def feature_set_of(column: int) -> str:
    """Name of the feature set (``lower``, ``upper``, ``mixed``) holding a column."""
    for name, sl in SET_SLICES.items():
        if sl.start <= column < sl.stop:
            return name
    raise ConfigError(f"feature column {column} out of range 0..30")
