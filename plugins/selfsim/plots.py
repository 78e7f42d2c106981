"""MDM heatmaps like Fig. 1 of Aristidou 2018: joints x time, flagged cells marked.

Every mark is explained on the figure: the colour bar is the MDM value (dimensionless,
``1 - exp(-M^2)`` of the joint's normalised rotation difference from its nearest
neighbours), the white squares are the cells above the threshold (the ones a repair
changes), named in a legend. matplotlib is imported lazily with the Agg backend.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np



def mdm_heatmap(mdm: np.ndarray, joints: Sequence[str], path: str | Path, fps: float = 24.0,
                threshold: float = 0.5, title: str = "") -> Path:
    """Write the movement digression map as a PNG.

    Parameters
    ----------
    mdm : ndarray of shape (T, m), values in [0, 1]
    joints : sequence of str, length m
        Row labels.
    path : str or Path
        Output PNG.
    fps : float
        Frame rate of ``mdm`` (the x axis is in seconds).
    threshold : float
        Cells above it are outlined (the cells a repair would change).
    title : str

    Returns
    -------
    Path
    """
    from mocapflow.framework.plotting import pyplot

    plt = pyplot("MDM heatmaps")
    mdm = np.asarray(mdm, float)
    path = Path(path)
    t, m = mdm.shape
    fig, ax = plt.subplots(figsize=(max(6.0, min(24.0, t / 40.0)), 0.22 * m + 1.8))
    try:
        extent = (0.0, t / fps, m - 0.5, -0.5)
        im = ax.imshow(mdm.T, aspect="auto", cmap="jet", vmin=0.0, vmax=1.0, interpolation="nearest", extent=extent)
        flagged = mdm > threshold
        from matplotlib.lines import Line2D

        mark = dict(marker="s", facecolors="none", edgecolors="white", linewidths=0.6)
        if flagged.any():
            f, j = np.nonzero(flagged)
            ax.scatter((f + 0.5) / fps, j, s=6, **mark)
        ax.set_yticks(range(m))
        ax.set_yticklabels(list(joints), fontsize=6)
        ax.set_ylabel("joint")
        ax.set_xlabel("time (s)")
        ax.set_title(title or "movement digression map", fontsize=9)
        cb = fig.colorbar(im, ax=ax, fraction=0.03, pad=0.01)
        cb.set_label("MDM value (dimensionless): 0 = moves like its\nnearest neighbours, 1 = digresses most", fontsize=7)
        key = Line2D([], [], ls="none", marker="s", markerfacecolor="none", markeredgecolor="white", markersize=5)
        leg = fig.legend([key], [f"white square: MDM > {threshold:g}, cell flagged as erroneous "
                                 f"({int(flagged.sum())} cells; the repair changes these)"],
                         loc="lower center", fontsize=7, frameon=True, facecolor="#00007f", labelcolor="white")
        leg.get_frame().set_edgecolor("none")
        height = 0.22 * m + 1.8
        fig.tight_layout(rect=(0.0, 0.35 / height, 1.0, 1.0))
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path
