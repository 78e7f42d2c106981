"""Pictures of ``cleaners.mdm``: MDM heatmaps like Fig. 1 of Aristidou 2018 (joints x time,
flagged cells marked, every mark explained on the figure) and before/after plots of the
most-edited joints. matplotlib is imported lazily with the Agg backend.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from mocapflow.framework import quaternions as quat

PAPER_SCORE = "MDM value (dimensionless): 0 = moves like its\nnearest neighbours, 1 = digresses most"


def mdm_heatmap(
    mdm: np.ndarray,
    joints: Sequence[str],
    path: str | Path,
    fps: float = 24.0,
    threshold: float = 0.5,
    title: str = "",
    score: str = PAPER_SCORE,
    rule: str = "",
) -> Path:
    """Write the map ``mdm`` (T, m) at ``fps`` as a PNG at ``path``, rows labelled ``joints``,
    cells above ``threshold`` outlined; ``score`` labels the colour bar (what the value is, its
    units), ``rule`` the white squares (what decided; default: the paper's MDM > threshold)."""
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
        cb.set_label(score, fontsize=7)
        key = Line2D([], [], ls="none", marker="s", markerfacecolor="none", markeredgecolor="white", markersize=5)
        leg = fig.legend(
            [key],
            [
                f"white square: {rule or f'MDM > {threshold:g}'}, cell flagged as erroneous "
                f"({int(flagged.sum())} cells at {fps:g} fps; the repair changes these)"
            ],
            loc="lower center",
            fontsize=7,
            frameon=True,
            facecolor="#00007f",
            labelcolor="white",
        )
        leg.get_frame().set_edgecolor("none")
        height = 0.22 * m + 1.8
        fig.tight_layout(rect=(0.0, 0.35 / height, 1.0, 1.0))
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path


def most_edited(edits: Any, n: int = 4) -> list[tuple[int, str, int]]:
    """(skeleton joint, joint name, edited input cells) of the ``n`` most-edited joints."""
    if edits.num_rows == 0:
        return []
    j = edits["joint"].to_numpy()
    names = edits["joint_name"].to_pylist()
    ids, counts = np.unique(j, return_counts=True)
    order = np.lexsort((ids, -counts))[:n]
    name_of = {int(a): b for a, b in zip(j.tolist(), names, strict=True)}
    return [(int(ids[k]), name_of[int(ids[k])], int(counts[k])) for k in order]


def before_after_plot(before: Any, after: Any, edits: Any, path: str | Path, n: int = 4, title: str = "") -> Path:
    """PNG of the ``n`` most-edited joints (``edits`` table): each joint's rotation angle
    from rest over time, ``before`` and ``after`` cleaning, edited frames shaded."""
    from mocapflow.framework.plotting import pyplot

    plt = pyplot("before/after plots")
    path = Path(path)
    joints = most_edited(edits, n)
    rows = max(len(joints), 1)
    t = np.arange(before.n_frames) / before.fps
    fig, axes = plt.subplots(rows, 1, figsize=(9.0, 1.9 * rows + 0.8), sharex=True, squeeze=False)
    try:
        frames = edits["frame"].to_numpy() if edits.num_rows else np.zeros(0, np.int64)
        ej = edits["joint"].to_numpy() if edits.num_rows else np.zeros(0, np.int64)
        cues = edits["cue"].to_pylist() if edits.num_rows and "cue" in edits.column_names else []
        for ax, (j, name, count) in zip(axes[:, 0], joints, strict=False):
            ident = quat.identity((before.n_frames,))
            a0 = np.rad2deg(quat.geodesic_angle(before.rotations[:, j], ident))
            a1 = np.rad2deg(quat.geodesic_angle(after.rotations[:, j], ident))
            hit = np.zeros(before.n_frames, bool)
            hit[frames[ej == j]] = True
            kinds = sorted({c for c, jj in zip(cues, ej.tolist(), strict=False) if jj == j and c})
            ax.fill_between(
                t,
                0,
                1,
                where=hit,
                transform=ax.get_xaxis_transform(),
                color="0.85",
                step="mid",
                label="edited frames" + (f" ({', '.join(kinds)})" if kinds else ""),
            )
            ax.plot(t, a0, color="tab:red", lw=1.0, label="before (take)")
            ax.plot(t, a1, color="tab:blue", lw=1.0, label="after (cleaned)")
            ax.set_ylabel(f"{name}\nangle (deg)", fontsize=8)
            ax.set_title(f"{name}: {count} input cells edited", fontsize=8)
            ax.legend(fontsize=7, loc="upper right")
        axes[-1, 0].set_xlabel("time (s)")
        fig.suptitle(
            title or f"{before.name}: most-edited joints, rotation angle from rest before/after cleaning", fontsize=9
        )
        fig.tight_layout()
        tmp = path.with_name(path.name + ".tmp.png")
        fig.savefig(tmp, dpi=100)
        tmp.replace(path)
    finally:
        plt.close(fig)
    return path
