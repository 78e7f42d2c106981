"""Fig. 3-style pictures of a lazy neighborhood graph (Krüger et al. 2010).

The distance matrix between a query and one stretch of a database clip, of which only
the cells found by the kNN search are known (grey, darker = more similar); all other cells
were never computed (blue). Warping paths of the matches in that stretch are drawn in
red, the plotted match thicker. Needs matplotlib (the ``plots`` extra), imported lazily.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapflow.framework.errors import ConfigError

from .lng import NeighborhoodGraph
from .matches import QueryMatches, SearchSpace


def local_distance_window(graph: NeighborhoodGraph, lo: int, hi: int) -> np.ndarray:
    """``(m, hi - lo)`` distances of the kNN cells with rows in ``[lo, hi)``; NaN elsewhere."""
    m = graph.ids.shape[0]
    img = np.full((m, hi - lo), np.nan, np.float32)
    for i in range(m):
        ids = graph.ids[i, : graph.count[i]]
        sel = (ids >= lo) & (ids < hi)
        img[i, ids[sel] - lo] = graph.dist[i, : graph.count[i]][sel]
    return img


def plot_neighborhood(graph: NeighborhoodGraph, matches: QueryMatches, space: SearchSpace, path: str | Path, *,
                      match: int = 0, pad: int | None = None, title: str = "") -> Path:
    """Write a PNG of the kNN cells around match ``match`` with the warping paths.

    Parameters
    ----------
    graph : NeighborhoodGraph
        From :func:`.lng.build_graph`.
    matches : QueryMatches
        Its matches (``graph.matches(...)``).
    space : SearchSpace
    path : str or Path
        Output PNG.
    match : int
        Which match (0 = best) the window is centred on.
    pad : int or None
        Database frames shown before and after the match (default: the query length).
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ConfigError("plots need matplotlib (a mocapflow dependency): pip install matplotlib") from exc
    if not 0 <= match < len(matches):
        raise ConfigError(f"match {match} out of range: the query has {len(matches)} matches")
    m = graph.ids.shape[0]
    pad = m if pad is None else pad
    s, e = int(matches.start[match]), int(matches.end[match]) - 1  # last row (end is exclusive)
    clip = space.clip_id[s]
    same = np.flatnonzero(space.clip_id == clip)
    lo, hi = max(int(same[0]), s - pad), min(int(same[-1]) + 1, e + 1 + pad)
    img = local_distance_window(graph, lo, hi)
    fig, ax = plt.subplots(figsize=(6, 6 * min(1.5, max(0.5, (hi - lo) / max(m, 1)))), dpi=100)
    ax.set_facecolor("#2f4b9a")  # cells never computed
    finite = img[np.isfinite(img)]
    vmax = float(finite.max()) if finite.size else 1.0
    f0 = int(space.frame[lo]) - lo  # row -> frame within the clip (rows of one clip are contiguous)
    ax.imshow(np.ma.masked_invalid(img.T), origin="lower", cmap="gray", vmin=0.0, vmax=vmax or 1.0, aspect="auto",
              interpolation="nearest", extent=(-0.5, m - 0.5, lo + f0 - 0.5, hi + f0 - 0.5))
    for r, p in enumerate(matches.paths):
        if lo <= p[:, 1].min() and p[:, 1].max() < hi:
            ax.plot(p[:, 0], p[:, 1] + f0, color="red", lw=2.5 if r == match else 1.0)
    ax.set_ylim(lo + f0 - 0.5, hi + f0 - 0.5)
    ax.set_xlabel("query frame")
    ax.set_ylabel(f"database frame (clip {int(clip)})")
    ax.set_title(title or f"match {match + 1}: cost {matches.cost[match]:.3g}", fontsize=9)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
