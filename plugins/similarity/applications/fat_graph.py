"""``analyses.fat_graph``: base poses of a fat graph in O(n log n) (Krüger et al. 2010, §5.3).

Shin & Oh (2006) cluster frames into base poses from a dense O(n^2) distance matrix;
Krüger et al. use kd-tree searches: the neighbours of every frame within radius ``r`` (at
most ``k``), then repeatedly the frame with the most *still uncovered* neighbours becomes a
base pose and its neighbourhood is covered, until all frames are covered or
``max_base_poses`` is reached. Counts are updated as frames are covered (O(n k) updates)
and a lazy heap yields the next base pose (O(n k log n)); ties go to the smaller frame id.

Tables: ``data`` (per frame: ``clip_id, frame, cluster`` (-1: uncovered), ``n_neighbours``),
``base_poses`` (``cluster, clip_id, frame, n_neighbours, n_members``), ``segments`` (runs of
one cluster tiling every clip: ``clip_id, start_frame, end_frame, cluster``), ``transitions``
(``clip_id, frame, from_cluster, to_cluster``), ``edges`` (``from_cluster, to_cluster,
n_transitions``). With a ``motions`` input also ``base_poses.png`` (stick figures).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import Analysis, DataError, Index, Params, StepContext, StepOutput
from mocapflow.framework.datasets import Dataset

#: Bones drawn in stick figures, as canonical joint pairs (missing joints are skipped).
STICK_BONES: tuple[tuple[str, str], ...] = (
    ("root", "lhip"),
    ("lhip", "lknee"),
    ("lknee", "lankle"),
    ("lankle", "ltoes"),
    ("root", "rhip"),
    ("rhip", "rknee"),
    ("rknee", "rankle"),
    ("rankle", "rtoes"),
    ("root", "lowerback"),
    ("lowerback", "upperback"),
    ("upperback", "chest"),
    ("chest", "neck"),
    ("neck", "head"),
    ("head", "headtop"),
    ("chest", "lclavicle"),
    ("lclavicle", "lshoulder"),
    ("lshoulder", "lelbow"),
    ("lelbow", "lwrist"),
    ("lwrist", "lfingers"),
    ("chest", "rclavicle"),
    ("rclavicle", "rshoulder"),
    ("rshoulder", "relbow"),
    ("relbow", "rwrist"),
    ("rwrist", "rfingers"),
)


@dataclass(frozen=True)
class BasePoses:
    """Result of :func:`select_base_poses`.

    Attributes
    ----------
    bases : ndarray of int64, shape (n_base,)
        Row (global frame) of each base pose, in selection order.
    cluster : ndarray of int64, shape (n,)
        Covering base pose of each row (position in ``bases``), -1 if uncovered.
    degree : ndarray of int64, shape (n,)
        Capped neighbourhood size of each row, itself included.
    """

    bases: np.ndarray
    cluster: np.ndarray
    degree: np.ndarray

    @property
    def n_members(self) -> np.ndarray:
        """Rows covered by each base pose, shape (n_base,)."""
        return np.bincount(self.cluster[self.cluster >= 0], minlength=len(self.bases))


def radius_neighbours(
    index: Index, x: np.ndarray, radius: float, k: int, chunk: int = 16384, progress: Callable[..., Any] | None = None
) -> np.ndarray:
    """Ids of up to ``k`` neighbours within ``radius`` of every row of ``x`` (built ``index``).

    Queried in chunks so that only the ids are kept (int32 when they fit), shape (n, k),
    padded with -1; ``progress`` (``ctx.progress``) shows the chunks.
    """
    n = len(x)
    dtype = np.int32 if n < 2**31 - 1 else np.int64
    ids = np.full((n, k), -1, dtype)
    starts = range(0, n, chunk)
    for s in progress(starts, total=len(starts), desc="fat graph: neighbours") if progress else starts:
        _, part = index.query(x[s : s + chunk], k, radius=radius)
        ids[s : s + chunk, : part.shape[1]] = part
    return ids


def select_base_poses(
    x: np.ndarray,
    radius: float,
    k: int,
    index: Index,
    max_base_poses: int = 0,
    ids: np.ndarray | None = None,
    progress: Callable[..., Any] | None = None,
) -> BasePoses:
    """Base poses of feature vectors ``x`` (Krüger 2010 §5.3, see the module docstring).

    Parameters
    ----------
    x : ndarray of shape (n, d)
        Feature vectors of every frame (float32).
    radius : float
        Search radius, in feature units (metres for the end-effector feature sets).
    k : int
        Neighbourhood cap.
    index : Index
        An unbuilt index component; it is built on ``x``.
    max_base_poses : int
        Stop after this many base poses; 0 covers every frame.
    ids : ndarray of shape (n, k), optional
        Precomputed neighbour rows (skips the search; the benchmark times both apart).
    progress : callable, optional
        ``ctx.progress``: a bar over the neighbour search.
    """
    x = np.ascontiguousarray(x, dtype=np.float32)
    if x.ndim != 2:
        raise DataError(f"fat graph: features must be (n_frames, dim), got {x.shape}")
    if not np.isfinite(x).all():
        raise DataError("fat graph: features contain NaN or inf")
    if len(x) == 0:
        z = np.zeros(0, np.int64)
        return BasePoses(z, z, z)
    if ids is None:
        index.build(x)
        ids = radius_neighbours(index, x, radius, k, progress=progress)
    from ._fat_graph_kernels import greedy_cover  # numba: imported when work starts

    bases, cluster, degree = greedy_cover(ids, max_base_poses)
    return BasePoses(bases, cluster, degree)


def cluster_runs(cluster: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Maximal runs of equal cluster within each clip: ``(start, end, cluster)`` global rows."""
    n = len(cluster)
    if n == 0:
        z = np.zeros(0, np.int64)
        return z, z, z
    brk = np.zeros(n, bool)
    brk[0] = True
    brk[1:] = cluster[1:] != cluster[:-1]
    brk[offsets[(offsets > 0) & (offsets < n)]] = True
    start = np.flatnonzero(brk)
    end = np.append(start[1:], n)
    return start, end, cluster[start]


def clip_transitions(cluster: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cluster changes along each clip, uncovered rows skipped: ``(row, from, to)``."""
    rows = np.flatnonzero(cluster >= 0)
    clip = np.searchsorted(offsets, rows, side="right") - 1
    cl = cluster[rows]
    change = (clip[1:] == clip[:-1]) & (cl[1:] != cl[:-1])
    return rows[1:][change], cl[:-1][change], cl[1:][change]


def plot_base_poses(
    positions: np.ndarray, joints: tuple[str, ...], path: Path, title: str = "", labels: list[str] | None = None
) -> None:
    """Stick figures of poses ``(n, J, 3)`` (root frame, metres), side by side, saved as PNG.

    Panels share one scale: x is the lateral offset from the root and y the height relative
    to the root, both in metres (the figure faces the viewer). ``labels`` (one per pose, e.g. source clip, frame
    and member count) title the panels; by default they are numbered.
    """
    from mocapflow.framework.plotting import pyplot

    plt = pyplot("base-pose plots")

    n = len(positions)
    cols = min(n, 8) or 1
    rows = max(1, -(-n // cols))
    fig, axes = plt.subplots(
        rows, cols, figsize=(1.7 * cols + 0.6, 2.6 * rows + 0.7), squeeze=False, sharex=True, sharey=True
    )
    j = {name: i for i, name in enumerate(joints)}
    bones = [(j[a], j[b]) for a, b in STICK_BONES if a in j and b in j]
    for i, ax in enumerate(axes.ravel()):
        if i >= n:
            ax.set_axis_off()
            continue
        p = positions[i]
        for a, b in bones:
            if np.isfinite(p[[a, b]]).all():
                # view from the side the character faces (+z towards the viewer): x right, y up
                ax.plot(p[[a, b], 0], p[[a, b], 1], "-", color="k", lw=1.2)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
        ax.set_title(labels[i] if labels is not None else str(i), fontsize=6.5)
    for ax in axes.ravel():
        ax.label_outer()
    fig.supxlabel("lateral offset from the root (m); each figure faces the viewer", fontsize=8)
    fig.supylabel("height relative to the root (m)", fontsize=8)
    fig.suptitle(title or f"{n} base poses", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


class FatGraphParams(Params):
    radius: float = Field(
        0.3,
        gt=0,
        description="neighbourhood radius in feature units (metres for "
        "features.end_effectors); the paper gives no value",
    )
    k: int = Field(64, ge=1, description="neighbourhood cap k of the radius search (k << n)")


#: base poses drawn in base_poses.png (when the step has a motions input)
PLOT_MAX = 48


class FatGraph(Analysis):
    """Base poses, per-frame clusters and cluster transitions of a fat graph (Krüger 2010 §5.3)."""

    name = "fat_graph"
    inputs: ClassVar[Mapping[str, bool]] = {"features": True, "motions": False}
    Params = FatGraphParams
    params: FatGraphParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        p = self.params
        feats = inputs["features"].features()
        from ..knn.kdtree import KDTreeIndex

        res = select_base_poses(feats.x, p.radius, p.k, KDTreeIndex(), progress=ctx.progress)
        clip_id, frame = feats.clip_id, feats.frame
        # clip boundaries of the feature rows (rows are clip-contiguous, in clip order)
        new_clip = np.ones(len(clip_id), bool)
        new_clip[1:] = (clip_id[1:] != clip_id[:-1]) | (frame[1:] != frame[:-1] + 1)
        offsets = np.append(np.flatnonzero(new_clip), len(clip_id))
        tables = self.tables(res, clip_id, frame, offsets)
        if "motions" in inputs and len(res.bases):
            self._plot(
                inputs["motions"],
                clip_id,
                frame,
                res.bases[:PLOT_MAX],
                ctx.out_dir / "base_poses.png",
                res.n_members[:PLOT_MAX],
            )
        summary = {
            "n_frames": int(len(clip_id)),
            "n_base_poses": int(len(res.bases)),
            "n_uncovered": int((res.cluster < 0).sum()),
            "n_edges": int(tables["edges"].num_rows),
            "backend": "indexes.kdtree + numba greedy",
        }
        return StepOutput(tables, summary)

    @staticmethod
    def tables(res: BasePoses, clip_id: np.ndarray, frame: np.ndarray, offsets: np.ndarray) -> dict[str, pa.Table]:
        """The step's tables (see the module docstring) from global-row results."""

        def i32(a: Any) -> pa.Array:
            return pa.array(np.asarray(a, np.int32))

        cl = res.cluster
        data = pa.table(
            {"clip_id": i32(clip_id), "frame": i32(frame), "cluster": i32(cl), "n_neighbours": i32(res.degree)}
        )
        bases = pa.table(
            {
                "cluster": i32(np.arange(len(res.bases))),
                "clip_id": i32(clip_id[res.bases]),
                "frame": i32(frame[res.bases]),
                "n_neighbours": i32(res.degree[res.bases]),
                "n_members": i32(res.n_members),
            }
        )
        s, e, c = cluster_runs(cl, offsets)
        segments = pa.table(
            {
                "clip_id": i32(clip_id[s]),
                "start_frame": i32(frame[s]),
                "end_frame": i32(frame[e - 1] + 1),
                "cluster": i32(c),
            }
        )
        rows, a, b = clip_transitions(cl, offsets)
        transitions = pa.table(
            {"clip_id": i32(clip_id[rows]), "frame": i32(frame[rows]), "from_cluster": i32(a), "to_cluster": i32(b)}
        )
        if len(a):
            pairs, counts = np.unique(np.stack([a, b], 1), axis=0, return_counts=True)
        else:
            pairs, counts = np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
        edges = pa.table(
            {"from_cluster": i32(pairs[:, 0]), "to_cluster": i32(pairs[:, 1]), "n_transitions": i32(counts)}
        )
        return {"data": data, "base_poses": bases, "segments": segments, "transitions": transitions, "edges": edges}

    @staticmethod
    def _plot(
        motions: Dataset, clip_id: np.ndarray, frame: np.ndarray, bases: np.ndarray, path: Path, n_members: np.ndarray
    ) -> None:
        from mocapflow.framework.joints import CANONICAL_JOINTS
        from mocapflow.framework.normalize import to_root_frame

        db = motions.motions()
        where = {int(c): i for i, c in enumerate(db.clip_ids)}
        poses, labels = [], []
        for i, b in enumerate(bases):
            m = db.motions[where[int(clip_id[b])]]
            f = int(frame[b])
            poses.append(m.canonical_positions()[f : f + 1])
            labels.append(f"#{i} {m.name} frame {f}\n{int(n_members[i])} member{'s' if n_members[i] != 1 else ''}")
        pos = to_root_frame(np.concatenate(poses, 0), CANONICAL_JOINTS)
        plot_base_poses(
            pos,
            CANONICAL_JOINTS,
            path,
            labels=labels,
            title=f"{len(bases)} base poses (of {len(clip_id)} frames): source clip, frame, frames covered",
        )
