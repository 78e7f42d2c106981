"""Fig. 3-style pictures of a lazy neighborhood graph (Krüger et al. 2010).

The distance matrix between a query and one stretch of a database clip, of which only
the cells of the graph (the kNN search's cells) are known (grey, darker = more similar,
with a colour bar in feature units); all other cells were never computed (blue). Warping
paths of the matches in that stretch are drawn in red, the plotted match thick and solid,
the others thin and dashed, each labelled with its rank; a legend names every mark and
the database clip is named, not numbered. Needs matplotlib, imported lazily.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from mocapflow.framework.errors import ConfigError
from mocapflow.framework.matching import QueryMatches, SearchSpace

if TYPE_CHECKING:  # annotations only: lng.py imports this module (lazily)
    from mocapflow.framework import StepContext

    from .graph import NeighborhoodGraph


def local_distance_window(graph: NeighborhoodGraph, lo: int, hi: int) -> np.ndarray:
    """``(m, hi - lo)`` distances of the kNN cells with rows in ``[lo, hi)``; NaN elsewhere."""
    m = graph.ids.shape[0]
    img = np.full((m, hi - lo), np.nan, np.float32)
    for i in range(m):
        ids = graph.ids[i, : graph.count[i]]
        sel = (ids >= lo) & (ids < hi)
        img[i, ids[sel] - lo] = graph.dist[i, : graph.count[i]][sel]
    return img


def plot_neighborhood(
    graph: NeighborhoodGraph,
    matches: QueryMatches,
    space: SearchSpace,
    path: str | Path,
    *,
    match: int = 0,
    pad: int | None = None,
    title: str = "",
) -> Path:
    """Write a PNG of the kNN cells around match ``match`` with the warping paths.

    Parameters
    ----------
    graph : NeighborhoodGraph
        From :func:`.graph.build_graph`.
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
    from mocapflow.framework.plotting import pyplot

    plt = pyplot("LNG plots")
    from matplotlib.patches import Patch

    if not 0 <= match < len(matches):
        raise ConfigError(f"match {match} out of range: the query has {len(matches)} matches")
    m = graph.ids.shape[0]
    pad = m if pad is None else pad
    s, e = int(matches.start[match]), int(matches.end[match]) - 1  # last row (end is exclusive)
    clip = space.clip_id[s]
    same = np.flatnonzero(space.clip_id == clip)
    lo, hi = max(int(same[0]), s - pad), min(int(same[-1]) + 1, e + 1 + pad)
    img = local_distance_window(graph, lo, hi)
    fig, ax = plt.subplots(figsize=(7, 1.6 + 6 * min(1.5, max(0.5, (hi - lo) / max(m, 1)))), dpi=100)
    never = "#2f4b9a"  # cells never computed
    ax.set_facecolor(never)
    finite = img[np.isfinite(img)]
    vmax = float(finite.max()) if finite.size else 1.0
    f0 = int(space.frame[lo]) - lo  # row -> frame within the clip (rows of one clip are contiguous)
    im = ax.imshow(
        np.ma.masked_invalid(img.T),
        origin="lower",
        cmap="gray",
        vmin=0.0,
        vmax=vmax or 1.0,
        aspect="auto",
        interpolation="nearest",
        extent=(-0.5, m - 0.5, lo + f0 - 0.5, hi + f0 - 0.5),
    )
    handles = [
        Patch(
            facecolor=never,
            edgecolor="none",
            label=f"not among the k = {graph.ids.shape[1]} nearest neighbours of the query frame (never computed)",
        )
    ]
    for r, p in enumerate(matches.paths):
        if lo <= p[:, 1].min() and p[:, 1].max() < hi:
            mine = r == match
            (line,) = ax.plot(
                p[:, 0],
                p[:, 1] + f0,
                color="red" if mine else "#ff8c69",
                lw=2.5 if mine else 1.2,
                ls="-" if mine else "--",
                label=f"{'this' if mine else 'another'} match: rank {r + 1}, cost {matches.cost[r]:.3g}",
            )
            handles.append(line)
            if not mine:
                mid = p[len(p) // 2]
                ax.annotate(
                    f"#{r + 1}",
                    (mid[0], mid[1] + f0),
                    color="#ff8c69",
                    fontsize=8,
                    xytext=(-14, 4),
                    textcoords="offset points",
                )
    ax.set_ylim(lo + f0 - 0.5, hi + f0 - 0.5)
    names = getattr(space, "clip_names", None) or {}
    clip_label = names.get(int(clip), f"clip id {int(clip)}")
    ax.set_xlabel("query frame (from the query's first frame)")
    ax.set_ylabel(f"frame of database clip {clip_label}")
    ax.set_title(title or f"match {match + 1}: cost {matches.cost[match]:.3g}", fontsize=9)
    cb = fig.colorbar(im, ax=ax, fraction=0.05, pad=0.02)
    cb.set_label(
        "local distance of a graph cell, darker = more similar\n(feature units: metres for end-effector features)",
        fontsize=8,
    )
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.09), fontsize=7, frameon=False)
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    from mocapflow.framework.workspace import atomic_path

    with atomic_path(out) as tmp:  # a new file renamed over the name: never writes through a link
        fig.savefig(tmp, format=out.suffix.lstrip(".").lower() or "png")
    plt.close(fig)
    return out


#: queries of a step that get pictures (``plots`` parameter of ``matchers.search``)
PLOT_QUERIES = 16


def plot_matches(
    n: int, query_id: int, query: Any, matches: QueryMatches, space: SearchSpace, ctx: StepContext, **graph_kw: Any
) -> None:
    """``plots/q<query>_m<rank>.png`` for the top ``n`` matches of one of the first
    :data:`PLOT_QUERIES` queries: the kNN cells of the query's lazy neighbourhood graph
    (:func:`.graph.build_graph`, the gap-tolerant defaults unless ``graph_kw`` says otherwise)."""
    if not n or query_id >= PLOT_QUERIES or not len(matches):
        return
    from .graph import build_graph, graph_options

    graph = build_graph(query.features, space, **{**graph_options(), **graph_kw})
    for r in range(min(n, len(matches))):
        plot_neighborhood(
            graph,
            matches,
            space,
            ctx.out_dir / "plots" / f"q{query_id}_m{r + 1}.png",
            match=r,
            title=f"{query.name} - match {r + 1}, cost {matches.cost[r]:.3g}",
        )
