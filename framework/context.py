"""What a running step can see: :class:`StepContext`."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .executors import Executor, LocalExecutor
from .progress import progress
from .registry import Registries


@dataclass
class StepContext:
    """Handed to ``Component.run``.

    Attributes
    ----------
    step_id : str
        The step's id (= dataset name).
    out_dir : Path
        Temporary directory of the step's output; files written here (index, model, PNG)
        become part of the dataset when the step commits atomically.
    base_dir : Path
        Directory relative paths in the pipeline resolve against (the YAML file's folder).
    workspace : Path
    registries : Registries
        To resolve other components (e.g. a reader by file extension).
    executor : Executor
        Fans out per-clip work; use :meth:`map`.
    """

    step_id: str
    out_dir: Path
    base_dir: Path
    workspace: Path
    registries: Registries
    executor: Executor = field(default_factory=LocalExecutor)
    log: logging.Logger = field(default_factory=lambda: logging.getLogger("mocapflow"))

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]:
        """``[fn(x) for x in items]`` on the executor, in order, with a progress bar."""
        return self.executor.map(fn, items, desc=desc or self.step_id)

    def map_clips(self, fn: Callable[..., Any], motions: Any, desc: str = "", with_ids: bool = False) -> list[Any]:
        """``[fn(motion) for motion in motions]`` (a motions :class:`Dataset`) on the executor,
        in clip order; workers read the clips from the Parquet file (:func:`.executors.map_clips`)."""
        from .executors import map_clips

        return map_clips(self.executor, fn, motions, desc=desc or self.step_id, with_ids=with_ids)

    def progress(self, items: Iterable[Any], total: int | None = None, desc: str = "") -> Iterable[Any]:
        """Wrap a loop that runs in this process with a progress bar."""
        return progress(items, total=total, desc=desc or self.step_id)

    def resolve(self, path: str | Path) -> Path:
        """A pipeline path (relative to the YAML file unless absolute)."""
        p = Path(path).expanduser()
        return p if p.is_absolute() else (self.base_dir / p)
