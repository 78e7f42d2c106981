"""One clip through the MDM cleaner: analysis, decision (paper or calibrated) and repair.

``mode="paper"``: the cells whose MDM exceeds ``threshold`` are repaired by
:func:`.repair.repair_texture` (median KNN word, Savitzky-Golay blend), as §3.4 and §4 say.
``mode="calibrated"``: :func:`.calibration.calibrate` fits the detector on the clean
context, :meth:`.calibration.Calibration.detect` flags the take's cells and
:func:`.bounded_repair.bounded_repair` repairs them (swaps found by their edges,
:mod:`.swaps`; offsets between two consistent jumps, :mod:`.offsets`; the KNN word
otherwise). ``agree`` drops runs only the digression flagged that no other cue backs;
``flag_rule: repaired`` reports only the flags whose repair held up. Session 4 (docs/cleaning.md):
``acc_persist`` caps the acceleration cue of isolated kinks at the take (fitted without it),
``acc_body`` drops the acceleration flags of whole-body jolts, ``freeze_still`` grows freeze
flags over the still interval (session 5: ``freeze_moving``, only where the consensus moves),
``flag_min_deg`` reports only edits of an error's size; session 5 ``shrink_full`` scales the edit
of a weakly evidenced acceleration/jitter run by its evidence and ``accept_margin`` (off) keeps a
run only on a consensus gain above the clean scatter (:mod:`.run_acceptance`); session 6
``freeze_hold`` counts the freeze cue only on holds (frames turning less than 0.05 degrees per
frame) and ``freeze_fill`` repairs a flagged hold as a gap (:mod:`.holds`). Both
modes carry the repair to the input frames with :func:`.repair.apply_to_input`.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from mocapflow.framework import quaternions as quat
from mocapflow.framework.motion import Motion


@dataclass
class CleanResult:
    """One clip through :meth:`MDMCleaner.clean` (analysis rate unless said).

    Attributes
    ----------
    analysis : DigressionResult (:mod:`.mdm`)
    flags : ndarray of bool, shape (T, m)
        Cells the decision flagged.
    value : ndarray of shape (T, m), in [0, 1]
        The map shown and stored (> 0.5 = flagged): the MDM (paper) or ``1 - 2^(-e^2)`` of
        the evidence (calibrated).
    cue : ndarray of object, shape (T, m)
        Name of the cue that flagged each flagged cell (``mdm`` in paper mode, ``mirror``
        for cells swapped back), None elsewhere.
    repaired : ndarray of shape (T, m, 4)
        The repaired texture.
    edited : ndarray of bool, shape (T, m)
        Cells whose rotation changed.
    cleaned : Motion
        The cleaned clip at the input rate.
    edits : pyarrow.Table
        One row per changed input cell (:func:`.repair.edits_table` plus ``cue``, ``edit_deg``).
    calibration : Calibration or None
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

    def map_result(self) -> Any:
        """An object :func:`.repair.map_to_input` takes, carrying ``value`` as its map."""
        from types import SimpleNamespace

        return SimpleNamespace(mdm=self.value, texture=self.analysis.texture)


def _input_cues(motion: Motion, texture: Any, cue: np.ndarray, frames: np.ndarray, joints: np.ndarray) -> list:
    """Cue of the analysis cell nearest each edited input cell (frame, skeleton joint)."""
    col = {int(j): c for c, j in enumerate(texture.joint_index)}
    x = np.rint(frames * (texture.fps / motion.fps)).astype(np.int64).clip(0, len(cue) - 1)
    out = []
    for f, j in zip(x.tolist(), joints.tolist()):
        c = col.get(int(j))
        v = cue[f, c] if c is not None else None
        if v is None and c is not None:  # an input frame next to a flagged analysis frame
            near = [cue[g, c] for g in (f - 1, f + 1) if 0 <= g < len(cue) and cue[g, c] is not None]
            v = near[0] if near else None
        out.append(v)
    return out


def _edits(motion: Motion, cleaned: Motion, changed: np.ndarray, texture: Any, cue: np.ndarray) -> pa.Table:
    from .repair import edits_table

    tab = edits_table(motion, cleaned, changed)
    f = tab["frame"].to_numpy()
    j = tab["joint"].to_numpy()
    deg = np.rad2deg(quat.geodesic_angle(motion.rotations[f, j], cleaned.rotations[f, j])) if len(f) else np.zeros(0)
    tab = tab.append_column("edit_deg", pa.array(deg.astype(np.float32)))
    return tab.append_column("cue", pa.array(_input_cues(motion, texture, cue, f, j), pa.string()))


def _agreeing(flags: np.ndarray, dom: np.ndarray, ev: np.ndarray, level: float) -> np.ndarray:
    """``flags`` without the runs of one joint flagged by the digression alone that no other
    cue backs: no cell of the run (+-1 frame) has acceleration or freeze evidence above
    ``level`` (an offset has jumps at its ends, a freeze its stillness; a rare clean pose
    neither)."""
    from .bounded_repair import _runs
    from .cues import CUES

    out = flags.copy()
    other = np.maximum(ev[..., CUES.index("acceleration")], ev[..., CUES.index("freeze")])
    other = np.maximum(other, ev[..., CUES.index("jitter")])
    other = np.maximum(other, ev[..., CUES.index("words")])
    dig = CUES.index("digression")
    for j in np.flatnonzero(flags.any(axis=0)):
        for a, b in _runs(flags[:, j]):
            if np.all(dom[a:b, j] == dig) and not (other[max(0, a - 1):b + 1, j] > level).any():
                out[a:b, j] = False
    return out


def _body_jolts_dropped(flags: np.ndarray, dom: np.ndarray, least: int) -> np.ndarray:
    """``flags`` without the acceleration flags of the frames where at least ``least`` joints
    are flagged by the acceleration cue: a jolt of the whole body (a stumble, a landing, a
    capture-wide timing glitch) is no joint error, and a KNN word cannot repair it. Swaps,
    whose edges make six chain joints jump at once, are found by their edges (:mod:`.swaps`),
    not by these flags."""
    from .cues import CUES

    acc = flags & (dom == CUES.index("acceleration"))
    jolt = acc.sum(axis=1) >= least
    return flags & ~(acc & jolt[:, None])


def _freezes_grown(flags: np.ndarray, dom: np.ndarray, q: np.ndarray, still: float, mean_q: np.ndarray | None = None,
                   moving: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Runs flagged by the freeze cue grown over the whole interval where the joint is still
    (moves less than ``still`` radians per frame): a frozen joint (a marker lost, its last
    value held) is exactly still from its first frozen frame to its last, and the freeze cue
    sees only the middle of it. With ``mean_q`` and ``moving`` (radians per frame), only
    over the frames where the KNN consensus moves at least that much (its mean speed over
    +-2 frames): where the consensus holds the joint still too, the stillness is the
    motion's. Returns the grown flags and deciding cues."""
    from .bounded_repair import _runs
    from .cues import CUES, _window_mean, speed

    fz = CUES.index("freeze")
    v = speed(q)
    calm = v < still
    calm[1:] |= calm[:-1]  # the frame after a still step holds the same pose
    if mean_q is not None and moving is not None:
        calm &= _window_mean(speed(mean_q), 2) >= moving
    out, dom = flags.copy(), dom.copy()
    seed = flags & (dom == fz)
    for j in np.flatnonzero(seed.any(axis=0)):
        for a, b in _runs(calm[:, j]):
            if seed[a:b, j].any() and b - a >= 3:
                new = ~out[a:b, j]
                out[a:b, j] = True
                dom[a:b, j][new] = fz
    return out, dom


def _run_checks(p: Any, res: Any, cal: Any, new24: np.ndarray, flags: np.ndarray, evidence: np.ndarray,
                dom: np.ndarray, swapped: np.ndarray, offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``shrink_full`` and ``accept_margin`` (:mod:`.run_acceptance`) on the bounded repair;
    returns the repair and its edited cells."""
    from .cues import CUES
    from .run_acceptance import accept_runs, shrink_weak_runs

    q = res.texture.q
    edited = np.any(new24 != q, axis=-1)
    exclude = swapped | offset
    if p.shrink_full is not None:
        eligible = flags & np.isin(dom, [CUES.index(c) for c in p.shrink_cues])
        new24 = shrink_weak_runs(q, new24, edited, exclude, evidence, eligible, p.shrink_full)
        edited = np.any(new24 != q, axis=-1)
    if p.unclaimed_revert and p.flag_min_deg is not None:
        from .run_acceptance import edit_runs

        size = quat.geodesic_angle(new24, q)
        for j, a, b in edit_runs(edited, exclude):
            short = p.unclaimed_frames is None or b - a <= p.unclaimed_frames
            if short and size[a:b, j].max() < np.deg2rad(p.flag_min_deg):
                new24[a:b, j] = q[a:b, j]
        edited = np.any(new24 != q, axis=-1)
    if p.accept_margin is not None:
        # a joint's typical clean distance to T̄: the calibration's, or the take's own when larger
        own = np.median(quat.geodesic_angle(q, res.mean_texture), axis=0)
        tau = np.maximum(cal.scales["digression"], own)
        new24, _ = accept_runs(q, new24, res.mean_texture, edited, swapped if p.accept_offsets else exclude,
                               tau, p.accept_margin)
        edited = np.any(new24 != q, axis=-1)
    return new24, edited


def cue_of_run(cue: np.ndarray, grown: np.ndarray) -> np.ndarray:
    """For the cells of ``grown`` (T, m), the cue of the nearest flagged cell of the same joint
    (the run they extend), values for ``cue[grown]``."""
    out = []
    for f, j in zip(*np.nonzero(grown)):
        col = cue[:, j]
        have = np.flatnonzero(col != None)  # noqa: E711 - object array: elementwise comparison with None
        out.append(col[have[np.argmin(np.abs(have - f))]] if len(have) else None)
    return np.array(out, dtype=object)


def clean_motion(cleaner: Any, motion: Motion, context: Any = None, contacts: Sequence[Any] = (),
                 analysis: Any = None, calibration: Any = None) -> Any:
    """Analyse, decide and repair one clip; returns :class:`.mdm.CleanResult`.

    ``analysis`` (a :class:`.mdm.DigressionResult` of this clip and context) and
    ``calibration`` (a :class:`.calibration.Calibration` fitted on this context) are reused
    when given (the evaluation harness runs several decisions on one analysis)."""
    from .bounded_repair import bounded_repair
    from .calibration import calibrate
    from .cues import CUES
    from .motion_words import context_motions
    from .repair import apply_to_input, repair_texture

    p = cleaner.params
    res = analysis if analysis is not None else cleaner.analyse(motion, context)
    cue = np.full(res.mdm.shape, None, dtype=object)
    if p.mode == "paper" or not res.neighbours:
        flags = res.mdm > p.threshold
        new24, edited = repair_texture(res, p.threshold, p.savgol_window, p.savgol_order, contacts)
        cue[flags] = "mdm"
        value, cal = res.mdm, None
    else:
        others = context_motions(motion, context, True)[1:]
        # the words cue (selfsim/word_noise.py, session 7) needs the warped KNN words: computed only when used
        word_half = p.words_half if "words" in p.cues else None
        analyser = cleaner.clone(include_self=True)  # the calibration analyses each clip with itself included
        cal = calibration if calibration is not None else calibrate(motion, others, analyser.analyse, res.joints, p.fps,
                        false_alarm=p.false_alarm, frames=p.calibration_frames, density=p.calibration_density,
                        seed=p.calibration_seed, null_quantile=p.null_quantile, cues=p.cues,
                        acc_persist=p.acc_persist if p.acc_persist_fit else None,
                        jitter_half=p.jitter_half, freeze_hold=p.freeze_hold,
                        cue_fa=dict(p.cue_fa), word_half=word_half, word_slack=p.words_slack,
                        word_erode=p.words_erode, floor_only=p.floor_only,
                        null_reach=None if p.words_reach is None else {"words": p.words_reach})
        if p.acc_persist is not None and not p.acc_persist_fit:
            # the persistence rule only removes flags: fitted without it, applied to the take
            cal = dataclasses.replace(cal, acc_persist=p.acc_persist)
        word_amp = None
        if cal.word_half is not None:
            from .word_noise import word_amplitude

            word_amp = word_amplitude(res.neighbours[0], res.mean_texture, cal.word_half)
        per_cue = cal.evidence(res.texture.q, res.mean_texture, res.spread, res.joints, word_amp)  # once: detect and agree
        flags, evidence, dom = cal.decide(per_cue)
        if p.agree is not None:
            flags = _agreeing(flags, dom, per_cue, p.agree)
        jolts = None
        if p.acc_body is not None:
            kept = _body_jolts_dropped(flags, dom, p.acc_body)
            if not p.merge_jolts:
                jolts = flags & ~kept  # dropped as a body jolt: no merged run bridges them either
            flags = kept
        if p.spike_level is not None:
            # short excursions found by their two jumps (selfsim/spikes.py), repaired as offsets
            from .spikes import spike_runs

            spk = spike_runs(res.texture.q, p.spike_level) & ~flags
            if p.spike_exact:
                spk_only = spk  # repaired over exactly the excursion, after the other repairs
            else:
                flags = flags | spk
                dom = np.where(spk, CUES.index("acceleration"), dom)
        if p.freeze_still is not None:
            flags, dom = _freezes_grown(flags, dom, res.texture.q, np.deg2rad(p.freeze_still), res.mean_texture,
                                        None if p.freeze_moving is None else np.deg2rad(p.freeze_moving))
        holds = np.zeros(flags.shape, bool)
        if p.freeze_fill != "off" and p.freeze_hold is not None:
            # a held joint is a gap: filled from its two sides (selfsim/holds.py), not moved towards a
            # consensus chosen on the frozen take; the other repairs leave its cells alone (a clean hold
            # merged into a spike's run would hide the spike's two jumps from the offset repair)
            from .holds import fill_holds

            fill24, filled, holds = fill_holds(res.texture.q, res.texture.q, flags & (dom == CUES.index("freeze")),
                                               p.freeze_hold, p.freeze_fill, res.mean_texture,
                                               p.freeze_guard)
            flags_hold = flags & holds
            flags = flags & ~holds
        noisy = np.zeros(flags.shape, bool)
        if p.noise_fix != "off":
            # a noise run's edit is bounded by its own measured noise amplitude (selfsim/noise.py):
            # 'lowpass' smooths it toward T̄, 'capped' caps the KNN word's edit; a clean fast joint
            # the jitter cue fires on has no amplitude beyond its null and is left as it was
            noisy = flags & np.isin(dom, [CUES.index(c) for c in p.noise_cues])
            if p.noise_fix == "lowpass":
                flags = flags & ~noisy
        mirror_flags = flags & (dom == CUES.index("mirror"))
        extra: dict = {}
        local = np.isin(dom, [CUES.index("acceleration"), CUES.index("mirror")])
        if p.gap_cap:
            local &= flags  # a cell a merged run takes in is bounded as an unflagged one (max_edit)
        cap = np.where(local, np.pi, np.deg2rad(p.max_edit))
        if p.noise_fix == "capped" and noisy.any():
            from .noise import noise_cap

            if p.noise_null == "words":
                from .noise import lowpassed, word_null

                amp = lowpassed(res.texture.q, res.mean_texture, p.noise_half)[1]
                ncap = np.maximum(amp - p.noise_factor * np.nan_to_num(word_null(res, p.noise_half), nan=np.inf), 0.0)
            else:
                ncap = noise_cap(res.texture.q, res.mean_texture, p.noise_half, p.noise_factor)
            cap = np.where(noisy, np.minimum(cap, ncap), cap)
        if not p.merge_mirror and mirror_flags.any():
            # a mirror flag whose swap-back does not hold up is left as it is (bounded_repair); no
            # merged run takes it in either (it would get the mirror cue's unbounded edit)
            jolts = mirror_flags if jolts is None else jolts | mirror_flags
        new24, edited, swapped = bounded_repair(res, flags, p.swap_gain, mirror_flags=mirror_flags, cap=cap,
                                                swap_level=p.swap_level, swap_max=p.swap_max,
                                                mirror_swaps=p.mirror_swaps, offset_level=p.offset_level,
                                                extra=extra, interp=dom == CUES.index("acceleration"),
                                                interp_max=p.interp_max, merge_gap=p.merge_gap, no_merge=jolts)
        if p.noise_fix == "capped" and noisy.any():
            still = noisy & (cap <= 0) & ~swapped & ~extra["offset"]  # no noise beyond the null: as it was
            new24 = np.where(still[..., None], res.texture.q, new24)
            edited = edited & ~still
        elif noisy.any():
            from .noise import noise_repair

            noisy &= ~edited & ~swapped & ~extra["offset"]
            smooth, done = noise_repair(res.texture.q, res.mean_texture, noisy, p.noise_half, p.noise_factor)
            new24 = np.where(done[..., None], smooth, new24)
            edited = edited | done
            flags = flags | noisy
        if p.spike_level is not None and p.spike_exact and spk_only.any():
            from .spikes import repair_spikes

            spk_only &= ~edited & ~swapped
            done = repair_spikes(res.texture.q, res.mean_texture, new24, spk_only, p.spike_keep,
                                 np.deg2rad(p.spike_least_deg))
            edited = edited | done
            extra["offset"] = extra["offset"] | done
            dom = np.where(done, CUES.index("acceleration"), dom)
            flags = flags | done
        if p.shrink_full is not None or p.accept_margin is not None or p.unclaimed_revert:
            new24, edited = _run_checks(p, res, cal, new24, flags, evidence, dom, swapped, extra["offset"])
            swapped &= edited
            extra["offset"] &= edited
        if holds.any():
            filled = filled & ~swapped & ~extra["offset"]  # a swap found by its edges wins
            new24 = np.where(filled[..., None], fill24, new24)
            edited = edited | filled
            flags = flags | (flags_hold & ~swapped & ~extra["offset"])
        else:
            filled = holds
        cue[flags] = np.array(CUES, dtype=object)[dom[flags]]
        cue[filled] = "freeze"
        grown = extra["offset"] & ~flags  # the rest of an offset interval, between its two jumps
        cue[grown] = cue_of_run(cue, grown)
        cue[swapped] = "mirror"
        if p.flag_rule == "repaired":
            # a flag whose repair did not hold up (not nearer the consensus, a swap that did not
            # smooth its ends) is no claim the cleaner acts on
            cue[flags & ~edited] = None
            flags = flags & edited
        flags = flags | swapped | extra["offset"] | filled
        if p.flag_min_deg is not None:
            # a change below the size of an error is a correction, not a claim: the swapped-back
            # hip of a swapped leg moves a few degrees (restored exactly, still edited)
            small = quat.geodesic_angle(new24, res.texture.q) < np.deg2rad(p.flag_min_deg)
            if p.flag_min_scope == "swaps":
                small &= swapped
            cue[flags & small] = None
            flags = flags & ~small
            if p.flag_min_revert:
                # no silent edits: a cell not claimed is left as it was, except the joints of a
                # swapped-back chain and offset intervals (restored whole)
                back = small & edited & ~swapped & ~extra["offset"]
                new24 = np.where(back[..., None], res.texture.q, new24)
                edited = edited & ~back
        value = 1.0 - np.exp2(-(evidence ** 2))
        value = np.where(flags, np.maximum(value, 0.5 + 1e-6), np.minimum(value, 0.5))
    # the calibrated modes never turn an input frame away from its repaired pose (repair.py)
    cleaned, changed = apply_to_input(motion, res.texture, new24, edited, guard=p.mode != "paper")
    return CleanResult(res, flags, value, cue, new24, edited, cleaned, _edits(motion, cleaned, changed, res.texture, cue),
                       cal)
