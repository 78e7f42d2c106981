"""MDM heatmaps like Fig. 1 of Aristidou 2018: joints x time, flagged cells marked.

matplotlib is optional (extra ``plots``); it is imported lazily with the Agg backend.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mocapflow.framework.errors import ConfigError


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
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - optional extra
        raise ConfigError("MDM heatmaps need matplotlib (a mocapflow dependency): pip install matplotlib") from exc
    mdm = np.asarray(mdm, float)
    path = Path(path)
    t, m = mdm.shape
    fig, ax = plt.subplots(figsize=(max(6.0, min(24.0, t / 40.0)), 0.22 * m + 1.4))
    try:
        extent = (0.0, t / fps, m - 0.5, -0.5)
        im = ax.imshow(mdm.T, aspect="auto", cmap="jet", vmin=0.0, vmax=1.0, interpolation="nearest", extent=extent)
        flagged = mdm > threshold
        if flagged.any():
            f, j = np.nonzero(flagged)
            ax.scatter((f + 0.5) / fps, j, s=6, marker="s", facecolors="none", edgecolors="white", linewidths=0.6)
        ax.set_yticks(range(m))
        ax.set_yticklabels(list(joints), fontsize=6)
        ax.set_xlabel("time (s)")
        ax.set_title(title or "movement digression map", fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.03, pad=0.01)
        fig.tight_layout()
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path
