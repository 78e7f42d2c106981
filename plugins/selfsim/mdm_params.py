"""Parameters of the MDM cleaner (``cleaners.mdm``): :class:`MDMParams` and :class:`JointGroup`.

Split from :mod:`.mdm` (session 6: the module had grown past 400 lines); :mod:`.mdm`
re-exports both. The analysis defaults are the paper's values (§3-§5); the decision and
repair parameters of ``mode: calibrated`` are documented in docs/cleaning.md, session by
session.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from mocapflow.framework.components import Params

from .motion_words import DEFAULT_GROUPS, DEFAULT_JOINTS


class JointGroup(Params):
    """A joint group of motion-words."""

    name: str = Field(description="group name (whole, upper, lower, left, right...)")
    joints: tuple[str, ...] = Field(default=(), description="canonical joints; empty = every texture joint")
    drop: int = Field(default=1, ge=0, description="largest joint distances left out of eq. 1")


def _default_groups() -> tuple[JointGroup, ...]:
    return tuple(JointGroup(name=n, joints=j, drop=d) for n, j, d in DEFAULT_GROUPS)


class MDMParams(Params):
    """Parameters of the MDM cleaner; the analysis defaults are the paper's values, the
    decision (``mode``) defaults to the calibrated detector."""

    mode: Literal["calibrated", "paper"] = Field(
        default="calibrated",
        description="'calibrated': detector fitted on the clean context (self-supervised, target false_alarm) and "
                    "bounded repair; 'paper': MDM > threshold, median KNN word, Savitzky-Golay blend (§3.4, §4)")
    false_alarm: float = Field(default=0.004, gt=0, lt=1, description="calibrated: share of clean (word, joint) "
                               "pairs of the calibration clips the detector may flag")
    null_quantile: float = Field(default=0.99, gt=0.5, lt=1, description="calibrated: quantile of a cue over a "
                                 "joint's clean calibration cells taken as its null level")
    calibration_frames: int = Field(default=600, ge=15, description="calibrated: frames (at fps) of context clips "
                                    "analysed with synthetic errors (the longest first; the take itself without context)")
    calibration_density: float = Field(default=0.2, gt=0, lt=1, description="calibrated: share of calibration "
                                       "words given a synthetic error")
    calibration_seed: int = Field(default=0, description="calibrated: seed of the synthetic errors")
    cues: tuple[Literal["digression", "acceleration", "mirror", "freeze", "range", "jitter", "words"], ...] = Field(
        default=("digression", "acceleration", "mirror", "freeze", "jitter"),
        description="calibrated: cues the detector may use (range = baseline (a), off by default; words = the jitter "
        "cue against the KNN words' own high-frequency energy, selfsim/word_noise.py, off by default)")
    max_edit: float = Field(default=30.0, gt=0, le=180, description="calibrated: largest edit, degrees, of a cell "
                            "flagged by the digression, freeze or range cue (spikes and swaps are bounded by their evidence)")
    swap_gain: float = Field(default=0.1, ge=0, description="calibrated: least chain mirror gain (radians over the "
                             "chain pair) for swapping limbs back")
    swap_level: float | None = Field(default=3.0, gt=0, description="calibrated: least edge benefit (units of the "
                                     "chains' typical acceleration) at both ends of a swap found by its edges "
                                     "(cleaners/swaps.py); None = only the mirror cue's swaps")
    offset_level: float | None = Field(default=6.0, gt=0, description="calibrated: flagged runs whose ends are "
                                       "two consistent jumps of at least this many typical accelerations of the joint "
                                       "(and 8 degrees) are repaired by taking the offset out (cleaners/offsets.py); "
                                       "None = always the KNN word")
    flag_rule: Literal["evidence", "repaired"] = Field(
        default="repaired", description="calibrated: cells reported flagged: every cell whose evidence exceeds its level "
        "('evidence'), or only those the bounded repair changed ('repaired'; swaps and offsets always)")
    interp_max: int = Field(default=0, ge=0, description="calibrated: runs of up to this many frames flagged by the "
                            "acceleration cue (and no offset) are interpolated between their neighbours instead of "
                            "taking the KNN word; 0 = off")
    merge_gap: int = Field(default=3, ge=0, description="calibrated: flagged runs of one joint at most this many "
                           "frames apart are repaired as one (the gap included); 0 = off")
    merge_jolts: bool = Field(default=False, description="calibrated: merge_gap may bridge cells whose acceleration "
                              "flags acc_body dropped (a whole-body jolt: a KNN word cannot repair them, and a merged "
                              "run gave them their cue's unbounded edit); False = a merged run stops at them (session 7; "
                              "True = session 6)")
    merge_mirror: bool = Field(default=False, description="calibrated: merge_gap may bridge mirror-cue flags (left "
                               "as they are when their swap-back does not hold up, bounded_repair); False = a merged run "
                               "stops at them (session 7; True = session 6)")
    gap_cap: bool = Field(default=False, description="calibrated: cells a merged run takes in without being flagged "
                          "are bounded by max_edit, not by their own cue's bound (session 7)")
    agree: float | None = Field(default=0.3, gt=0, description="calibrated: runs flagged by the digression alone "
                                "are kept only where the acceleration or freeze evidence exceeds this somewhere in "
                                "the run (+-1 frame); None = off")
    acc_persist: float | None = Field(default=1.5, gt=0, description="calibrated: the acceleration cue of a cell "
                                      "is capped at this many times the larger of its two neighbours' (isolated "
                                      "kinks of clean fast joints drop; spikes, steps, jitter keep it); None = off")
    acc_persist_fit: bool = Field(default=False, description="calibrated: fit the cue weights with acc_persist "
                                  "applied (True) or fit without it and apply it to the take only (False: the rule "
                                  "then only removes flags)")
    jitter_half: int = Field(default=4, ge=1, description="calibrated: the jitter cue is the median of the "
                             "acceleration cue over 2 jitter_half + 1 frames")
    acc_body: int | None = Field(default=3, ge=2, description="calibrated: at frames where at least this many "
                                 "joints are flagged by the acceleration cue (a jolt of the whole body), those "
                                 "flags are dropped; None = off")
    freeze_still: float | None = Field(default=0.05, gt=0, description="calibrated: runs the freeze cue flags are "
                                      "grown over the interval where the joint moves less than this many degrees "
                                      "per frame (the whole frozen interval); None = off")
    freeze_moving: float | None = Field(default=0.1, gt=0, description="calibrated: the freeze_still growth "
                                        "covers only frames where the KNN consensus moves at least this many degrees "
                                        "per frame (a joint the consensus holds still too is genuinely still); None = off")
    freeze_hold: int | None = Field(default=8, ge=2, description="calibrated: the freeze cue counts only on "
                                    "holds of at least this many frames (consecutive frames turning less than 0.05 "
                                    "degrees per frame, cues.HOLD_SPEED), where it is the consensus' speed over the "
                                    "take's own (session 6); None = the 9-frame speed ratio of session 2")
    freeze_fill: Literal["off", "hermite", "slerp", "consensus"] = Field(
        default="consensus", description="calibrated, with freeze_hold: a hold the freeze cue flags is filled as a gap "
        "between the two frames that bound it (selfsim/holds.py): a Hermite curve with the take's velocities, the "
        "geodesic, or the KNN consensus joined to both ends without the nearer-consensus bound; off = the bounded "
        "repair")
    freeze_guard: bool = Field(default=False, description="calibrated, with freeze_fill: a filled hold is kept "
                               "only when its summed squared distance to the KNN consensus does not rise")
    spike_level: float | None = Field(default=None, gt=0, description="calibrated: excursions of at most 3 frames "
                                      "whose two end jumps both exceed this many times twice the joint's median "
                                      "acceleration (and 8 degrees) and agree are flagged and repaired as offsets "
                                      "(selfsim/spikes.py); None = off")
    spike_exact: bool = Field(default=False, description="calibrated, with spike_level: the excursions are "
                              "repaired as offsets over exactly the frames their two jumps bound (not grown, not "
                              "through the other repairs)")
    spike_keep: float | None = Field(default=None, gt=0, le=1, description="calibrated, with spike_exact: an "
                                     "excursion is repaired only when its mean digression is at least spike_least_deg and "
                                     "the repair leaves at most this share of it (selfsim/spikes.py); None = any drop")
    spike_least_deg: float = Field(default=8.0, ge=0, description="calibrated, with spike_keep: least mean "
                                   "digression of an excursion, degrees")
    noise_fix: Literal["off", "lowpass", "capped"] = Field(default="off", description="calibrated: runs the "
                                                           "noise_cues decided are repaired by a low-pass toward the KNN "
                                                           "consensus ('lowpass') or by the KNN word ('capped'), each "
                                                           "cell's edit bounded by its noise amplitude (selfsim/noise.py)")
    noise_cues: tuple[Literal["acceleration", "jitter", "words"], ...] = Field(default=("jitter",), description="calibrated, "
                                                                       "with noise_fix: deciding cues of the runs it repairs")
    noise_null: Literal["take", "words"] = Field(default="take", description="calibrated, with noise_fix capped: the "
                                                 "null amplitude is the joint's median over the take or, per cell, the "
                                                 "median over the KNN words at that frame (noise.word_null)")
    noise_half: int = Field(default=2, ge=1, description="calibrated, with noise_fix: half window, frames")
    noise_factor: float = Field(default=2.0, ge=0, description="calibrated, with noise_fix: a cell moves by at most its "
                                "noise amplitude beyond this many times the joint's median amplitude over the take")
    words_half: int = Field(default=2, ge=1, description="calibrated, with the words cue: half window of the noise "
                            "amplitude of the take and of the KNN words, frames (selfsim/word_noise.py)")
    words_slack: int = Field(default=0, ge=0, description="calibrated, with the words cue: the KNN words' amplitude "
                             "is its largest over +-words_slack frames (a warped word may turn a frame away)")
    words_reach: int | None = Field(default=None, ge=0, description="calibrated, with the words cue: its null level "
                                    "leaves out the clean calibration cells within this many frames of an injected "
                                    "error (the windowed amplitude leaks into them); None = every clean cell")
    floor_only: tuple[Literal["digression", "acceleration", "mirror", "freeze", "range", "jitter", "words"], ...] = Field(
        default=(), description="calibrated: cues the greedy allocation may not use: their weight is their cue_fa "
        "floor only (calibration.cue_floor)")
    words_erode: int = Field(default=0, ge=0, description="calibrated, with the words cue: the cue is its smallest "
                             "over +-words_erode frames (a short spike's leak into clean neighbours does not count)")
    cue_fa: dict[Literal["digression", "acceleration", "mirror", "freeze", "range", "jitter", "words"], float] = Field(
        default_factory=dict, description="calibrated: per cue, a false-alarm rate of its own (share of clean "
        "calibration (word, joint) pairs the cue alone may flag): its weight is at most that level, even where the "
        "greedy allocation of false_alarm leaves it unused (calibration.cue_floor, session 6)")
    shrink_full: float | None = Field(default=1.5, gt=1, description="calibrated: an edited run whose strongest "
                                      "evidence E is below this has its edit scaled by (E - 1) / (shrink_full - 1) "
                                      "(selfsim/run_acceptance.py); None = off")
    shrink_cues: tuple[Literal["digression", "acceleration", "mirror", "freeze", "range", "jitter", "words"], ...] = Field(
        default=("acceleration", "jitter"), description="calibrated: deciding cues of the runs shrink_full applies to")
    accept_margin: float | None = Field(default=None, ge=0, description="calibrated: an edited run is kept only when "
                                        "the squared distance to the KNN consensus it removes exceeds this many times "
                                        "its cells' summed squared typical clean digression; None = off")
    unclaimed_revert: bool = Field(default=False, description="calibrated: a run (not a swap nor an offset) the "
                                   "repair changes nowhere by flag_min_deg or more is left as it was (no silent run)")
    unclaimed_frames: int | None = Field(default=None, ge=1, description="calibrated: unclaimed_revert only for "
                                         "runs of at most this many frames; None = any length")
    accept_offsets: bool = Field(default=False, description="calibrated: accept_margin also tests offset intervals")
    flag_min_deg: float | None = Field(default=10.0, ge=0, description="calibrated: cells the repair changes by "
                                       "less than this many degrees are edited but not reported flagged (a "
                                       "correction smaller than an error); None = every repaired cell")
    flag_min_revert: bool = Field(default=False, description="calibrated: cells flag_min_deg leaves unreported "
                                  "keep their value (no silent edit), except swapped-back chains and offsets")
    flag_min_scope: Literal["all", "swaps"] = Field(default="all", description="calibrated: cells flag_min_deg "
                                                    "applies to: every repaired cell or the swapped-back ones")
    swap_max: int = Field(default=72, ge=2, description="calibrated: longest swap found by its edges, frames at fps")
    mirror_swaps: bool = Field(default=True, description="calibrated: also swap back the runs the mirror cue flags "
                               "where no edge swap overlaps")

    fps: float = Field(default=24.0, gt=0, description="analysis frame rate (§5: 120 Hz reduced to 24 fps)")
    joints: tuple[str, ...] = Field(default=DEFAULT_JOINTS, description="texture joints (canonical names; absent ones are skipped)")
    groups: tuple[JointGroup, ...] = Field(default_factory=_default_groups, description="joint groups of the motion-words")
    source_length: int = Field(default=15, ge=2, description="source word length N, frames")
    source_step: int = Field(default=5, ge=1, description="frames between source words")
    target_length: int = Field(default=20, ge=2, description="target word length M, frames")
    k: int = Field(default=5, ge=1, description="nearest neighbours per word")
    slope_run: int = Field(default=2, ge=1, description="DTW slope constraint: most consecutive steps in one direction")
    exclusion: int | None = Field(default=None, ge=0, description="minima this close to the source word are discarded (frames; None = N/2)")
    threshold: float = Field(default=0.5, ge=0, le=1, description="MDM value above which a cell is erroneous (§4)")
    normalization: Literal["mean", "texture", "median", "spread", "none"] = Field(
        default="mean",
        description="scale M = |T - T̄| is divided by (§3.4): 'mean' = the mean of M's row (the paper), 'texture' = "
                    "the joint's mean rotation angle in T, 'median' = robust_factor x the median of M's row, 'spread' "
                    "= spread_factor x the scatter of the KNN samples about T̄ at that cell (see module doc), 'none'")
    min_scale: float = Field(default=0.1, gt=0, description="floor of the 'texture' row scale, radians (joints that hardly rotate)")
    mean_floor: float = Field(default=0.01, ge=0, description="floor of the 'mean' row scale, radians: a joint whose "
                              "difference is numerically zero everywhere is not blown up to 1")
    robust_factor: float = Field(default=2.5, gt=0, description="'median': the row median is multiplied by this "
                                 "(a cell is flagged above 0.83 x this x its joint's median difference)")
    spread_factor: float = Field(default=3.0, gt=0, description="'spread': the KNN scatter is multiplied by this "
                                 "(a cell is flagged above 0.83 x this x the scatter of its neighbours)")
    noise_floor: float = Field(default=0.035, ge=0, description="'median'/'spread': floor of the noise scale, radians "
                               "(2 degrees; cells whose neighbours agree exactly, joints that never rotate)")
    include_self: bool = Field(default=True, description="search the clip itself as part of its context")
    two_stage: bool = Field(default=False, description="§5: local search first, larger context only around distinct words")
    stage1_groups: tuple[str, ...] = Field(default=("whole",), description="groups of the local first stage")
    knn_method: Literal["pruned", "brute"] = Field(default="pruned", description="exact KNN search: pruned (fast) or brute force")
    warp: Literal["polyphase", "path"] = Field(default="polyphase", description="neighbour to source length: polyphase "
                                               "resampling of the warped target (§3.2) or per-frame mean along the path")
    savgol_window: int = Field(default=7, ge=3, description="Savitzky-Golay window of the repair blending, frames at fps")
    savgol_order: int = Field(default=2, ge=1, description="Savitzky-Golay polynomial order (quadratic)")
    write_bvh: bool = Field(default=True, description="write each cleaned clip as BVH into the step folder")
    heatmaps: bool = Field(default=True, description="write an MDM heatmap PNG per clip into the step folder")

    def groups_tuple(self) -> tuple[tuple[str, tuple[str, ...], int], ...]:
        return tuple((g.name, g.joints, g.drop) for g in self.groups)
