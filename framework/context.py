"""What a running step can see (:class:`StepContext`) and what an executor must do
(:class:`Executor`)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Protocol, TypeVar

from .clip_refs import _SliceTask, clear_cache, clip_slices
from .datasets import Dataset
from .params import Params
from .progress import progress
from .registry import Registries

T = TypeVar("T")


class Executor(Protocol):
    """How a step fans out per-item work (per clip, per query, per shard).

    ``map`` returns results in input order; ``workers`` is how many items run at once;
    ``close`` frees the workers. An executor may also have ``start()`` (bring workers up
    without blocking: the runner calls it before planning). Its options are declared in
    ``Params`` (a pipeline's ``executor_options``, validated when the pipeline is planned)
    and passed to ``__init__`` as keywords, with ``jobs``. ``fn`` and the items must be
    picklable when work leaves the process.
    """

    name: ClassVar[str]
    Params: ClassVar[type[Params]]

    @property
    def workers(self) -> int: ...

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]: ...

    def close(self) -> None: ...


class SerialExecutor:
    """Every item in this process, in order (the executor of a context made by hand)."""

    name: ClassVar[str] = "serial"
    Params: ClassVar[type[Params]] = Params
    workers: int = 1

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any], desc: str = "") -> list[Any]:
        try:
            return [fn(x) for x in progress(items, total=len(items), desc=desc)]
        finally:
            clear_cache()  # the process keeps no dataset between steps

    def close(self) -> None:
        pass


def map_clips(
    executor: Executor,
    fn: Callable[..., Any],
    dataset: Dataset,
    desc: str = "",
    with_ids: bool = False,
    slices_per_worker: int = 4,
) -> list[Any]:
    """``[fn(motion) for motion in dataset]`` on ``executor``, in clip order.

    Items are :class:`~.clip_refs.ClipSlice` references (``slices_per_worker`` per worker,
    balanced by frames; one slice when the executor has a single worker), so workers read
    their clips from the Parquet file instead of receiving pickled motions. ``fn`` must be
    picklable (a module-level function, a bound method of a component, a
    ``functools.partial``); with ``with_ids`` it is called as ``fn(motion, clip_id)``.
    """
    workers = max(1, int(executor.workers))
    pieces = clip_slices(dataset, 1 if workers == 1 else workers * slices_per_worker)
    # largest slices first (a long clip started last would finish alone); results back in clip order
    frames = dataset.table("clips", columns=["n_frames"])["n_frames"].to_numpy()
    order = sorted(range(len(pieces)), key=lambda i: -int(frames[pieces[i].start : pieces[i].stop].sum()))
    out = executor.map(_SliceTask(fn, with_ids), [pieces[i] for i in order], desc=desc)
    by_slice = dict(zip(order, out, strict=True))
    return [r for i in range(len(pieces)) for r in by_slice[i]]


@dataclass
class StepContext:
    """Handed to a step.

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
        The run's registries (what its plugins, less any ``--block``, registered): to resolve
        other components (a reader by file extension, an index class). Work sent to
        executor workers carries them.
    executor : Executor
        Fans out per-clip work; use :meth:`map` and :meth:`map_clips`.
    """

    step_id: str
    out_dir: Path
    base_dir: Path
    workspace: Path
    registries: Registries
    executor: Executor = field(default_factory=SerialExecutor)
    log: logging.Logger = field(default_factory=lambda: logging.getLogger("mocapflow"))

    def map(self, fn: Callable[[Any], T], items: Sequence[Any], desc: str = "") -> list[T]:
        """``[fn(x) for x in items]`` on the executor, in order, with a progress bar."""
        return self.executor.map(fn, items, desc=desc or self.step_id)

    def map_clips(self, fn: Callable[..., T], motions: Dataset, desc: str = "", with_ids: bool = False) -> list[T]:
        """``[fn(motion) for motion in motions]`` (a motions :class:`Dataset`) on the executor,
        in clip order; workers read the clips from the Parquet file (:func:`map_clips`)."""
        return map_clips(self.executor, fn, motions, desc=desc or self.step_id, with_ids=with_ids)

    def progress(self, items: Iterable[T], total: int | None = None, desc: str = "") -> Iterable[T]:
        """Wrap a loop that runs in this process with a progress bar."""
        return progress(items, total=total, desc=desc or self.step_id)

    def resolve(self, path: str | Path) -> Path:
        """A pipeline path (relative to the YAML file unless absolute)."""
        p = Path(path).expanduser()
        return p if p.is_absolute() else (self.base_dir / p)
