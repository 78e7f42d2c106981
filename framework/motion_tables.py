"""Motions <-> Arrow tables (the on-disk form of a motions dataset)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from . import schema
from .database import MotionDatabase
from .errors import DataError
from .motion import Motion
from .schema import fixed_list
from .skeleton import Skeleton


def clip_row(clip_id: int, motion: Motion) -> dict[str, Any]:
    """One row of the ``clips`` table from a motion's metadata."""
    meta = motion.metadata
    return {
        "clip_id": int(clip_id),
        "name": motion.name,
        "path": str(meta.get("path", "")),
        "format": str(meta.get("format", "")),
        "subject": str(meta.get("subject", "")),
        "fps": float(motion.fps),
        "n_frames": int(motion.n_frames),
        "skeleton": motion.skeleton.fingerprint(),
        "checksum": str(meta.get("checksum", "")),
        "source_fps": float(meta.get("source_fps", motion.fps)),
        "source_frames": int(meta.get("source_frames", motion.n_frames)),
    }


def clips_table(rows: Sequence[dict[str, Any]]) -> pa.Table:
    return pa.Table.from_pylist(list(rows), schema=schema.CLIPS)


def skeletons_table(skeletons: Sequence[Skeleton]) -> pa.Table:
    seen: dict[str, Skeleton] = {}
    for s in skeletons:
        seen.setdefault(s.fingerprint(), s)
    return pa.Table.from_pylist(
        [
            {"skeleton": k, "name": s.name, "n_joints": s.n_joints, "definition": json.dumps(s.to_dict())}
            for k, s in seen.items()
        ],
        schema=schema.SKELETONS,
    )


#: The three kept components for each dropped one (smallest-three quaternions).
_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], np.intp)


def pack_rotations(rotations: np.ndarray) -> tuple[bytes, bytes]:
    """Unit quaternions ``(T, J, 4)`` -> ``(largest, quats)`` of :func:`.schema.motion_rotations`:
    the index of each largest-magnitude component (``J*T`` bytes, joint-major) and the other
    three, sign-flipped so that the dropped one is positive, as float32 ``(J, 3, T)``, its
    bytes split by position (:func:`split_bytes`)."""
    q = np.asarray(rotations, np.float64)
    t, j = q.shape[:2]
    big = np.abs(q).argmax(axis=-1)  # (T, J)
    sign = np.where(np.take_along_axis(q, big[..., None], -1)[..., 0] < 0, -1.0, 1.0)
    kept = np.take_along_axis(q, _OTHERS[big], -1) * sign[..., None]  # (T, J, 3)
    quats = np.ascontiguousarray(kept.transpose(1, 2, 0), dtype=np.float32).reshape(-1)
    return np.ascontiguousarray(big.T, np.uint8).tobytes(), split_bytes(quats)


def split_bytes(x: np.ndarray) -> bytes:
    """float32 values -> their bytes by position: byte 0 of every value, then byte 1, ...
    (Parquet's byte-stream-split, which pyarrow applies to flat columns only): the high
    bytes of a smooth series repeat, so zstd packs them (15 % smaller rotations)."""
    return np.ascontiguousarray(np.asarray(x, "<f4").view(np.uint8).reshape(-1, 4).T).tobytes()


def join_bytes(raw: Any) -> np.ndarray:
    """Inverse of :func:`split_bytes`: the float32 values."""
    b = np.frombuffer(raw, np.uint8)
    if len(b) % 4:
        raise DataError(f"rotations: {len(b)} bytes is not a whole number of float32 values")
    return np.ascontiguousarray(b.reshape(4, -1).T).view("<f4").reshape(-1)


def unpack_rotations(largest: Any, quats: Any, n_frames: int, n_joints: int) -> np.ndarray:
    """Inverse of :func:`pack_rotations`: unit quaternions ``(T, J, 4)`` float64."""
    t, j = int(n_frames), int(n_joints)
    big = np.frombuffer(largest, np.uint8).reshape(j, t).T.astype(np.intp)  # (T, J)
    values = join_bytes(quats)
    if big.size * 3 != values.size:
        raise DataError(f"rotations: {values.size} values for {t} frames of {j} joints (want {3 * big.size})")
    kept = values.astype(np.float64).reshape(j, 3, t).transpose(2, 0, 1)  # (T, J, 3)
    w = np.sqrt(np.maximum(0.0, 1.0 - np.einsum("tjk,tjk->tj", kept, kept)))
    q = np.empty((t, j, 4))
    np.put_along_axis(q, big[..., None], w[..., None], -1)
    np.put_along_axis(q, _OTHERS[big], kept, -1)
    norm: np.ndarray = q / np.linalg.norm(q, axis=-1, keepdims=True)  # undo float32 rounding of the norm
    return norm


def frames_table(clip_id: int, motion: Motion) -> pa.Table:
    """Frame rows of one clip (:func:`.schema.motion_frames`; no forward kinematics)."""
    t = motion.n_frames
    return pa.Table.from_arrays(
        [
            pa.array(np.full(t, clip_id, np.int32)),
            pa.array(np.arange(t, dtype=np.int32)),
            fixed_list(motion.root_translation.astype(np.float32)),
        ],
        schema=schema.motion_frames(),
    )


def rotations_table(clip_id: int, motion: Motion) -> pa.Table:
    """The clip's row of the ``rotations`` table (:func:`.schema.motion_rotations`)."""
    largest, quats = pack_rotations(motion.rotations)
    return pa.Table.from_arrays(
        [
            pa.array([int(clip_id)], pa.int32()),
            pa.array([motion.n_frames], pa.int32()),
            pa.array([motion.n_joints], pa.int32()),
            pa.array([largest], pa.binary()),
            pa.array([quats], pa.binary()),
        ],
        schema=schema.motion_rotations(),
    )


def motions_to_tables(motions: Sequence[Motion], clip_ids: Sequence[int] | None = None) -> dict[str, pa.Table]:
    """``{"data": frames, "clips": ..., "skeletons": ...}`` for a list of motions.

    ``clip_ids`` (distinct; any order) default to ``0..n-1`` like :class:`MotionDatabase`'s;
    ingest passes the stable ids of the files (:func:`.schema.clip_ids_of`).
    """
    ids = list(range(len(motions))) if clip_ids is None else [int(c) for c in clip_ids]
    if len(ids) != len(motions) or len(set(ids)) != len(ids):
        raise DataError(f"need {len(motions)} distinct clip ids, got {len(set(ids))} distinct of {len(ids)}")
    frames = [frames_table(i, m) for i, m in zip(ids, motions, strict=True)]
    data = pa.concat_tables(frames) if frames else schema.motion_frames().empty_table()
    rots = [rotations_table(i, m) for i, m in zip(ids, motions, strict=True)]
    return {
        "data": data,
        "rotations": pa.concat_tables(rots) if rots else schema.motion_rotations().empty_table(),
        "clips": clips_table([clip_row(i, m) for i, m in zip(ids, motions, strict=True)]),
        "skeletons": skeletons_table([m.skeleton for m in motions]),
    }


def database_from_tables(
    clips: pa.Table, skeletons: pa.Table, frames: pa.Table, rotations: pa.Table | None = None
) -> MotionDatabase:
    """Rebuild a :class:`MotionDatabase` from the tables of a motions dataset: ``rotations``
    (one row per clip, in ``clips`` order), or, in the first layout, a ``rotations`` column
    of ``frames``."""
    skel = {row["skeleton"]: Skeleton.from_dict(json.loads(row["definition"])) for row in skeletons.to_pylist()}
    root = np.asarray(frames["root_translation"].combine_chunks().flatten().to_numpy(), np.float64).reshape(-1, 3)
    if "rotations" in frames.column_names:
        rot_flat = np.asarray(frames["rotations"].combine_chunks().flatten().to_numpy(), np.float64)
    elif rotations is None:
        raise DataError("a motions dataset's rotations: no `rotations` table and no rotations column in `data`")
    elif rotations.num_rows != clips.num_rows:
        raise DataError(f"clips table has {clips.num_rows} clips, rotations table {rotations.num_rows}")
    else:
        return _database_v2(clips, skel, root, rotations)
    motions, ids = [], []
    # frames are stored clip by clip, in clips-table order (clip ids are hashes, not sorted)
    n_frames = clips["n_frames"].to_numpy().astype(np.int64)
    starts = np.concatenate([[0], np.cumsum(n_frames)[:-1]]).astype(np.int64)
    if int(n_frames.sum()) != frames.num_rows:
        raise DataError(f"clips table counts {int(n_frames.sum())} frames, data table has {frames.num_rows}")
    rot_offset = 0
    for row, start in zip(clips.to_pylist(), starts, strict=False):  # no clip: starts is [0]
        s = skel[row["skeleton"]]
        n = row["n_frames"]
        size = n * s.n_joints * 4
        rot = rot_flat[rot_offset : rot_offset + size].reshape(n, s.n_joints, 4)
        rot_offset += size
        rot = rot / np.linalg.norm(rot, axis=-1, keepdims=True)  # undo float32 rounding of the norm
        meta = {k: row[k] for k in ("path", "format", "subject", "checksum", "source_fps", "source_frames")}
        motions.append(Motion(s, root[start : start + n], rot, row["fps"], name=row["name"], metadata=meta))
        ids.append(row["clip_id"])
    return MotionDatabase(motions, ids)


def _database_v2(clips: pa.Table, skel: dict[str, Skeleton], root: np.ndarray, rotations: pa.Table) -> MotionDatabase:
    n_frames = clips["n_frames"].to_numpy().astype(np.int64)
    if int(n_frames.sum()) != root.shape[0]:
        raise DataError(f"clips table counts {int(n_frames.sum())} frames, data table has {root.shape[0]}")
    starts = np.concatenate([[0], np.cumsum(n_frames)]).astype(np.int64)
    # the clips' buffers as they lie in the Arrow arrays (no Python bytes copies)
    quats, largest = rotations["quats"].combine_chunks(), rotations["largest"].combine_chunks()
    frames_of, joints_of = rotations["n_frames"].to_numpy(), rotations["n_joints"].to_numpy()
    motions, ids = [], []
    for i, row in enumerate(clips.to_pylist()):
        s, n = skel[row["skeleton"]], int(row["n_frames"])
        if (int(frames_of[i]), int(joints_of[i])) != (n, s.n_joints):
            raise DataError(f"rotations of clip {row['clip_id']} do not match its clips row and skeleton")
        rot = unpack_rotations(largest[i].as_buffer(), quats[i].as_buffer(), n, s.n_joints)
        meta = {k: row[k] for k in ("path", "format", "subject", "checksum", "source_fps", "source_frames")}
        motions.append(Motion(s, root[starts[i] : starts[i + 1]], rot, row["fps"], name=row["name"], metadata=meta))
        ids.append(row["clip_id"])
    return MotionDatabase(motions, ids)
