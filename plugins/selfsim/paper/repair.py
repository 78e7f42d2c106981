"""Repair (Aristidou 2018 §4): flagged cells take the medoid KNN word's value (an actual
motion, not a mean; with a contact, the word whose effector lands closest), blended by a
quadratic Savitzky-Golay filter, at the analysis rate; :func:`apply_to_input` carries it to
the input frames. :func:`sparse_reconstruction`: full body from some joints (Fig. 8).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion, forward_kinematics
from mocapflow.framework.schema import fixed_list

from .knn import ContextTextures, WordNeighbours, knn_search
from .motion_words import motion_texture, resolve_groups, source_word_starts


@dataclass(frozen=True)
class Contact:
    """An end-effector contact: canonical ``joint`` at analysis ``frame`` should be at
    ``position`` (metres, in the facing-aligned frame of the analysis texture)."""

    joint: str
    frame: int
    position: tuple[float, float, float]


def _analysis_times(motion: Motion, fps: float) -> np.ndarray:
    """Input frames expressed in analysis frames (float)."""
    return np.arange(motion.n_frames) * (fps / motion.fps)


def map_to_input(res: Any, motion: Motion) -> np.ndarray:
    """MDM at the input clip's frames, shape (T_in, J), linear in time; 0 off the texture."""
    x = _analysis_times(motion, res.texture.fps)
    out = np.zeros((motion.n_frames, motion.n_joints))
    grid = np.arange(res.mdm.shape[0])
    for c, j in enumerate(res.texture.joint_index):
        out[:, j] = np.interp(x, grid, res.mdm[:, c])
    return out


def _medoid(warped: np.ndarray, valid: np.ndarray, mask: np.ndarray) -> int:
    """Index of the KNN word (K, N, m, 4) with the least summed distance to the others."""
    idx = np.flatnonzero(valid)
    if len(idx) <= 2:
        return int(idx[0])
    w = warped[idx][..., mask, :]
    d = np.abs(np.einsum("anjc,bnjc->abnj", w, w))
    cost = (np.arccos(np.clip(d, 0, 1)) ** 2).sum(axis=(2, 3)).sum(axis=1)
    return int(idx[np.argmin(cost)])


def _contact_choice(
    motion24: Motion, tex_index: np.ndarray, candidates: np.ndarray, valid: np.ndarray, s: int, contact: Contact
) -> int:
    """KNN word whose effector lands closest to the contact at ``contact.frame``."""
    f = contact.frame
    e = motion24.skeleton.canonical.get(contact.joint)
    if e is None:
        raise DataError(f"contact joint {contact.joint!r} is not in the skeleton")
    best, best_d = -1, np.inf
    for kk in np.flatnonzero(valid):
        rot = motion24.rotations[f : f + 1].copy()
        rot[0, tex_index] = candidates[kk, f - s]
        pos, _ = forward_kinematics(motion24.skeleton, motion24.root_translation[f : f + 1], rot)
        d = float(np.linalg.norm(pos[0, e] - np.asarray(contact.position)))
        if d < best_d:
            best, best_d = int(kk), d
    return best


def repair_texture(
    res: Any, threshold: float = 0.5, window: int = 7, order: int = 2, contacts: Sequence[Contact] = ()
) -> tuple[np.ndarray, np.ndarray]:
    """Repaired texture (T, m, 4) and the flagged cells (T, m); only flagged cells differ."""
    q = res.texture.q
    t_count, m = q.shape[:2]
    flagged = res.mdm > threshold
    new = q.copy()
    if not flagged.any() or not res.neighbours:
        return new, flagged
    n = res.neighbours[0].warped.shape[3]
    proposal = np.full((t_count, m, 4), np.nan)
    for neigh in res.neighbours:
        _propose(neigh, n, q, flagged, proposal, res, contacts)
    have = flagged & ~np.isnan(proposal[..., 0])
    for j in np.flatnonzero(have.any(axis=0)):
        track = q[:, j].copy()
        rows = np.flatnonzero(have[:, j])
        rep = proposal[rows, j]
        rep = np.where(np.sum(rep * track[rows], -1, keepdims=True) < 0, -rep, rep)  # same hemisphere
        track[rows] = rep
        if t_count >= window:
            from scipy.signal import savgol_filter  # lazy: scipy.signal costs seconds at import

            smooth = savgol_filter(track, window, order, axis=0, mode="interp")
        else:
            smooth = track
        new[rows, j] = quat.normalize(smooth[rows])
    return new, have


def _propose(
    neigh: WordNeighbours,
    n: int,
    q: np.ndarray,
    flagged: np.ndarray,
    proposal: np.ndarray,
    res: Any,
    contacts: Sequence[Contact],
) -> None:
    t_count, m = q.shape[:2]
    starts = neigh.starts
    centres = starts + (n - 1) / 2.0
    # nearest word centre per frame (only words that cover the frame)
    word_of = np.full(t_count, -1, np.int64)
    for f in range(t_count):
        cover = np.flatnonzero((starts <= f) & (f < starts + n))
        if len(cover):
            word_of[f] = cover[np.argmin(np.abs(centres[cover] - f))]
    mean_d = np.where(neigh.target >= 0, neigh.distance, np.nan)
    with np.errstate(all="ignore"):
        score = np.nanmean(mean_d, axis=2)  # (G, S)
    score = np.where(np.isnan(score), np.inf, score)
    g_of = np.full((len(starts), m), -1, np.int64)
    for j in range(m):
        holders = np.flatnonzero(neigh.groups.mask[:, j])
        if len(holders):
            g_of[:, j] = holders[np.argmin(score[holders], axis=0)]
    chosen: dict[tuple[int, int], int] = {}
    by_frame = {c.frame: c for c in contacts}
    for f, j in zip(*np.nonzero(flagged), strict=True):
        w = word_of[f]
        if w < 0 or g_of[w, j] < 0:
            continue
        g = g_of[w, j]
        valid = neigh.target[g, w] >= 0
        if not valid.any():
            continue
        key = (g, w)
        if key not in chosen:
            s = int(starts[w])
            hit = [c for fr, c in by_frame.items() if s <= fr < s + n]
            if hit:
                chosen[key] = _contact_choice(
                    res.texture.motion, res.texture.joint_index, neigh.warped[g, w], valid, s, hit[0]
                )
            else:
                chosen[key] = _medoid(neigh.warped[g, w], valid, neigh.groups.mask[g])
        proposal[f, j] = neigh.warped[g, w, chosen[key], f - starts[w], j]


def repair_motion(motion: Motion, res: Any, params: Any, contacts: Sequence[Contact] = ()) -> tuple[Motion, pa.Table]:
    """Cleaned motion at the input rate and its edits table (see :func:`edits_table`)."""
    new24, flagged = repair_texture(res, params.threshold, params.savgol_window, params.savgol_order, contacts)
    cleaned, changed = apply_to_input(motion, res.texture, new24, flagged)
    return cleaned, edits_table(motion, cleaned, changed)


#: Guard slack, radians: a carried correction that ends this much farther from the repaired
#: pose than the input frame was is refused (rounding of an exact carry stays far below it).
GUARD_SLACK = 1e-6


def apply_to_input(
    motion: Motion, texture: Any, new24: np.ndarray, flagged: np.ndarray, guard: bool = False
) -> tuple[Motion, np.ndarray]:
    """Carry a repaired texture (T, m, 4), edited at ``flagged`` (T, m), to the input frames
    as a per-joint right correction ``q_in * delta`` slerped in time, applied only next to a
    flagged analysis frame; returns the motion and changed (T_in, J).

    ``guard``: keep a frame's correction only when it lands nearer (by :data:`GUARD_SLACK`)
    the repaired pose at its time than it was; a correction computed on an analysis sample
    that caught a glitch shorter than one analysis frame would otherwise turn the clean input
    frames beside it (CMU 16_15's left arm, its first two 120-fps frames).
    """
    q24 = texture.q
    delta = quat.mul(quat.conjugate(q24), new24)  # right correction: new = old * delta
    x = _analysis_times(motion, texture.fps)
    i0 = np.minimum(np.floor(x).astype(np.int64), len(q24) - 1)
    i1 = np.minimum(i0 + 1, len(q24) - 1)
    w = x - i0
    rot = motion.rotations.copy()
    # input frames in the texture's (facing-aligned) frame, where the repaired poses live
    local = None
    changed = np.zeros((motion.n_frames, motion.n_joints), bool)
    for c, j in enumerate(texture.joint_index):
        hit = (flagged[i0, c] & (w < 1.0)) | (flagged[i1, c] & (w > 0.0))
        if not hit.any():
            continue
        d0 = np.where(flagged[i0, c][:, None], delta[i0, c], quat.identity((len(x),)))
        d1 = np.where(flagged[i1, c][:, None], delta[i1, c], quat.identity((len(x),)))
        d = quat.slerp(d0, d1, w)
        if guard:
            hit &= ~_snap_edges(d, motion.rotations[:, j], flagged[:, c], delta[:, c], x)
            if local is None:
                local = _texture_frame(motion).rotations
            target = quat.slerp(new24[i0[hit], c], new24[i1[hit], c], w[hit])
            was = quat.geodesic_angle(local[hit, j], target)
            now = quat.geodesic_angle(quat.mul(local[hit, j], d[hit]), target)
            hit[np.flatnonzero(hit)[now > was + GUARD_SLACK]] = False
        rot[hit, j] = quat.normalize(quat.mul(motion.rotations[hit, j], d[hit]))
        changed[hit, j] = True
    return motion.with_arrays(rotations=rot), changed


#: An input frame's step is an edge when it is at least this many times every other step
#: within one analysis frame of it, and at least ``SNAP_MIN_DEG`` degrees.
SNAP_RATIO, SNAP_MIN_DEG = 2.0, 3.0


def _snap_edges(d: np.ndarray, track: np.ndarray, flagged: np.ndarray, delta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Move the edges of each edited run of one joint to the input rate, in place on the
    corrections ``d`` (T_in, 4): between the last clean analysis frame and the first edited
    one (and the last edited and the first clean), the input frame where ``track`` (T_in, 4)
    jumps most starts (ends) the error; the frames on its error side take the run's whole
    end correction and the others none, instead of a correction slerped in time. An edge with
    no clear jump (:data:`SNAP_RATIO`, :data:`SNAP_MIN_DEG`) keeps the slerp. Returns the
    input frames now left as they are (T_in,)."""
    out = np.zeros(len(track), bool)
    if len(track) < 3:
        return out
    step = np.zeros(len(track))
    step[1:] = quat.geodesic_angle(track[1:], track[:-1])
    ident = quat.identity(())
    t24 = len(flagged)
    edge = np.diff(np.concatenate([[False], flagged, [False]]).astype(np.int8))
    for f, into in [(int(a), True) for a in np.flatnonzero(edge == 1)] + [
        (int(b), False) for b in np.flatnonzero(edge == -1)
    ]:
        if f == 0 or f >= t24:  # a run touching an end of the take has no outside sample
            continue
        span = np.flatnonzero((x > f - 1) & (x <= f))  # the input frames after sample f - 1, up to f
        if len(span) < 2:
            continue
        k = int(span[np.argmax(step[span])])
        near = np.flatnonzero((x > f - 2) & (x <= f + 1))
        others = step[near[near != k]]
        if step[k] < np.deg2rad(SNAP_MIN_DEG) or (len(others) and step[k] < SNAP_RATIO * others.max()):
            continue
        inside = span[span >= k] if into else span[span < k]
        outside = span[span < k] if into else span[span >= k]
        d[inside] = delta[f] if into else delta[f - 1]
        d[outside] = ident
        out[outside] = True
        out[inside] = False
    return out


def _texture_frame(motion: Motion) -> Motion:
    """``motion`` at its own rate in the texture's frame: facing-aligned as
    :func:`.motion_words.motion_texture` does when the skeleton maps both hips."""
    from mocapflow.framework.normalize import align_facing

    return align_facing(motion) if {"lhip", "rhip"} <= set(motion.skeleton.canonical) else motion


def edits_table(motion: Motion, cleaned: Motion, changed: np.ndarray, clip_id: int = 0) -> pa.Table:
    """One row per changed (frame, joint): clip_id, frame, joint, joint_name, old and new
    rotation (w, x, y, z)."""
    f, j = np.nonzero(changed)
    names = np.array(motion.skeleton.names, dtype=object)
    return pa.table(
        {
            "clip_id": pa.array(np.full(len(f), clip_id, np.int32)),
            "frame": pa.array(f.astype(np.int32)),
            "joint": pa.array(j.astype(np.int32)),
            "joint_name": pa.array(names[j].tolist() if len(j) else [], pa.string()),
            "old_rotation": fixed_list(motion.rotations[f, j].reshape(-1, 4)),
            "new_rotation": fixed_list(cleaned.rotations[f, j].reshape(-1, 4)),
        }
    )


def sparse_reconstruction(sparse: Motion, context: Sequence[Motion], known: Sequence[str], params: Any) -> Motion:
    """Full-body motion at the analysis rate from the rotations of ``known`` joints (§4, Fig. 8):
    source words compared on the known joints find KNN words in the full-body ``context``;
    the first word is the nearest neighbour, each later one the candidate closest to the
    previous word at their shared frame; the unknown joints are stitched and smoothed by the
    Savitzky-Golay filter, the known ones keep their input rotations."""
    joints = tuple(j for j in params.joints if all(j in c.skeleton.canonical for c in [sparse, *context]))
    missing = [j for j in known if j not in joints]
    if missing:
        raise DataError(f"sparse joints {missing} are not texture joints of every clip")
    tex = motion_texture(sparse, joints, params.fps)
    ctx = ContextTextures.from_arrays(
        [motion_texture(c, joints, params.fps).q for c in context], [c.name for c in context]
    )
    groups = resolve_groups(joints, [("known", tuple(known), 0)])
    n = params.source_length
    starts = source_word_starts(tex.n_frames, n, params.source_step)
    if len(starts) == 0:
        raise DataError(f"motion {sparse.name!r} is shorter than one word ({n} frames at {params.fps} fps)")
    neigh = knn_search(
        tex.q,
        ctx,
        groups,
        self_clip=-1,
        word_starts=starts,
        source_length=n,
        target_length=params.target_length,
        k=params.k,
        slope_run=params.slope_run,
    )
    out = tex.q.copy()
    prev = None
    for w, s in enumerate(starts):
        valid = np.flatnonzero(neigh.target[0, w] >= 0)
        if not len(valid):
            continue
        if prev is None:
            pick = valid[0]
        else:
            ref = out[s]  # the previous word already filled this frame
            d = [
                np.sum(np.arccos(np.clip(np.abs(np.sum(neigh.warped[0, w, kk, 0] * ref, -1)), 0, 1)) ** 2)
                for kk in valid
            ]
            pick = valid[int(np.argmin(d))]
        end = starts[w + 1] if w + 1 < len(starts) else len(out)
        word = neigh.warped[0, w, pick]
        seg = word[: end - s]
        seg = np.where(np.sum(seg * out[s:end], -1, keepdims=True) < 0, -seg, seg)
        out[s:end, ~groups.mask[0]] = seg[:, ~groups.mask[0]]
        prev = pick
    unknown = ~groups.mask[0]
    if len(out) >= params.savgol_window:
        from scipy.signal import savgol_filter  # lazy: scipy.signal costs seconds at import

        sm = savgol_filter(
            quat.make_continuous(out, axis=0), params.savgol_window, params.savgol_order, axis=0, mode="interp"
        )
        out[:, unknown] = quat.normalize(sm[:, unknown])
    rot = tex.motion.rotations.copy()
    rot[:, tex.joint_index] = out
    return tex.motion.with_arrays(rotations=rot)
