"""The decision rule of ``mode: calibrated``: which cells are errors, and how each is repaired.

With the measured constants of :mod:`.constants`: flag cells whose largest cue evidence
exceeds 1; drop digression-only runs no other cue backs and whole-body jolts; grow freeze
flags over the still interval; fill holds from the consensus (:mod:`.holds`), swap limbs
back, take offsets out, repair the rest within bounds (:mod:`.bounded_repair`); scale weak
runs' edits by their evidence; report only cells changed by at least ``FLAG_MIN_DEG``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat

from .bounded_repair import _runs
from .constants import (
    ACC_BODY,
    AGREE,
    CUES,
    FLAG_MIN_DEG,
    FREEZE_HOLD,
    FREEZE_MOVING,
    HOLD_SPEED,
    SHRINK_CUES,
    SHRINK_FULL,
)

_DIG, _ACC, _MIRROR, _FREEZE, _JITTER = (
    CUES.index(c) for c in ("digression", "acceleration", "mirror", "freeze", "jitter")
)


def _agreeing(flags: np.ndarray, dom: np.ndarray, ev: np.ndarray, level: float) -> np.ndarray:
    """``flags`` without the digression-only runs of one joint that no acceleration, freeze or
    jitter evidence above ``level`` backs within +-1 frame (a rare clean pose has neither
    an offset's jumps nor a freeze's stillness)."""
    out = flags.copy()
    other = np.maximum(np.maximum(ev[..., _ACC], ev[..., _FREEZE]), ev[..., _JITTER])
    for j in np.flatnonzero(flags.any(axis=0)):
        for a, b in _runs(flags[:, j]):
            if np.all(dom[a:b, j] == _DIG) and not (other[max(0, a - 1) : b + 1, j] > level).any():
                out[a:b, j] = False
    return out


def _body_jolts_dropped(flags: np.ndarray, dom: np.ndarray, least: int) -> np.ndarray:
    """``flags`` without the acceleration flags of frames where at least ``least`` joints have
    them: a whole-body jolt is no joint error and no KNN word repairs it (swaps are found by
    their edges, :mod:`.swaps`)."""
    acc = flags & (dom == _ACC)
    jolt = acc.sum(axis=1) >= least
    return flags & ~(acc & jolt[:, None])


def _freezes_grown(
    flags: np.ndarray,
    dom: np.ndarray,
    q: np.ndarray,
    still: float,
    mean_q: np.ndarray | None = None,
    moving: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Freeze-cue runs grown over the whole interval where the joint moves less than ``still``
    rad/frame (a frozen joint is exactly still throughout) and, given ``mean_q``, the
    consensus moves at least ``moving`` (else the stillness is the motion's). Returns the flags and deciding cues."""
    from .cues import _window_mean, speed

    v = speed(q)
    calm = v < still
    calm[1:] |= calm[:-1]  # the frame after a still step holds the same pose
    if mean_q is not None and moving is not None:
        calm &= _window_mean(speed(mean_q), 2) >= moving
    out, dom = flags.copy(), dom.copy()
    seed = flags & (dom == _FREEZE)
    for j in np.flatnonzero(seed.any(axis=0)):
        for a, b in _runs(calm[:, j]):
            if seed[a:b, j].any() and b - a >= 3:
                new = ~out[a:b, j]
                out[a:b, j] = True
                dom[a:b, j][new] = _FREEZE
    return out, dom


def shrink_weak_runs(
    q: np.ndarray,
    new: np.ndarray,
    edited: np.ndarray,
    exclude: np.ndarray,
    evidence: np.ndarray,
    eligible: np.ndarray,
    full: float,
) -> np.ndarray:
    """``new`` (T, m, 4) with the edit of each weak run scaled by its evidence: a run of
    ``edited & ~exclude`` whose strongest cell is ``eligible`` with evidence ``E < full`` is
    slerped by ``(E - 1) / (full - 1)`` (a clean knee's kink barely over its level moves a
    little; the edit follows the evidence, not the distance to T̄ every fast joint has).
    """
    out = new.copy()
    mask = edited & ~exclude
    for j in np.flatnonzero(mask.any(axis=0)):
        for a, b in _runs(mask[:, j]):
            ev = evidence[a:b, j]
            k = int(np.argmax(ev))
            if not eligible[a + k, j]:
                continue
            s = float(np.clip((ev[k] - 1.0) / (full - 1.0), 0.0, 1.0))
            if s < 1.0:
                out[a:b, j] = q[a:b, j] if s == 0.0 else quat.slerp(q[a:b, j], new[a:b, j], np.full(b - a, s))
    return out


def cue_of_run(cue: np.ndarray, grown: np.ndarray) -> np.ndarray:
    """For the cells of ``grown`` (T, m), the cue of the nearest flagged cell of the same joint
    (the run they extend), values for ``cue[grown]``."""
    out = []
    for f, j in zip(*np.nonzero(grown), strict=True):
        col = cue[:, j]
        have = np.flatnonzero(col != None)  # noqa: E711 - object array: elementwise comparison with None
        out.append(col[have[np.argmin(np.abs(have - f))]] if len(have) else None)
    return np.array(out, dtype=object)


def calibrated_decision(res: Any, calibration: Any, max_edit: float) -> tuple[np.ndarray, ...]:
    """Decide and repair one analysed take with a fitted ``calibration``: flags (T, m), map
    value ``1 - 2^(-e^2)`` (> 0.5 = flagged), cue name per flagged cell, repaired texture
    (T, m, 4) and the changed cells."""
    from .bounded_repair import bounded_repair
    from .holds import fill_holds

    q, mean_q = res.texture.q, res.mean_texture
    per_cue = calibration.evidence(q, mean_q, res.joints)
    flags, evidence, dom = calibration.decide(per_cue)
    flags = _agreeing(flags, dom, per_cue, AGREE)
    kept = _body_jolts_dropped(flags, dom, ACC_BODY)
    no_merge = flags & ~kept  # a body jolt's dropped flags: no merged run bridges them either
    flags = kept
    flags, dom = _freezes_grown(flags, dom, q, HOLD_SPEED, mean_q, FREEZE_MOVING)
    # a held joint is a gap filled from its two sides, not moved towards a consensus chosen on
    # the frozen take; the other repairs leave its cells alone (a clean hold merged into a
    # spike's run would hide the spike's two jumps from the offset repair)
    fill24, filled, holds = fill_holds(q, flags & (dom == _FREEZE), FREEZE_HOLD, mean_q)
    flags_hold = flags & holds
    flags = flags & ~holds
    mirror_flags = flags & (dom == _MIRROR)
    # a mirror flag whose swap-back does not hold up is left as it is; no merged run takes it in
    no_merge |= mirror_flags
    cap = np.where(np.isin(dom, [_ACC, _MIRROR]), np.pi, np.deg2rad(max_edit))
    new24, edited, swapped, offset = bounded_repair(res, flags, mirror_flags, cap, no_merge, holds)
    eligible = flags & np.isin(dom, [CUES.index(c) for c in SHRINK_CUES])
    new24 = shrink_weak_runs(q, new24, edited, swapped | offset, evidence, eligible, SHRINK_FULL)
    edited = np.any(new24 != q, axis=-1)
    swapped &= edited
    offset &= edited
    if holds.any():
        filled &= ~swapped & ~offset  # a swap found by its edges wins
        new24 = np.where(filled[..., None], fill24, new24)
        edited |= filled
        flags |= flags_hold & ~swapped & ~offset
    else:
        filled = holds
    cue = np.full(flags.shape, None, dtype=object)
    cue[flags] = np.array(CUES, dtype=object)[dom[flags]]
    cue[filled] = "freeze"
    grown = offset & ~flags  # the rest of an offset interval, between its two jumps
    cue[grown] = cue_of_run(cue, grown)
    cue[grown & (cue == None)] = "steps"  # noqa: E711 - an offset the scan found by its two steps alone
    cue[swapped] = "mirror"
    # a flag whose repair did not hold up (not nearer the consensus, a swap that did not smooth
    # its ends) is no claim the cleaner acts on
    cue[flags & ~edited] = None
    flags = (flags & edited) | swapped | offset | filled
    # a change below the size of an error is a correction, not a claim: the swapped-back hip
    # of a swapped leg moves a few degrees (restored exactly, still edited)
    small = quat.geodesic_angle(new24, q) < np.deg2rad(FLAG_MIN_DEG)
    cue[flags & small] = None
    flags &= ~small
    value = 1.0 - np.exp2(-(evidence**2))
    value = np.where(flags, np.maximum(value, 0.5 + 1e-6), np.minimum(value, 0.5))
    return flags, value, cue, new24, edited
