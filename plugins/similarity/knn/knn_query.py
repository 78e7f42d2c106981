"""``analyses.nearest_poses``: the k nearest poses of a few frames, from a persisted kNN index.

The query frames are rows of the index itself (Krüger et al. 2010 Fig. 1: "the 256 nearest
neighbours for 9 exemplary poses"). Each query is ``"<clip>:<frame>"`` where ``<clip>`` is a
clip name (needs the ``motions`` input) or a clip id, and ``<frame>`` a frame of that clip at
the dataset's rate. Output ``data``: query_id, query_clip_id, query_frame, rank (0 = nearest),
clip_id, frame, distance (feature units).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import Analysis
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from mocapflow.framework import Dataset, StepContext, StepOutput


class NearestPoses(Analysis):
    """The k nearest indexed frames of each query frame (exact kNN from an ``indexes.*`` step)."""

    name: ClassVar[str] = "nearest_poses"
    inputs: ClassVar[Mapping[str, bool]] = {"index": True, "motions": False}

    class Params(BaseParams):
        queries: list[str] = Field(min_length=1, description='query frames "<clip name or id>:<frame>"')
        k: int = Field(16, ge=1, description="neighbours per query")
        exclude_frames: int | None = Field(
            None, ge=0, description="skip neighbours of the query's own clip within this many frames (0 = itself)"
        )

    params: Params

    def _rows(self, clip_id: np.ndarray, frame: np.ndarray, names: dict[str, int]) -> np.ndarray:
        rows = []
        for q in self.params.queries:
            clip, sep, f = q.rpartition(":")
            if not sep or not f.strip().lstrip("-").isdigit():
                raise ConfigError(f"{self.key()}: query {q!r} is not '<clip>:<frame>'")
            if clip in names:
                cid = names[clip]
            elif clip.isdigit():
                cid = int(clip)
            else:
                raise ConfigError(
                    f"{self.key()}: unknown clip {clip!r} in query {q!r} (give a motions input for names)"
                )
            hit = np.flatnonzero((clip_id == cid) & (frame == int(f)))
            if not hit.size:
                raise ConfigError(f"{self.key()}: frame {f} of clip {clip!r} is not in the index")
            rows.append(int(hit[0]))
        return np.array(rows, np.int64)

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        index = inputs["index"].index(ctx.registries)
        clip_id, frame = inputs["index"].frame_ids()
        names: dict[str, int] = {}
        if "motions" in inputs:
            clips = inputs["motions"].table("clips", columns=["clip_id", "name"])
            names = {n: int(c) for c, n in zip(clips["clip_id"].to_pylist(), clips["name"].to_pylist(), strict=True)}
            names.update({n.rsplit(".", 1)[0]: c for n, c in list(names.items())})
        rows = self._rows(clip_id, frame, names)
        if not hasattr(index, "query_rows"):
            raise ConfigError(f"{self.key()}: index {inputs['index'].producer} cannot query its own rows")
        dist, ids = index.query_rows(rows, self.params.k, exclude=self.params.exclude_frames)
        qid, rank = np.meshgrid(np.arange(len(rows)), np.arange(self.params.k), indexing="ij")
        ok = ids.ravel() >= 0
        nb = ids.ravel()[ok]
        table = pa.table(
            {
                "query_id": pa.array(qid.ravel()[ok].astype(np.int32)),
                "query_clip_id": pa.array(clip_id[rows][qid.ravel()[ok]].astype(np.int32)),
                "query_frame": pa.array(frame[rows][qid.ravel()[ok]].astype(np.int32)),
                "rank": pa.array(rank.ravel()[ok].astype(np.int32)),
                "clip_id": pa.array(clip_id[nb].astype(np.int32)),
                "frame": pa.array(frame[nb].astype(np.int32)),
                "distance": pa.array(dist.ravel()[ok].astype(np.float64)),
            }
        )
        return StepOutput(
            {"data": table},
            summary={"queries": len(rows), "k": self.params.k, "method": getattr(index, "method_", None)},
        )
