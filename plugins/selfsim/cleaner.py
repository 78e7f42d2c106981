"""``cleaners.mdm``: the self-similarity cleaner of Aristidou et al. 2018 (docs/cleaning.md).

The paper's analysis (:func:`.paper.mdm.digression_map`), then by ``mode`` the paper's
decision and repair (:mod:`.paper.repair`) or the calibrated one (:mod:`.calibrated.decision`).
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

import numpy as np
import pyarrow as pa
from pydantic import Field, model_validator

from mocapflow.framework import quaternions as quat
from mocapflow.framework.components import Cleaner, Params
from mocapflow.framework.motion import Motion

from .calibrated.constants import DEFAULT_RATE
from .paper.motion_words import DEFAULT_GROUPS, DEFAULT_JOINTS


class JointGroup(Params):
    """A joint group of motion-words."""

    name: str = Field(description="group name (whole, upper, lower, left, right...)")
    joints: tuple[str, ...] = Field(default=(), description="canonical joints; empty = every texture joint")
    drop: int = Field(default=1, ge=0, description="largest joint distances left out of eq. 1")


def _default_groups() -> tuple[JointGroup, ...]:
    return tuple(JointGroup(name=n, joints=j, drop=d) for n, j, d in DEFAULT_GROUPS)


class CalibratedParams(Params):
    """What a user chooses in ``mode: calibrated`` (the rest is measured: :mod:`.calibrated.constants`)."""

    false_alarm_rate: float = Field(
        default=DEFAULT_RATE,
        gt=0,
        lt=1,
        description="share of the (frame, joint) cells of a clean take the test flags (a conformal "
        "p-value against clean context words like the take)",
    )
    frames: int = Field(
        default=600,
        ge=15,
        description="null budget: analysis frames of the context spans most like the take (by its KNN words)",
    )
    false_alarm: float | None = Field(
        default=None, gt=0, lt=1, description="deprecated, ignored: use false_alarm_rate (a share of cells)"
    )
    seed: int | None = Field(default=None, description="deprecated, ignored: the calibration injects nothing")
    max_edit: float | None = Field(
        default=None, gt=0, le=180, description="deprecated, ignored: an edit is bounded by its digression"
    )

    @model_validator(mode="after")
    def _shims(self) -> CalibratedParams:
        for old, instead in (
            ("false_alarm", "calibrated.false_alarm_rate (a share of (frame, joint) cells, not of word pairs)"),
            ("seed", "nothing: the null is measured on clean context words, no synthetic errors"),
            ("max_edit", "nothing: an edit is bounded by the cell's digression plus the KNN spread"),
        ):
            if getattr(self, old) is not None:
                warnings.warn(
                    f"cleaners.mdm: calibrated.{old} is deprecated and ignored (removed next release); use {instead}",
                    DeprecationWarning,
                    stacklevel=2,
                )
        return self


class MDMParams(Params):
    """Parameters of the MDM cleaner: the analysis and the paper's decision at the top level
    (the paper's values), the calibrated decision's in ``calibrated``."""

    mode: Literal["calibrated", "paper"] = Field(
        default="calibrated",
        description="'calibrated': one fused test per (frame, joint) at false_alarm_rate against clean "
        "context words like the take, repairs only where it fired; 'paper': MDM > threshold, median KNN word, Savitzky-Golay blend (§3.4, §4)",
    )
    fps: float = Field(default=24.0, gt=0, description="analysis frame rate (§5: 120 Hz reduced to 24 fps)")
    joints: tuple[str, ...] = Field(
        default=DEFAULT_JOINTS, description="texture joints (canonical names; absent ones are skipped)"
    )
    groups: tuple[JointGroup, ...] = Field(
        default_factory=_default_groups, description="joint groups of the motion-words"
    )
    source_length: int = Field(default=15, ge=2, description="source word length N, frames")
    source_step: int = Field(default=5, ge=1, description="frames between source words")
    target_length: int = Field(default=20, ge=2, description="target word length M, frames")
    k: int = Field(default=5, ge=1, description="nearest neighbours per word")
    slope_run: int = Field(default=2, ge=1, description="DTW slope constraint: most consecutive steps in one direction")
    exclusion: int | None = Field(
        default=None, ge=0, description="minima this close to the source word are discarded (frames; None = N/2)"
    )
    include_self: bool = Field(default=True, description="search the clip itself as part of its context")
    threshold: float = Field(
        default=0.5, ge=0, le=1, description="paper: MDM value above which a cell is erroneous (§4)"
    )
    savgol_window: int = Field(
        default=7, ge=3, description="paper: Savitzky-Golay window of the repair blending, frames at fps"
    )
    savgol_order: int = Field(default=2, ge=1, description="paper: Savitzky-Golay polynomial order (quadratic)")
    calibrated: CalibratedParams = Field(
        default_factory=CalibratedParams, description="calibrated: the user's choices of the calibrated decision"
    )
    write_bvh: bool = Field(default=True, description="write each cleaned clip as BVH into the step folder")
    heatmaps: bool = Field(default=True, description="write an MDM heatmap PNG per clip into the step folder")

    def groups_tuple(self) -> tuple[tuple[str, tuple[str, ...], int], ...]:
        return tuple((g.name, g.joints, g.drop) for g in self.groups)


@dataclass
class CleanResult:
    """One clip through :meth:`MDMCleaner.clean`, (T, m) at the analysis rate: ``flags``
    (decided), ``value`` (the map, > 0.5 = flagged: the MDM or ``0.5 S / threshold`` of the
    fused statistic), ``cue`` (deciding detector name or None), ``repaired`` (T, m, 4), ``edited``; then
    ``cleaned`` (input rate) and ``edits`` (:func:`.paper.repair.edits_table` plus
    ``edit_deg``, ``cue``); calibrated: ``calibration`` (the take's :class:`.calibrated.null.Null`),
    ``stat`` (T, m) the fused statistic and ``pvalue`` its conformal p-values.
    """

    analysis: Any
    flags: np.ndarray
    value: np.ndarray
    cue: np.ndarray
    repaired: np.ndarray
    edited: np.ndarray
    cleaned: Motion
    edits: Any
    calibration: Any = None
    stat: np.ndarray | None = None
    pvalue: np.ndarray | None = None

    def map_result(self) -> Any:
        """An object :func:`.paper.repair.map_to_input` takes, carrying ``value`` as its map."""
        from types import SimpleNamespace

        return SimpleNamespace(mdm=self.value, texture=self.analysis.texture)


def _input_cues(motion: Motion, texture: Any, cue: np.ndarray, frames: np.ndarray, joints: np.ndarray) -> list[Any]:
    """Cue of the analysis cell nearest each edited input cell (frame, skeleton joint)."""
    col = {int(j): c for c, j in enumerate(texture.joint_index)}
    x = np.rint(frames * (texture.fps / motion.fps)).astype(np.int64).clip(0, len(cue) - 1)
    out = []
    for f, j in zip(x.tolist(), joints.tolist(), strict=True):
        c = col.get(int(j))
        v = cue[f, c] if c is not None else None
        if v is None and c is not None:  # an input frame next to a flagged analysis frame
            near = [cue[g, c] for g in (f - 1, f + 1) if 0 <= g < len(cue) and cue[g, c] is not None]
            v = near[0] if near else None
        out.append(v)
    return out


def _edits(motion: Motion, cleaned: Motion, changed: np.ndarray, texture: Any, cue: np.ndarray) -> pa.Table:
    from .paper.repair import edits_table

    tab = edits_table(motion, cleaned, changed)
    f = tab["frame"].to_numpy()
    j = tab["joint"].to_numpy()
    deg = np.rad2deg(quat.geodesic_angle(motion.rotations[f, j], cleaned.rotations[f, j])) if len(f) else np.zeros(0)
    tab = tab.append_column("edit_deg", pa.array(deg.astype(np.float32)))
    return tab.append_column("cue", pa.array(_input_cues(motion, texture, cue, f, j), pa.string()))


def clean_motion(
    cleaner: MDMCleaner,
    motion: Motion,
    context: Any = None,
    contacts: Sequence[Any] = (),
    analysis: Any = None,
    calibration: Any = None,
) -> CleanResult:
    """Analyse, decide and repair one clip; ``analysis`` and ``calibration`` of this context
    are reused when given (the evaluation runs several decisions on one analysis)."""
    from .paper.repair import apply_to_input, repair_texture

    p = cleaner.params
    res = analysis if analysis is not None else cleaner.analyse(motion, context)
    if p.mode != "paper" and not res.neighbours:
        logging.getLogger("mocapflow.cleaning").warning(
            "%s: %d analysis frames, shorter than one motion word (%d): left as it is",
            motion.name,
            res.texture.n_frames,
            p.source_length,
        )
    if p.mode == "paper" or not res.neighbours:
        flags = res.mdm > p.threshold
        new24, edited = repair_texture(res, p.threshold, p.savgol_window, p.savgol_order, contacts)
        cue = np.full(res.mdm.shape, None, dtype=object)
        cue[flags] = "mdm"
        value, cal, stat, pv = res.mdm, None, None, None
    else:
        from .calibrated.calibration import calibrate
        from .calibrated.decision import calibrated_decision
        from .paper.motion_words import context_motions

        c = p.calibrated
        if calibration is None:
            others = context_motions(motion, context, True)[1:]
            calibration = calibrate(
                res,
                motion,
                others,
                cleaner.clone(include_self=True).analyse,
                p.fps,
                frames=c.frames,
                self_first=p.include_self,
            )
            if calibration.fallback:
                logging.getLogger("mocapflow.cleaning").warning(
                    "%s: %s; decided on the null shipped with the package", motion.name, calibration.fallback
                )
        cal = calibration
        flags, value, cue, new24, edited, pv, stat = calibrated_decision(res, cal, c.false_alarm_rate)
    cleaned, changed = apply_to_input(motion, res.texture, new24, edited, guard=p.mode != "paper")
    return CleanResult(
        res,
        flags,
        value,
        cue,
        new24,
        edited,
        cleaned,
        _edits(motion, cleaned, changed, res.texture, cue),
        cal,
        stat,
        pv,
    )


class MDMCleaner(Cleaner):
    """Self-similarity cleaning with the movement digression map (Aristidou et al. 2018)."""

    name = "mdm"
    version = "3"
    Params: ClassVar[type[Params]] = MDMParams
    params: MDMParams

    def analyse(self, motion: Motion, context: Any = None) -> Any:
        """The full analysis at the analysis rate (texture, T̄, MDM, neighbours)."""
        from .paper.mdm import digression_map

        return digression_map(motion, context, self.params)

    def clean(self, motion: Motion, context: Any = None, contacts: Sequence[Any] = ()) -> CleanResult:
        """Analysis, decision and repair of one clip (see :class:`CleanResult`)."""
        from mocapflow.framework.cleaning import check_take

        check_take(motion, self.key())
        return clean_motion(self, motion, context, contacts)

    def detect(self, motion: Motion, context: Any = None) -> np.ndarray:
        """Digression map at the input frames, shape (T, J) in [0, 1] (> 0.5 = flagged)."""
        from .paper.repair import map_to_input

        return map_to_input(self.clean(motion, context).map_result(), motion)

    def repair(self, motion: Motion, context: Any = None, contacts: Sequence[Any] = ()) -> tuple[Motion, Any]:
        """Cleaned motion (input frame rate) and the edits as an Arrow table."""
        out = self.clean(motion, context, contacts)
        return out.cleaned, out.edits

    def detect_and_repair(
        self, motion: Motion, context: Any, clip_id: int, out_dir: Any = None, registries: Any = None
    ) -> Any:
        """The step's hook for one clip: :func:`.outputs.clean_and_write_clip`."""
        from mocapflow.framework.cleaning import CleanedClip

        from .outputs import clean_and_write_clip

        out = clean_and_write_clip(self, motion, context, clip_id, out_dir, registries)
        return CleanedClip(out["mdm"], out["edits"], out["cleaned"], out["summary"])
