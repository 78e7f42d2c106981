"""Marker trajectories: the optical-marker counterpart of :class:`~.motion.Motion`.

Glossary
--------
marker
    A labelled point tracked by the capture system (``LFHD``, ``R.ASIS``...).
gap
    A frame where a marker was not reconstructed; its position is NaN (all three
    coordinates).
axes
    Positions are metres in the file's own axes. C3D and TRC files are often z-up; readers
    record the up axis in ``metadata["up_axis"]`` (``"+y"``, ``"+z"``...) and convert to y-up
    only when asked (see :func:`to_y_up`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .errors import DataError


@dataclass(frozen=True, eq=False)
class Markers:
    """Labelled marker trajectories of one take.

    Parameters
    ----------
    labels : tuple of str, length M
        Marker labels, stripped of padding.
    positions : ndarray of shape (T, M, 3), metres
        Marker positions; NaN marks a gap.
    fps : float
        Frames per second.
    name : str
        Take name (usually the file stem).
    metadata : dict
        Source path, format, checksum, ``up_axis``, ``first_frame`` and anything else worth
        keeping (JSON-serialisable).
    """

    labels: tuple[str, ...]
    positions: np.ndarray
    fps: float
    name: str = ""
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        labels = tuple(str(x) for x in self.labels)
        pos = np.asarray(self.positions, dtype=np.float64)
        if pos.ndim != 3 or pos.shape[1:] != (len(labels), 3):
            raise DataError(f"markers {self.name!r}: positions must be (T, {len(labels)}, 3), got {pos.shape}")
        if not self.fps > 0:
            raise DataError(f"markers {self.name!r}: fps must be positive, got {self.fps}")
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "fps", float(self.fps))

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    @property
    def duration(self) -> float:
        """Length in seconds (``n_frames / fps``)."""
        return self.n_frames / self.fps

    def __len__(self) -> int:
        return self.n_frames

    @property
    def gaps(self) -> np.ndarray:
        """Boolean mask of missing samples, shape (T, M)."""
        return np.asarray(np.isnan(self.positions).any(axis=-1))

    def index(self, label: str) -> int:
        try:
            return self.labels.index(label)
        except ValueError:
            raise DataError(f"markers {self.name!r} have no label {label!r}") from None

    def select(self, labels: list[str] | tuple[str, ...]) -> Markers:
        """The named markers only, in the given order."""
        idx = [self.index(lb) for lb in labels]
        return replace(self, labels=tuple(labels), positions=self.positions[:, idx])

    def slice(self, start: int, stop: int) -> Markers:
        """Frames ``[start, stop)`` (metadata records the offset)."""
        meta = dict(self.metadata, source_start_frame=int(self.metadata.get("source_start_frame", 0)) + int(start))
        return replace(self, positions=self.positions[start:stop], metadata=meta)


def to_y_up(markers: Markers) -> Markers:
    """Rotate z-up markers (``metadata["up_axis"]`` ``"+z"`` or ``"-z"``) to y-up.

    ``+z``: ``(x, y, z) -> (x, z, -y)``, a rotation of -90 degrees about x; ``-z``: the
    opposite rotation. Both are proper rotations (handedness kept). Markers already y-up
    are returned unchanged; other up axes raise :class:`DataError`.
    """
    up = markers.metadata.get("up_axis", "+y")
    if up == "+y":
        return markers
    p = markers.positions
    if up == "+z":
        out = np.stack([p[..., 0], p[..., 2], -p[..., 1]], axis=-1)
    elif up == "-z":  # +90 degrees about x
        out = np.stack([p[..., 0], -p[..., 2], p[..., 1]], axis=-1)
    else:
        raise DataError(f"markers {markers.name!r}: cannot convert up axis {up!r} to +y")
    return replace(markers, positions=out, metadata=dict(markers.metadata, up_axis="+y", converted_from_up_axis=up))


def guess_up_axis(positions: np.ndarray, letter: str | None = None) -> str:
    """The up axis of marker positions, as ``"+z"``, ``"-y"``...

    Parameters
    ----------
    positions : ndarray of shape (T, M, 3)
        Marker positions (NaN gaps allowed).
    letter : str or None
        The vertical axis if known (``"z"``, e.g. from C3D ``POINT:Y_SCREEN``); otherwise
        the axis along which the marker cloud spreads most (median over frames; right for
        people standing or walking, not lying).

    The sign is the side of 0 where the markers lie (the floor is near 0). At most ~500
    evenly spaced frames are used.
    """
    sample = np.asarray(positions)[:: max(1, len(positions) // 500)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames that are all gaps
        if letter is None:
            med = np.nanmedian(np.nanmax(sample, axis=1) - np.nanmin(sample, axis=1), axis=0)
            letter = "xyz"[int(np.nanargmax(med))] if np.isfinite(med).any() else "y"
        centre = np.nanmedian(sample[..., "xyz".index(letter)])
    return ("-" if centre < 0 else "+") + letter
