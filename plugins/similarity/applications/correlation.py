"""``analyses.distance_correlation``: the rank-correlation study of Krüger et al. 2010, Fig. 2.

For ``samples`` random frames of the motions dataset and each *row* measure, the ``k``
nearest frames by that measure are found (feature sets: the exact kd-tree; distance
measures: a full scan); then, for each *column* measure, Spearman's rank correlation
between the row measure's distances and the column measure's distances to those ``k``
frames is computed, and averaged over the samples. The matrix is not symmetric: the
neighbours always come from the row measure. The query frame itself is excluded from its
neighbours.

Measures: ``D_quat, D_euler, D_pc1, D_pc11, D_wb`` (:mod:`.distances`) and the feature sets
``F_pca<n>`` (fitted on the ``reference`` motions, else on the motions themselves),
``F_E15/30/39`` and windowed ``F_E<n>x<l>`` (:mod:`mocapflow.plugins.similarity.knn.end_effectors`).

Outputs: ``data`` (row_measure, col_measure, rho, rho_std, n_samples), a ``matrix`` table
(one row per row measure, a column per column measure) and ``correlation.png``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, ClassVar, cast

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import Analysis, MotionDatabase
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.errors import ConfigError

from ..knn.distances import DISTANCE_MEASURES, PoseMeasures

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    from mocapflow.framework import Dataset, StepContext, StepOutput

FIG2_MEASURES = (
    "D_quat",
    "D_euler",
    "D_pc1",
    "D_pc11",
    "D_wb",
    "F_pca8",
    "F_pca16",
    "F_pca25",
    "F_E15",
    "F_E30",
    "F_E39",
    "F_E15x3",
    "F_E15x5",
    "F_E30x3",
)
#: window of the F_E<n>x<l> feature sets, seconds (the paper's 0.3)
WINDOW = 0.3
#: weight of D_wb's joint-velocity term, s^2
VELOCITY_WEIGHT = 0.01
_FEATURE = re.compile(r"F_(?:pca(\d+)|E(15|30|39)(?:x(\d+))?)")


def _check_measure(name: str) -> None:
    if name in DISTANCE_MEASURES or re.fullmatch(r"D_pc\d+", name) or _FEATURE.fullmatch(name):
        return
    raise ConfigError(f"unknown measure {name!r}; use D_quat, D_euler, D_pc<n>, D_wb, F_pca<n>, F_E15/30/39[x<l>]")


def feature_matrix(name: str, db: MotionDatabase, reference: MotionDatabase | None, window: float = 0.3) -> np.ndarray:
    """Features of every frame of ``db`` for a measure name ``F_...``, float32 (n_frames, dim)."""
    from ..knn.end_effectors import EndEffectorFeatures
    from ..knn.pca import PosePCA

    m = _FEATURE.fullmatch(name)
    if m is None:
        raise ConfigError(f"{name!r} is not a feature-set measure")
    if m.group(1):
        return PosePCA(n_components=int(m.group(1))).fit(reference if reference is not None else db).transform(db)
    return EndEffectorFeatures(joints=int(m.group(2)) // 3, samples=int(m.group(3) or 1), window=window).transform(db)


def spearman_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Spearman's rho between rows of ``a`` and ``b`` (m, k), average ranks for ties; NaN if constant."""
    from scipy.stats import rankdata

    ra = rankdata(a, axis=1)
    rb = rankdata(b, axis=1)
    ra -= ra.mean(1, keepdims=True)
    rb -= rb.mean(1, keepdims=True)
    den = np.sqrt((ra**2).sum(1) * (rb**2).sum(1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, (ra * rb).sum(1) / np.where(den > 0, den, 1.0), np.nan)


class DistanceCorrelationStudy(Analysis):
    """Spearman rank correlations between pose distance measures and feature sets (Krüger 2010, Fig. 2)."""

    name: ClassVar[str] = "distance_correlation"
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True, "reference": False}

    class Params(BaseParams):
        samples: int = Field(1024, ge=1, description="random query frames (paper: 1024)")
        k: int = Field(256, ge=2, description="nearest neighbours per query and row measure (paper: 256)")
        measures: tuple[str, ...] = Field(FIG2_MEASURES, min_length=1, description="the measures, in order")

    params: Params

    def study(
        self,
        db: MotionDatabase,
        reference: MotionDatabase | None = None,
        progress: Callable[..., Any] | None = None,
        rows: tuple[str, ...] | None = None,
    ) -> tuple[tuple[str, ...], tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
        """Run the study; returns ``(rows, cols, rho (R, C), rho_std (R, C), n (R, C))`` (``rows``:
        the neighbour sources, default every measure)."""
        from ..knn.kdtree import KDTreeIndex

        p = self.params
        cols = tuple(p.measures)
        rows = tuple(rows) if rows is not None else cols
        for name in set(cols) | set(rows):
            _check_measure(name)
        n = db.n_frames
        if n <= p.k:
            raise ConfigError(f"{self.key()}: the database has {n} frames, need more than k={p.k}")
        pm = PoseMeasures(db, VELOCITY_WEIGHT) if any(c.startswith("D_") for c in cols + rows) else None
        feats = {c: feature_matrix(c, db, reference, WINDOW) for c in dict.fromkeys(cols + rows) if c.startswith("F_")}
        clip_id, frame = db.frame_ids
        rng = np.random.default_rng(0)
        queries = np.sort(rng.choice(n, size=min(p.samples, n), replace=False))

        def dist(measure: str, i: int, js: np.ndarray) -> np.ndarray:
            if measure in feats:
                diff = feats[measure][js].astype(np.float64) - feats[measure][i]
                return cast("np.ndarray", np.sqrt((diff * diff).sum(1)))
            assert pm is not None  # D_ measures exist when one is asked for
            return pm.distance(measure, i, js)

        rho = np.full((len(rows), len(cols)), np.nan)
        std = np.full_like(rho, np.nan)
        count = np.zeros(rho.shape, np.int64)
        # units of progress weighted by distance evaluations, so the bar and its ETA move
        # evenly: a measure row's neighbours scan every frame per sample (one unit per 32
        # samples), a feature row's come from a kd-tree, a column is k distances per sample
        nq, chunk = len(queries), 32
        units, weights = [], []
        for r, row in enumerate(rows):
            parts = [(a, min(a + chunk, nq)) for a in range(0, nq, chunk)] if row not in feats else [(0, nq)]
            units += [(r, -1, a, b) for a, b in parts]
            weights += [(b - a) * n if row not in feats else 20.0 * n for a, b in parts]
            units += [(r, c, 0, 0) for c in range(len(cols))]
            weights += [float(nq * p.k)] * len(cols)
        desc = f"correlation: {len(rows)} rows x ({len(cols)} columns + neighbours)"
        for r, c, a, b in progress(units, desc=desc, weights=weights) if progress else units:
            row = rows[r]
            if c < 0:  # the row's neighbours (a measure row: samples a..b of them)
                if row in feats:
                    ix = KDTreeIndex(method="kdtree").build(feats[row], groups=clip_id, frames=frame)
                    nd, nb = ix.query_rows(queries, p.k, exclude=0)
                else:
                    if a == 0:
                        nd, nb = np.full((nq, p.k), np.inf), np.full((nq, p.k), -1, np.int64)
                    assert pm is not None  # a row that is no feature is a D_ measure
                    nd[a:b], nb[a:b] = self._scan(pm, row, queries[a:b], clip_id, frame)
                per = np.full((nq, len(cols)), np.nan)
                ok = np.asarray((nb >= 0).all(1))
                continue
            col = cols[c]
            if col == row:
                per[:, c] = 1.0
            else:
                other = np.stack([dist(col, int(q), nb[s]) if ok[s] else np.zeros(p.k) for s, q in enumerate(queries)])
                per[:, c] = spearman_rows(nd.astype(np.float64), other)
            if c == len(cols) - 1:  # the row is complete
                per[~ok] = np.nan
                rho[r] = np.nanmean(per, 0)
                std[r] = np.nanstd(per, 0)
                count[r] = np.isfinite(per).sum(0)
        return rows, cols, rho, std, count

    def _scan(
        self,
        pm: PoseMeasures,
        row: str,
        queries: np.ndarray,
        clip_id: np.ndarray,
        frame: np.ndarray,
        chunk: int = 65536,
    ) -> tuple[np.ndarray, np.ndarray]:
        k, n = self.params.k, len(clip_id)
        nd = np.full((len(queries), k), np.inf)
        nb = np.full((len(queries), k), -1, np.int64)
        for s, q in enumerate(queries):
            d = np.concatenate([pm.distance(row, int(q), np.arange(a, min(a + chunk, n))) for a in range(0, n, chunk)])
            d[(clip_id == clip_id[q]) & (frame == frame[q])] = np.inf
            top = np.argpartition(d, k - 1)[:k]
            top = top[np.lexsort((top, d[top]))]
            nd[s], nb[s] = d[top], np.where(np.isfinite(d[top]), top, -1)
        return nd, nb

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.datasets import StepOutput

        db = inputs["motions"].motions()
        ref = inputs["reference"].motions() if "reference" in inputs else None
        rows, cols, rho, std, count = self.study(db, ref, progress=ctx.progress)
        r_idx, c_idx = np.meshgrid(np.arange(len(rows)), np.arange(len(cols)), indexing="ij")
        long = pa.table(
            {
                "row_measure": pa.array([rows[i] for i in r_idx.ravel()]),
                "col_measure": pa.array([cols[j] for j in c_idx.ravel()]),
                "rho": pa.array(rho.ravel()),
                "rho_std": pa.array(std.ravel()),
                "n_samples": pa.array(count.ravel().astype(np.int32)),
            }
        )
        wide = pa.table({"row_measure": pa.array(list(rows)), **{c: pa.array(rho[:, j]) for j, c in enumerate(cols)}})
        png = plot_heatmap(
            rows,
            cols,
            rho,
            ctx.out_dir / "correlation.png",
            title=f"Spearman rho, {self.params.k} NN of {int(count.max(initial=0))} samples, {db.n_frames} frames",
        )
        return StepOutput(
            {"data": long, "matrix": wide},
            summary={"plot": png.name if png else None, "frames": db.n_frames, "rows": len(rows), "cols": len(cols)},
        )


def plot_heatmap(rows: Sequence[str], cols: Sequence[str], rho: np.ndarray, path: Path, title: str = "") -> Path | None:
    """Write the correlation matrix as an annotated heatmap PNG (needs matplotlib: extra ``plots``)."""
    from mocapflow.framework.errors import ConfigError
    from mocapflow.framework.plotting import pyplot

    try:
        plt = pyplot("correlation heatmaps")
    except ConfigError:  # the tables hold the numbers
        return None
    fig, ax = plt.subplots(figsize=(1.0 + 0.62 * len(cols), 1.0 + 0.5 * len(rows)))
    im = ax.imshow(rho, vmin=0.0, vmax=1.0, cmap="viridis")
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right")
    ax.set_yticks(range(len(rows)), rows)
    for (i, j), v in np.ndenumerate(rho):
        if np.isfinite(v):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=7, color="white" if v < 0.6 else "black")
    ax.set_xlabel("distances by (column)")
    ax.set_ylabel("neighbours by (row)")
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, fraction=0.03).set_label("mean Spearman \u03c1 (dimensionless)", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
