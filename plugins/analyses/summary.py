"""``analyses.clip_summary``: a per-clip overview of a motions dataset.

Tables
------
data : one row per clip
    ``clip_id, name, n_frames, fps, duration_s, root_path_length_m`` (horizontal distance
    travelled by the root, metres), ``root_height_mean_m``, ``mean_speed_m_s``.
joint_rom : one row per (clip, canonical joint)
    ``rom_deg``: range of motion of the joint's local rotation, the largest geodesic angle
    (degrees) between two of its rotations in the clip, estimated in O(T) by a two-sweep
    search (the frame farthest from the chordal mean, then the frame farthest from that
    one). It is exact for rotations about a single axis (hinge joints) and a lower bound
    otherwise. ``mean_deg`` is the mean geodesic angle to the chordal mean rotation.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import pyarrow as pa

from mocapflow.framework import Analysis, Motion, StepContext, StepOutput
from mocapflow.framework import quaternions as quat
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.joints import CANONICAL_JOINTS


def joint_range_of_motion(motion: Motion) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Per canonical joint: (rom_deg, mean_deg, names); see the module docstring."""
    names, rom, mean = [], [], []
    for canon in CANONICAL_JOINTS:
        j = motion.skeleton.canonical.get(canon)
        if j is None:
            continue
        q = motion.rotations[:, j]
        centre = quat.chordal_mean(q)
        ang = np.rad2deg(quat.geodesic_angle(q, centre[None, :]))
        # farthest frame from the mean, then the farthest frame from it: a 2-sweep diameter estimate
        far = q[int(np.argmax(ang))]
        diam = np.rad2deg(quat.geodesic_angle(q, far[None, :])).max()
        names.append(canon)
        rom.append(float(diam))
        mean.append(float(ang.mean()))
    return np.array(rom), np.array(mean), names


class ClipSummary(Analysis):
    """Duration, frame count, root path length and per-joint range of motion of every clip."""

    name = "clip_summary"
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True}
    output_kind = "table"
    input_kinds = {"motions": ("motions",)}

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        db = inputs["motions"].motions()
        rows, rom_rows = [], []
        for cid, m in zip(db.clip_ids, ctx.progress(db.motions, total=db.n_clips, desc=ctx.step_id), strict=True):
            ground = m.root_translation[:, [0, 2]]
            path = float(np.linalg.norm(np.diff(ground, axis=0), axis=1).sum()) if m.n_frames > 1 else 0.0
            rows.append(
                {
                    "clip_id": int(cid),
                    "name": m.name,
                    "n_frames": m.n_frames,
                    "fps": m.fps,
                    "duration_s": m.duration,
                    "root_path_length_m": path,
                    "root_height_mean_m": float(m.root_translation[:, 1].mean()),
                    "mean_speed_m_s": path / m.duration if m.duration > 0 else 0.0,
                }
            )
            rom, mean, names = joint_range_of_motion(m)
            rom_rows += [
                {"clip_id": int(cid), "joint": n, "rom_deg": r, "mean_deg": a}
                for n, r, a in zip(names, rom, mean, strict=True)
            ]
        data = pa.Table.from_pylist(
            rows,
            schema=pa.schema(
                [
                    ("clip_id", pa.int32()),
                    ("name", pa.string()),
                    ("n_frames", pa.int32()),
                    ("fps", pa.float64()),
                    ("duration_s", pa.float64()),
                    ("root_path_length_m", pa.float64()),
                    ("root_height_mean_m", pa.float64()),
                    ("mean_speed_m_s", pa.float64()),
                ]
            ),
        )
        rom_t = pa.Table.from_pylist(
            rom_rows,
            schema=pa.schema(
                [("clip_id", pa.int32()), ("joint", pa.string()), ("rom_deg", pa.float64()), ("mean_deg", pa.float64())]
            ),
        )
        return StepOutput({"data": data, "joint_rom": rom_t}, {"clips": len(rows)})
