"""Writing AMC motions (``:DEGREES``) for skeletons read from an ASF file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import Motion
from mocapflow.framework.quaternions import euler_extrinsic_inverse

from . import _euler_branch as euler_branch


class NotAnAsfSkeleton(DataError, NotImplementedError):
    """AMC can only be written for skeletons read from an ASF file."""


def write_amc(motion: Motion, path: str | Path, precision: int = 10) -> None:
    """Write a motion whose skeleton came from an ASF file as AMC (``:DEGREES``), with
    ``precision`` significant digits per value (10 keeps round trips within 1e-6). Angles
    are written in the source file's Euler branch and continuous (:mod:`._euler_branch`)."""
    sk = motion.skeleton
    if sk.meta.get("format") != "asf" or sk.axes is None or not sk.channels:
        raise NotAnAsfSkeleton(
            f"motion {motion.name!r}: its skeleton did not come from an ASF file (no ASF "
            "axes/dofs); writing AMC for other skeletons is not supported, write BVH instead"
        )
    scale = float(sk.meta["length_scale"])
    cols: list[np.ndarray] = []
    fmt: list[str] = []
    g = f"%.{precision}g"
    for j, name in enumerate(sk.names):
        ch = sk.channels[j]
        if not ch:
            continue
        c_ = sk.axes[j]
        m = quat.mul(quat.mul(quat.conjugate(c_), motion.rotations[:, j]), c_)
        if j == 0:
            rch = [c for c in ch if c[0] == "R"]
            ang = euler_extrinsic_inverse(m, "".join(c[1].lower() for c in rch), degrees=True)
            ang = euler_branch.apply(ang, name, [f"{name}.{c.lower()}" for c in rch], motion.metadata, motion.fps)
            by = {c: ang[:, k] for k, c in enumerate(rch)}
            for k, c in enumerate("XYZ"):
                by[f"T{c}"] = motion.root_translation[:, k] / scale
            cols += [by[c] for c in ch]
        else:
            ang = euler_extrinsic_inverse(m, "".join(c[1] for c in ch), degrees=True)
            ang = euler_branch.apply(ang, name, [f"{name}.{c.lower()}" for c in ch], motion.metadata, motion.fps)
            cols += list(ang.T)
        fmt.append(name + "".join(" " + g for _ in ch))
    table = np.column_stack([np.arange(1, motion.n_frames + 1)] + cols)
    frame_fmt = "%d\n" + "\n".join(fmt) + "\n"
    body = "".join(frame_fmt % tuple(row) for row in table.tolist())
    Path(path).write_text(":FULLY-SPECIFIED\n:DEGREES\n" + body, encoding="latin-1")
