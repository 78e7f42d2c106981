"""Progress bars for long work (stderr, only when it is a terminal or forced), and the
announcement of numba compilations (:func:`announce_compilation`)."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

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
