"""Progress bars for long work (stderr, only when it is a terminal or forced), and the
announcement of numba compilations (:func:`announce_compilation`)."""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, TypeVar

T = TypeVar("T")


def progress_enabled() -> bool:
    """Bars show on an interactive stderr, unless ``MOCAPFLOW_PROGRESS=0``; ``=1`` forces them."""
    flag = os.environ.get("MOCAPFLOW_PROGRESS")
    if flag is not None:
        return flag not in ("0", "", "false", "no")
    return sys.stderr.isatty()


#: Bars drawing now (the step heartbeat stays quiet while a step shows its own bar).
_ACTIVE = [0]


def progress(
    items: Iterable[T],
    total: int | None = None,
    desc: str = "",
    enabled: bool | None = None,
    weights: Sequence[float] | None = None,
) -> Iterator[T]:
    """Iterate with a progress bar (tqdm when installed, a plain counter otherwise).

    ``weights`` (one per item): the relative work of each item, so that a loop of uneven
    items moves its bar and its ETA by work done, not by items counted."""
    if not (progress_enabled() if enabled is None else enabled):
        yield from items
        return
    _ACTIVE[0] += 1
    try:
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
        if weights is None:
            yield from tqdm(items, total=total, desc=desc, leave=False, file=sys.stderr, dynamic_ncols=True)
            return
        w = [float(x) for x in weights]
        fmt = "{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]"
        with tqdm(total=sum(w), desc=desc, leave=False, file=sys.stderr, dynamic_ncols=True, bar_format=fmt) as bar:
            for item, wi in zip(items, w, strict=False):
                yield item
                bar.update(wi)
    finally:
        _ACTIVE[0] -= 1


@contextlib.contextmanager
def heartbeat(
    desc: str, expected: float | None = None, after: float = 2.0, enabled: bool | None = None
) -> Iterator[None]:
    """While the block runs longer than ``after`` seconds and no other bar is drawing, a
    line on stderr that moves every half second: elapsed time and, when ``expected`` (the
    seconds the same step took last time) is known, a bar and the time left by it."""
    if not (progress_enabled() if enabled is None else enabled):
        yield
        return
    stop = threading.Event()
    t0 = time.monotonic()
    drawn = [False]

    def beat() -> None:
        if stop.wait(after):
            return
        spin = "|/-\\"
        i = 0
        while not stop.wait(0.5):
            if _ACTIVE[0]:
                continue
            el = time.monotonic() - t0
            if expected and expected > 0:
                frac = min(el / expected, 1.0)
                left = f"~{expected - el:.0f} s left" if el < expected else "longer than last time"
                line = f"{desc}: [{'#' * int(frac * 20):<20}] {el:.0f} s, {left} (last run {expected:.0f} s)"
            else:
                line = f"{desc}: {spin[i % 4]} {el:.0f} s"
            i += 1
            sys.stderr.write("\r" + line + "\x1b[K")
            sys.stderr.flush()
            drawn[0] = True

    thread = threading.Thread(target=beat, name="mocapflow-heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        if drawn[0]:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()


COMPILING_MESSAGE = (
    "compiling numba kernels for this machine (once: later runs load them from the cache; this can take a minute)"
)


class _AfterImport:
    """A ``sys.meta_path`` finder that calls ``callback()`` once module ``name`` has been
    imported (a post-import hook), so that a listener can be attached to a heavy module
    without importing it."""

    def __init__(self, name: str, callback: Callable[[], None]) -> None:
        self.name, self.callback, self._busy = name, callback, False

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname != self.name or self._busy:
            return None
        import importlib.util

        self._busy = True
        try:
            spec = importlib.util.find_spec(fullname)
        finally:
            self._busy = False
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        spec.loader = _CallbackLoader(spec.loader, self.callback)  # type: ignore[assignment]
        return spec


class _CallbackLoader:
    """Delegates to the real loader; runs the callback after the module's code ran."""

    def __init__(self, loader: Any, callback: Callable[[], None]) -> None:
        self._loader, self._callback = loader, callback

    def create_module(self, spec: Any) -> Any:
        return self._loader.create_module(spec)

    def exec_module(self, module: Any) -> None:
        self._loader.exec_module(module)
        self._callback()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._loader, name)


@contextlib.contextmanager
def announce_compilation(echo: Callable[[str], None], message: str = COMPILING_MESSAGE) -> Iterator[None]:
    """Within the block, say ``message`` (once) when numba compiles a kernel (cache misses
    only), so a first run on a fresh install does not sit silent. Imports nothing; worker
    processes are not seen."""
    said: list[bool] = []
    listeners: list[tuple[Any, Any]] = []

    def attach() -> None:
        try:
            from numba.core import event
        except Exception:  # no numba, or an API we do not know: stay silent, as before
            return

        class _Announce(event.Listener):  # type: ignore[misc]  # numba: no type information
            def on_start(self, ev: Any) -> None:
                if not said:
                    said.append(True)
                    echo(message)

            def on_end(self, ev: Any) -> None:
                pass

        listener = _Announce()
        event.register("numba:compile", listener)
        listeners.append((event, listener))

    finder = None
    if "numba" in sys.modules:
        attach()
    else:
        finder = _AfterImport("numba", attach)
        sys.meta_path.insert(0, finder)
    try:
        yield
    finally:
        if finder is not None and finder in sys.meta_path:
            sys.meta_path.remove(finder)
        for ev_mod, listener in listeners:
            with contextlib.suppress(Exception):
                ev_mod.unregister("numba:compile", listener)
