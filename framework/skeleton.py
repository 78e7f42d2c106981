"""Skeletons: the immutable joint hierarchy shared by the frames of a clip."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import DataError
from .joints import CANONICAL_JOINTS


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy: ``names`` (J) in topological order, ``parents`` (J,) (-1: root,
    joint 0), rest ``offsets`` (J, 3) metres in the parent's frame (the root's ignored),
    ``canonical`` name -> joint index. For writers: per-joint Euler ``rotation_orders`` as
    listed (``""``: none), ASF ``axes`` (J, 4) quaternions, the file's ``channels``."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    canonical: dict[str, int] = field(default_factory=dict)
    rotation_orders: tuple[str, ...] = ()
    axes: np.ndarray | None = None
    channels: tuple[tuple[str, ...], ...] = ()
    name: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = tuple(self.names)
        parents = np.asarray(self.parents, dtype=np.int64)
        offsets = np.asarray(self.offsets, dtype=np.float64)
        n = len(names)
        if parents.shape != (n,) or offsets.shape != (n, 3):
            raise DataError(
                f"skeleton {self.name!r}: parents {parents.shape} / offsets {offsets.shape} do not match {n} joints"
            )
        if n == 0 or parents[0] != -1 or np.any(parents[1:] >= np.arange(1, n)) or np.any(parents[1:] < 0):
            raise DataError(f"skeleton {self.name!r}: joints must be in topological order with the root first")
        parents.setflags(write=False)
        offsets.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        if not self.rotation_orders:
            object.__setattr__(self, "rotation_orders", ("zxy",) * n)
        if self.axes is not None:
            axes = np.asarray(self.axes, dtype=np.float64)
            axes.setflags(write=False)
            object.__setattr__(self, "axes", axes)
        for canon, idx in self.canonical.items():
            if canon not in CANONICAL_JOINTS or not 0 <= idx < n:
                raise DataError(f"skeleton {self.name!r}: bad canonical entry {canon!r} -> {idx}")

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of a joint by source name or canonical name."""
        if name in self.canonical:
            return self.canonical[name]
        try:
            return self.names.index(name)
        except ValueError:
            raise DataError(f"skeleton {self.name!r} has no joint {name!r}") from None

    def children(self, j: int) -> list[int]:
        return [int(c) for c in np.nonzero(self.parents == j)[0]]

    def canonical_indices(self, joints: tuple[str, ...] | list[str] = CANONICAL_JOINTS) -> np.ndarray:
        """Joint index per canonical name, ``-1`` where the skeleton lacks it."""
        return np.array([self.canonical.get(j, -1) for j in joints], dtype=np.int64)

    # --- serialisation ------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "names": list(self.names),
            "parents": self.parents.tolist(),
            "offsets": self.offsets.tolist(),
            "canonical": dict(self.canonical),
            "rotation_orders": list(self.rotation_orders),
            "axes": None if self.axes is None else self.axes.tolist(),
            "channels": [list(c) for c in self.channels],
            "name": self.name,
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Skeleton:
        return cls(
            names=tuple(d["names"]),
            parents=np.asarray(d["parents"]),
            offsets=np.asarray(d["offsets"], dtype=float),
            canonical={k: int(v) for k, v in d.get("canonical", {}).items()},
            rotation_orders=tuple(d.get("rotation_orders", ())),
            axes=None if d.get("axes") is None else np.asarray(d["axes"]),
            channels=tuple(tuple(c) for c in d.get("channels", ())),
            name=d.get("name", ""),
            meta=d.get("meta", {}),
        )

    def fingerprint(self) -> str:
        """Stable content hash (16 hex digits) used as the skeleton id in tables (cached)."""
        cached = self.__dict__.get("_fingerprint")
        if cached is None:
            payload = json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":")).encode()
            cached = hashlib.sha1(payload).hexdigest()[:16]
            object.__setattr__(self, "_fingerprint", cached)
        return cached

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Skeleton) and self.fingerprint() == other.fingerprint()

    def __hash__(self) -> int:
        return hash(self.fingerprint())
