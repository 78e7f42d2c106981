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
from .workspace import TableWriter

T = TypeVar("T")


class Executor(Protocol):
    """How a step fans out per-item work: ``map`` (results in input order; ``fn`` and items
    picklable), ``workers`` running at once, ``close``, optionally ``start()`` (called before
    planning). Options: ``Params`` (``executor_options``), passed as keywords with ``jobs``."""

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
    clips: tuple[int, int] | None = None,
) -> list[Any]:
    """``[fn(motion) for motion in dataset]`` (``fn(motion, clip_id)`` with ``with_ids``) on
    ``executor``, in clip order; ``clips``: only the clips at positions ``[start, stop)``
    (a batch of :func:`~.clip_refs.clip_batches`). Workers get :class:`~.clip_refs.ClipSlice` references
    (``slices_per_worker`` each, balanced by frames) and read their clips from Parquet."""
    workers = max(1, int(executor.workers))
    pieces = clip_slices(dataset, 1 if workers == 1 else workers * slices_per_worker, clips)
    # largest slices first (a long clip started last would finish alone); results back in clip order
    frames = dataset.table("clips", columns=["n_frames"])["n_frames"].to_numpy()
    order = sorted(range(len(pieces)), key=lambda i: -int(frames[pieces[i].start : pieces[i].stop].sum()))
    out = executor.map(_SliceTask(fn, with_ids), [pieces[i] for i in order], desc=desc)
    by_slice = dict(zip(order, out, strict=True))
    return [r for i in range(len(pieces)) for r in by_slice[i]]


@dataclass
class StepContext:
    """Handed to a step: files written to ``out_dir`` become part of the dataset at commit;
    relative pipeline paths resolve against ``base_dir``; ``registries`` are the run's
    (less any ``--block``), carried by work sent to workers."""

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

    def map_clips(
        self,
        fn: Callable[..., T],
        motions: Dataset,
        desc: str = "",
        with_ids: bool = False,
        clips: tuple[int, int] | None = None,
    ) -> list[T]:
        """:func:`map_clips` on the step's executor (``clips``: a range of clip positions)."""
        return map_clips(self.executor, fn, motions, desc=desc or self.step_id, with_ids=with_ids, clips=clips)

    def table_writer(self, name: str, schema: Any) -> TableWriter:
        """A table of this step written in pieces (``writer.write(table)`` per batch of
        clips), so that no step holds the whole library; return it in ``StepOutput.tables``
        under ``name``."""
        return TableWriter(self.out_dir / f"{name}.parquet", schema)

    def progress(
        self, items: Iterable[T], total: int | None = None, desc: str = "", weights: Sequence[float] | None = None
    ) -> Iterable[T]:
        """Wrap a loop that runs in this process with a progress bar (``weights``: the
        relative work of each item, for a loop of uneven items)."""
        return progress(items, total=total, desc=desc or self.step_id, weights=weights)

    def resolve(self, path: str | Path) -> Path:
        """A pipeline path (relative to the YAML file unless absolute)."""
        p = Path(path).expanduser()
        return p if p.is_absolute() else (self.base_dir / p)
