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

Every threshold is one value of :data:`THRESHOLDS` (the paper's where it gives one, e.g. 120
degrees for "bent" and one humerus length for "hand in front"); the step's ``thresholds``
parameter overrides them by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, ClassVar, cast

import numpy as np
import pyarrow as pa
from pydantic import Field, field_validator

from mocapflow.framework.components import FeatureSet
from mocapflow.framework.components import Params as BaseParams
from mocapflow.framework.errors import ConfigError, DataError
from mocapflow.framework.joints import CANONICAL_JOINTS

from . import primitives as prim
from .body import body_measures
from .feature_table import (
    _FALLBACK,
    FEATURE_IDS,
    FEATURES,
    OPS,
    SET_SLICES,
    SETS,
    THRESHOLDS,
)

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework.context import StepContext
    from mocapflow.framework.database import MotionDatabase
    from mocapflow.framework.datasets import Dataset, StepOutput
    from mocapflow.framework.motion import Motion


def relational_features(
    positions: np.ndarray,
    fps: float,
    measures: Mapping[str, np.ndarray | float],
    params: RelationalFeatures.Params | None = None,
    offsets: np.ndarray | None = None,
) -> np.ndarray:
    """The 31 features of concatenated clips, vectorised over all frames.

    ``positions`` (T, 25, 3) canonical joints, metres; speeds in humerus lengths per second
    at ``fps``; ``measures``: ``humerus_length``, ``shoulder_width``, ``hip_width`` in metres,
    scalars or (T,) (clips of several skeletons); speeds never cross clip ``offsets``
    (n_clips + 1,). Returns (T, 31) bool in Table 1 order (:data:`FEATURE_IDS`).
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
    values = {**THRESHOLDS, **params.thresholds}
    thr = np.empty(len(FEATURES), np.float32)
    below = np.empty(len(FEATURES), bool)
    unit = np.empty(len(FEATURES), np.int64)
    for i, d in enumerate(FEATURES):
        a = values[d.param]
        if d.unit == "deg":  # the value is a cosine: angle < theta iff cos > cos(theta)
            thr[i], below[i] = np.cos(np.radians(a)), not d.below
        else:
            thr[i], below[i] = a, d.below
        unit[i] = units.index(d.unit.removesuffix("/s"))
    out = np.zeros((t, len(FEATURES)), dtype=bool)
    if t:
        from ._feature_kernels import feature_bits

        feature_bits(np.ascontiguousarray(pos), starts, float(fps), *_program(), unit, scale, thr, below, out)
    return out


def _program() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The feature table as arrays for the kernel: op codes, joint indices, term counts, fallbacks."""
    ops = np.array([OPS.index(d.op) for d in FEATURES], dtype=np.int64)
    joints = np.full((len(FEATURES), 4, 4), -1, dtype=np.int64)
    for i, d in enumerate(FEATURES):
        for k, term in enumerate(d.terms):
            joints[i, k, : len(term)] = [CANONICAL_JOINTS.index(j) for j in term]
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
    """Integer code (T,) int32 of each frame's feature vector (``bits`` (T, 31)) within one
    set ("lower", "upper" or "mixed"; bit ``i`` = the set's i-th feature)."""
    sl = SET_SLICES[feature_set]
    b = np.asarray(bits[:, sl]) > 0.5
    return cast("np.ndarray", (b.astype(np.int32) << np.arange(b.shape[1], dtype=np.int32)).sum(axis=1, dtype=np.int32))


class RelationalFeatures(FeatureSet):
    """The 31 boolean relational features of Müller et al. 2005, Table 1 (F_l, F_u, F_m).

    Output columns are 0/1 float32 in the order of :data:`FEATURE_IDS`. As a pipeline step
    it also writes a ``codes`` table (``clip_id, frame, lower, upper, mixed``: each set's
    feature vector as an integer, bit ``i`` = the set's ``i``-th feature).
    """

    name = "relational"
    version = "1"

    class Params(BaseParams):
        thresholds: dict[str, float] = Field(
            default_factory=dict,
            description="decision thresholds overriding "
            "THRESHOLDS by name, e.g. {foot_raised: 1.1} (units and defaults: "
            "docs/relational-features.md)",
        )

        @field_validator("thresholds")
        @classmethod
        def _known(cls, v: dict[str, float]) -> dict[str, float]:
            unknown = sorted(set(v) - set(THRESHOLDS))
            if unknown:
                raise ValueError(f"unknown thresholds {unknown}; known: {', '.join(THRESHOLDS)}")
            return v

    params: Params

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
        measures = {
            k: np.repeat([c[k] for c in per_clip], lengths) for k in ("humerus_length", "shoulder_width", "hip_width")
        }
        pos = np.concatenate([m.canonical_positions() for m in motions], axis=0)
        return relational_features(pos, fps.pop(), measures, self.params, offsets)

    def transform_motion(self, motion: Motion) -> np.ndarray:
        return self.transform_bits(motion).astype(np.float32)

    def transform(self, data: Motion | MotionDatabase) -> np.ndarray:
        return self.transform_bits(data).astype(np.float32)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.steps import run_features

        out = run_features(self, inputs, ctx, stream=False)  # the codes are derived from the whole table
        data = out.tables["data"]
        assert isinstance(data, pa.Table)  # stream=False: the whole table
        from mocapflow.framework.schema import fixed_list_to_numpy

        bits = fixed_list_to_numpy(data["features"]) > 0.5
        cols = {"clip_id": data["clip_id"], "frame": data["frame"]}
        for name, _, _ in SETS:
            cols[name] = pa.array(set_codes(bits, name))
        out.tables["codes"] = pa.table(cols)
        out.summary.update(
            {
                "features": len(FEATURES),
                "frames": data.num_rows,
                "fraction_on": {FEATURE_IDS[i]: round(float(v), 4) for i, v in enumerate(bits.mean(0))}
                if len(bits)
                else {},
            }
        )
        return out

    feature_ids: ClassVar[tuple[str, ...]] = FEATURE_IDS
