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


def frames_table(clip_id: int, motion: Motion) -> pa.Table:
    """Frame rows of one clip (:func:`.schema.motion_frames`; no forward kinematics)."""
    t, j = motion.n_frames, motion.n_joints
    rot = motion.rotations.astype(np.float32).reshape(t, j * 4)
    rot_arr = pa.ListArray.from_arrays(
        pa.array(np.arange(0, t * j * 4 + 1, j * 4, dtype=np.int32)), pa.array(rot.reshape(-1))
    )
    return pa.Table.from_arrays(
        [
            pa.array(np.full(t, clip_id, np.int32)),
            pa.array(np.arange(t, dtype=np.int32)),
            fixed_list(motion.root_translation.astype(np.float32)),
            rot_arr,
        ],
        schema=schema.motion_frames(),
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
    return {
        "data": data,
        "clips": clips_table([clip_row(i, m) for i, m in zip(ids, motions, strict=True)]),
        "skeletons": skeletons_table([m.skeleton for m in motions]),
    }


def database_from_tables(clips: pa.Table, skeletons: pa.Table, frames: pa.Table) -> MotionDatabase:
    """Rebuild a :class:`MotionDatabase` from the tables of a motions dataset."""
    skel = {row["skeleton"]: Skeleton.from_dict(json.loads(row["definition"])) for row in skeletons.to_pylist()}
    root = np.asarray(frames["root_translation"].combine_chunks().flatten().to_numpy(), np.float64).reshape(-1, 3)
    rot_flat = np.asarray(frames["rotations"].combine_chunks().flatten().to_numpy(), np.float64)
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
