"""Progress bars for long work (stderr, only when it is a terminal or forced)."""
from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def progress_enabled() -> bool:
    """Bars show on an interactive stderr, unless ``MOCAPFLOW_PROGRESS=0``; ``=1`` forces them."""
    flag = os.environ.get("MOCAPFLOW_PROGRESS")
    if flag is not None:
        return flag not in ("0", "", "false", "no")
    return sys.stderr.isatty()


def progress(items: Iterable[T], total: int | None = None, desc: str = "", enabled: bool | None = None) -> Iterator[T]:
    """Iterate with a progress bar (tqdm when installed, a plain counter otherwise)."""
    if not (progress_enabled() if enabled is None else enabled):
        yield from items
        return
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional: fall back to a one-line counter
        n = total if total is not None else (len(items) if hasattr(items, "__len__") else None)  # type: ignore[arg-type]
        for i, item in enumerate(items, 1):
            sys.stderr.write(f"\r{desc} {i}/{n if n is not None else '?'}")
            sys.stderr.flush()
            yield item
        sys.stderr.write("\n")
        return
    yield from tqdm(items, total=total, desc=desc, leave=False, file=sys.stderr, dynamic_ncols=True)
