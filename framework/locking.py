"""The runner's own folder in a workspace, and the lock that lets one run at a time use it.

A workspace may be a folder the user already had (``workspace: ~/mocap``): the runner then
deletes or replaces nothing it did not create. Its temporary step outputs and the previous
versions of replaced datasets live in ``<workspace>/.mocapflow/`` (``tmp/``, ``trash/``),
which carries a marker file; a ``.mocapflow`` folder without the marker is not the runner's
and is refused, never cleaned.

``<workspace>/.mocapflow/lock`` keeps two runs from writing one workspace at once. It is an
advisory ``flock`` (released by the kernel when the holder exits, even by ``kill -9``) on a
file that records the holder (pid, host, start time, pipeline) for messages. A second run
waits up to ``wait`` seconds, then refuses with a :class:`~.errors.LockError` naming the
holder. A holder recorded in a lock nobody holds is a run that was killed: the next run
says so and takes the lock over. Where ``flock`` is unavailable (no :mod:`fcntl`, or a
filesystem without locks) the record alone decides: the lock is taken over when its holder
ran on this host and is no longer alive.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import shutil
import socket
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from .errors import ConfigError, LockError

log = logging.getLogger("mocapflow")

RUNNER_DIR = ".mocapflow"
MARKER = "CREATED-BY-MOCAPFLOW"
LOCK_FILE = "lock"
_MARKER_TEXT = (
    "This folder was created by the mocapflow runner for its temporary files and its lock.\n"
    "mocapflow deletes what is inside tmp/ and trash/ here; it never deletes anything else.\n"
)


def runner_dir(workspace: str | Path, create: bool = True) -> Path | None:
    """``<workspace>/.mocapflow``, created (atomically, with its marker) if ``create``.

    Raises :class:`ConfigError` when a ``.mocapflow`` entry exists without the marker: it
    belongs to someone else and the runner will not use or clean it.
    """
    d = Path(workspace) / RUNNER_DIR
    for _ in range(2):
        if d.exists() or d.is_symlink():
            if d.is_symlink() or not d.is_dir() or not (d / MARKER).is_file():
                raise ConfigError(
                    f"{d} exists but was not created by mocapflow (no {MARKER} inside); the runner keeps "
                    "its temporary files there and will not touch it: move it away or choose another workspace"
                )
            return d
        if not create:
            return None
        staging = d.with_name(f"{RUNNER_DIR}-{uuid.uuid4().hex[:8]}")
        staging.mkdir(parents=True)
        (staging / MARKER).write_text(_MARKER_TEXT)
        try:
            os.rename(staging, d)  # atomic: the folder never exists without its marker
            return d
        except OSError:  # another run created it first: use theirs
            shutil.rmtree(staging, ignore_errors=True)
    raise ConfigError(f"cannot create {d}")  # pragma: no cover - only under a pathological race


def remove_owned(workspace: str | Path, *names: str) -> None:
    """Delete ``names`` (e.g. ``tmp``, ``trash``) inside the runner's own marked folder only."""
    d = runner_dir(workspace, create=False)
    if d is not None:
        for name in names:
            shutil.rmtree(d / name, ignore_errors=True)


def _proc_start(pid: int) -> str | None:
    """Start time of a process in clock ticks since boot (Linux), to tell pid reuse apart."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rpartition(")")[2].split()[19]
    except (OSError, IndexError):
        return None


def holder_alive(holder: dict[str, Any]) -> bool:
    """Whether the process recorded in a lock may still run (``True`` when it cannot be told:
    another host, or no pid)."""
    pid = holder.get("pid")
    if holder.get("host") != socket.gethostname() or not isinstance(pid, int):
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass
    start = holder.get("proc_start")
    return start is None or _proc_start(pid) in (None, start)


def describe_holder(holder: dict[str, Any]) -> str:
    if not holder:
        return "a process that left no record"
    pipeline = f", pipeline {holder['pipeline']!r}" if holder.get("pipeline") else ""
    return f"pid {holder.get('pid')} on host {holder.get('host')}, started {holder.get('started')}{pipeline}"


class WorkspaceLock:
    """Exclusive use of a workspace by one run; a context manager.

    Parameters
    ----------
    workspace : Path
        The workspace folder (created if missing).
    wait : float
        Seconds to wait for another run to finish before refusing (``0``: refuse at once;
        ``float("inf")``: wait as long as it takes).
    pipeline : str
        Recorded in the lock, for the message another run shows.
    echo : callable, optional
        Receives the "waiting for ..." line.
    poll : float
        Seconds between attempts while waiting.
    """

    def __init__(
        self,
        workspace: str | Path,
        wait: float = 0.0,
        pipeline: str = "",
        echo: Callable[[str], None] | None = None,
        poll: float = 0.2,
    ) -> None:
        self.workspace = Path(workspace)
        self.wait = float(wait)
        self.pipeline = pipeline
        self.echo = echo or (lambda msg: None)
        self.poll = poll
        self._fd: int | None = None
        self.path: Path | None = None

    # --- the record ----------------------------------------------------------------
    def _read(self, fd: int) -> dict[str, Any]:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            raw = b""
            while chunk := os.read(fd, 65536):
                raw += chunk
            return json.loads(raw) if raw.strip() else {}
        except (OSError, ValueError):
            return {"pid": None, "host": "?", "started": "?"}

    def _write(self, fd: int) -> None:
        me = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "proc_start": _proc_start(os.getpid()),
            "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "pipeline": self.pipeline,
        }
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(me).encode())
        os.fsync(fd)

    # --- acquiring -----------------------------------------------------------------
    def _try_flock(self, fd: int) -> bool | None:
        """True: locked; False: held by another; None: this filesystem has no flock."""
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            return False
        except OSError as exc:
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                return False
            if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                return None
            raise

    def acquire(self) -> WorkspaceLock:
        self.workspace.mkdir(parents=True, exist_ok=True)
        self.path = runner_dir(self.workspace) / LOCK_FILE
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.wait
        waiting = False
        try:
            while True:
                got = self._try_flock(fd)
                holder = self._read(fd)
                if got is None:  # no flock here: the record decides
                    got = not holder or not holder_alive(holder)
                if got:
                    break
                if time.monotonic() >= deadline:
                    hint = (
                        "wait for it to finish, or pass a longer --wait SECONDS"
                        if self.wait
                        else "wait for it to finish, or pass --wait SECONDS to wait for it"
                    )
                    raise LockError(
                        f"workspace {self.workspace} is in use by another run ({describe_holder(holder)}); {hint}"
                    )
                if not waiting:
                    self.echo(
                        f"  workspace {self.workspace} is in use by {describe_holder(holder)}; waiting "
                        f"{'as long as it takes' if self.wait == float('inf') else f'up to {self.wait:g} s'}..."
                    )
                    waiting = True
                time.sleep(self.poll)
            if holder:
                state = "is no longer running" if not holder_alive(holder) else "no longer holds it"
                log.warning(
                    "workspace %s: taking over the lock of a run that did not finish (%s, which %s); "
                    "its unfinished outputs are discarded",
                    self.workspace,
                    describe_holder(holder),
                    state,
                )
            self._write(fd)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        return self

    def release(self) -> None:
        """Clear the record (so the next run sees a clean release), then unlock."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
        finally:
            os.close(fd)  # closing the last descriptor releases the flock

    def __enter__(self) -> WorkspaceLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
