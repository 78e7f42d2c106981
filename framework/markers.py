"""Marker trajectories: the optical-marker counterpart of :class:`~.motion.Motion`.

Positions are metres in the file's own axes (C3D/TRC often z-up: readers record
``metadata["up_axis"]``, :func:`to_y_up` converts); a gap (marker not reconstructed) is NaN.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .errors import DataError


@dataclass(frozen=True, eq=False)
class Markers:
    """Labelled marker trajectories of one take: ``labels`` (M), ``positions`` (T, M, 3)
    metres with NaN gaps, ``fps``, JSON-serialisable ``metadata`` (``up_axis``...)."""

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
    """Rotate markers whose up axis is any of ``+-x``, ``-y``, ``+-z`` to y-up by a proper
    rotation (handedness kept): -/+90 degrees about x for ``+z``/``-z``, +/-90 degrees about z
    for ``+x``/``-x``, 180 degrees about z for ``-y``."""
    up = markers.metadata.get("up_axis", "+y")
    if up == "+y":
        return markers
    p = markers.positions
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    rotations = {
        "+z": (x, z, -y),
        "-z": (x, -z, y),
        "+x": (-y, x, z),
        "-x": (y, -x, z),
        "-y": (-x, -y, z),
    }
    if up not in rotations:
        raise DataError(f"markers {markers.name!r}: cannot convert up axis {up!r} to +y")
    out = np.stack(rotations[up], axis=-1)
    return replace(markers, positions=out, metadata=dict(markers.metadata, up_axis="+y", converted_from_up_axis=up))


def guess_up_axis(positions: np.ndarray, letter: str | None = None) -> str:
    """The up axis (``"+z"``, ``"-y"``...) of positions (T, M, 3): ``letter`` if known, else
    the axis the cloud spreads most along (people standing, not lying); the sign is the
    side of the floor (0) the markers lie on. Uses at most ~500 frames."""
    sample = np.asarray(positions)[:: max(1, len(positions) // 500)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames that are all gaps
        if letter is None:
            med = np.nanmedian(np.nanmax(sample, axis=1) - np.nanmin(sample, axis=1), axis=0)
            letter = "xyz"[int(np.nanargmax(med))] if np.isfinite(med).any() else "y"
        centre = np.nanmedian(sample[..., "xyz".index(letter)])
    return ("-" if centre < 0 else "+") + letter
