"""Step outputs in memory and finished datasets on disk.

A dataset is the directory ``<workspace>/<step>/`` a step wrote atomically. It holds one
Parquet file per table (``data.parquet`` is the main one; a motions dataset also has
``clips``, ``skeletons`` and ``rejects``), any files the component wrote (a persisted index,
a fitted model, PNG plots) and ``_manifest.json`` with the provenance (also stored in each
Parquet file's key-value metadata under ``mocapflow``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from . import schema
from .errors import DataError, PipelineError
from .schema import fixed_list, fixed_list_to_numpy
from .workspace import MANIFEST, TableWriter, Workspace

if TYPE_CHECKING:
    from .database import MotionDatabase
    from .registry import Registries


@dataclass
class StepOutput:
    """What a component's ``run`` returns: named Arrow tables (``"data"`` is the main one)
    and a free-form summary (shown by the CLI, stored in the manifest). A table may be a
    :class:`~.workspace.TableWriter` the step streamed in pieces (``ctx.table_writer``)."""

    tables: dict[str, pa.Table | TableWriter] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class FeatureMatrix:
    """Feature vectors with their frame ids.

    Attributes
    ----------
    clip_id, frame : ndarray of int32, shape (n,)
    x : ndarray of float32, shape (n, dim)
    """

    clip_id: np.ndarray
    frame: np.ndarray
    x: np.ndarray


def frame_id_table(clip_id: np.ndarray, frame: np.ndarray) -> pa.Table:
    return pa.table(
        {"clip_id": pa.array(np.asarray(clip_id, np.int32)), "frame": pa.array(np.asarray(frame, np.int32))}
    )


def feature_table(clip_id: np.ndarray, frame: np.ndarray, x: np.ndarray) -> pa.Table:
    """Feature table (``clip_id``, ``frame``, fixed-size ``features``) of ``x (n, dim)`` float32."""
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 2 or x.shape[0] != len(clip_id):
        raise DataError(f"features must be (n_frames, dim) with n_frames={len(clip_id)}, got {x.shape}")
    t = frame_id_table(clip_id, frame)
    return t.append_column("features", fixed_list(x))


class Dataset:
    """A finished step output directory ``<workspace>/<step>`` (read-only view)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if not (self.path / MANIFEST).is_file():
            raise PipelineError(f"{self.path} is not a finished mocapflow dataset (no {MANIFEST})")

    @cached_property
    def manifest(self) -> dict[str, Any]:
        manifest: dict[str, Any] = json.loads((self.path / MANIFEST).read_text())
        return manifest

    @property
    def step(self) -> str:
        return str(self.manifest["step"])

    @property
    def producer(self) -> str:
        """Registry key of the component that wrote it (``features.end_effectors``)."""
        return str(self.manifest["component"])

    @property
    def producer_kind(self) -> str:
        return self.producer.partition(".")[0]

    @property
    def fingerprint(self) -> str:
        return str(self.manifest["fingerprint"])

    def table_names(self) -> list[str]:
        return sorted(p.stem for p in self.path.glob("*.parquet"))

    def has_table(self, name: str) -> bool:
        return (self.path / f"{name}.parquet").is_file()

    def schema(self, name: str = "data") -> pa.Schema:
        """The Arrow schema of one table (its footer only: no column is decoded)."""
        p = self.path / f"{name}.parquet"
        if not p.is_file():
            raise PipelineError(
                f"dataset {self.path.name!r} has no table {name!r} (has {', '.join(self.table_names())})"
            )
        return pq.read_schema(p)

    def table(self, name: str = "data", columns: list[str] | None = None) -> pa.Table:
        p = self.path / f"{name}.parquet"
        if not p.is_file():
            raise PipelineError(
                f"dataset {self.path.name!r} has no table {name!r} (has {', '.join(self.table_names())})"
            )
        return pq.read_table(p, columns=columns, memory_map=True)

    # --- typed views ----------------------------------------------------------------
    def features(self) -> FeatureMatrix:
        """The feature matrix of a features dataset."""
        if "features" not in (self.schema("data").names if self.has_table("data") else []):
            raise PipelineError(f"dataset {self.path.name!r} ({self.producer}) holds no feature vectors")
        t = self.table("data", columns=["clip_id", "frame", "features"])
        return FeatureMatrix(
            t["clip_id"].to_numpy().astype(np.int32),
            t["frame"].to_numpy().astype(np.int32),
            fixed_list_to_numpy(t["features"]),
        )

    def motions(self) -> MotionDatabase:
        """The clips of a motions dataset as a :class:`MotionDatabase`."""
        from .motion_tables import database_from_tables

        if not self.has_table("clips"):
            raise PipelineError(f"dataset {self.path.name!r} ({self.producer}) holds no motions")
        if self.has_table("rotations"):
            frames = self.table("data", columns=list(schema.MOTION_COLUMNS))
            return database_from_tables(self.table("clips"), self.table("skeletons"), frames, self.table("rotations"))
        frames = self.table("data", columns=list(schema.MOTION_COLUMNS_V1))  # the first layout
        return database_from_tables(self.table("clips"), self.table("skeletons"), frames)

    def index(self, registries: Registries) -> Any:
        """Load the persisted index of an index dataset (no rebuild) with the class that
        ``registries`` hold for its producer."""
        return registries.resolve(self.producer).load(self.path / "index")

    def frame_ids(self) -> tuple[np.ndarray, np.ndarray]:
        """``(clip_id, frame)`` of the rows of the main table."""
        t = self.table("data", columns=["clip_id", "frame"])
        return t["clip_id"].to_numpy().astype(np.int32), t["frame"].to_numpy().astype(np.int32)


def read_datasets(workspace: str | Path) -> Mapping[str, Dataset]:
    """Every finished dataset of a workspace, by step id."""
    return {d.name: Dataset(d) for d in Workspace(workspace).dataset_dirs()}
