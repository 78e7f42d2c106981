"""Components of the template plugin.

* ``features.joint_speed``: speed (m/s) of the hands, feet and head per frame;
* ``matchers.sliding_window``: brute-force matching of a query clip against every window
  of the same length in the database, by mean Euclidean feature distance.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import FeatureSet, Matcher, Motion, StepContext, StepOutput, hookimpl
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.datasets import Dataset
from mocapflow.framework.errors import ConfigError
from mocapflow.framework.schema import MATCHES

END_EFFECTORS = ("lwrist", "rwrist", "lankle", "rankle", "head")


class JointSpeed(FeatureSet):
    """Speeds of hands, feet and head (m/s), one column per joint."""

    name = "joint_speed"

    class Params(BaseParams):
        joints: tuple[str, ...] = Field(END_EFFECTORS, min_length=1, description="canonical joints")

    params: Params  # for type checkers: this component's own fields

    @property
    def dim(self) -> int:
        return len(self.params.joints)

    def transform_motion(self, motion: Motion) -> np.ndarray:
        pos = motion.canonical_positions(self.params.joints)
        if motion.n_frames < 2:
            return np.zeros((motion.n_frames, self.dim), np.float32)
        # central differences inside the clip, one-sided at its ends
        vel = np.gradient(pos, 1.0 / motion.fps, axis=0)
        return np.linalg.norm(vel, axis=-1).astype(np.float32)


class SlidingWindow(Matcher):
    """Best windows of the database for one query clip (brute force, mean feature distance)."""

    name = "sliding_window"
    inputs: ClassVar[Mapping[str, bool]] = {"database": True, "query": True}

    class Params(BaseParams):
        query_clip: int = Field(
            0,
            ge=0,
            description="position of the query clip in the query dataset "
            "(0: its first clip; clip ids are stable hashes of the file paths)",
        )
        top: int = Field(5, ge=1, description="number of matches")

    params: Params

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        db = inputs["database"].features()
        q = inputs["query"].features()
        order = q.clip_id[np.sort(np.unique(q.clip_id, return_index=True)[1])]  # clips in dataset order
        if self.params.query_clip >= len(order):
            raise ConfigError(f"query_clip {self.params.query_clip}: the query dataset has {len(order)} clips")
        query = q.x[q.clip_id == order[self.params.query_clip]]
        n = len(query)
        rows = []
        for cid in np.unique(db.clip_id):
            x = db.x[db.clip_id == cid]
            if len(x) < n or n == 0:
                continue
            windows = np.lib.stride_tricks.sliding_window_view(x, n, axis=0).transpose(0, 2, 1)
            cost = np.linalg.norm(windows - query[None], axis=-1).mean(axis=1)
            best = int(np.argmin(cost))
            rows.append((int(cid), best, best + n, float(cost[best])))
        rows.sort(key=lambda r: r[3])
        table = pa.Table.from_pylist(
            [
                {"query_id": 0, "rank": r, "clip_id": c, "start_frame": s, "end_frame": e, "cost": k}
                for r, (c, s, e, k) in enumerate(rows[: self.params.top], start=1)
            ],
            schema=MATCHES,
        )
        return StepOutput({"data": table}, {"matches": table.num_rows})


@hookimpl
def register_features() -> list[type]:
    return [JointSpeed]


@hookimpl
def register_matchers() -> list[type]:
    return [SlidingWindow]
