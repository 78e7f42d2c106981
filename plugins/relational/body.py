"""Body-size measures of Müller et al. 2005: the relational features' thresholds are
multiples of the actor's humerus length, shoulder and hip widths and height, measured on
the rest pose."""

from __future__ import annotations

from typing import cast

import numpy as np

from mocapflow.framework import quaternions as quat
from mocapflow.framework.errors import DataError
from mocapflow.framework.motion import forward_kinematics
from mocapflow.framework.skeleton import Skeleton


def rest_positions(skeleton: Skeleton) -> np.ndarray:
    """Joint positions of the rest pose (all identity rotations), shape (J, 3), metres."""
    pos, _ = forward_kinematics(skeleton, np.zeros((1, 3)), quat.identity((1, skeleton.n_joints)))
    return cast("np.ndarray", pos[0])


def body_measures(skeleton: Skeleton) -> dict[str, float]:
    """Body-size measures from the rest pose, metres.

    Returns ``humerus_length`` (mean of left/right shoulder-elbow), ``shoulder_width``
    (lshoulder-rshoulder), ``hip_width`` (lhip-rhip), ``height`` (headtop or head above
    the lower ankle), used to make feature thresholds relative to body size.
    """
    rest = rest_positions(skeleton)
    c = skeleton.canonical

    def dist(a: str, b: str) -> float:
        if a not in c or b not in c:
            raise DataError(f"skeleton {skeleton.name!r} lacks {a!r} or {b!r} needed for body measures")
        return float(np.linalg.norm(rest[c[a]] - rest[c[b]]))

    top = c.get("headtop", c.get("head"))
    feet = min(rest[c["lankle"], 1], rest[c["rankle"], 1]) if "lankle" in c and "rankle" in c else rest[:, 1].min()
    return {
        "humerus_length": 0.5 * (dist("lshoulder", "lelbow") + dist("rshoulder", "relbow")),
        "shoulder_width": dist("lshoulder", "rshoulder"),
        "hip_width": dist("lhip", "rhip"),
        "height": float(rest[top, 1] - feet) if top is not None else float("nan"),
    }
