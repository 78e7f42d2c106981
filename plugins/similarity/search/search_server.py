"""The search server of ``mocapflow search --serve`` and the client side of ``mocapflow search``.

A fresh Python process pays a fixed cost before the first match (measured at 1 M frames,
docs/knn.md): importing NumPy, pyarrow, pydantic and numba, loading the cached numba
kernels, building the registries. The server pays it once: it holds one
:class:`~.search_command.SearchSession` (index memory-mapped, kernels loaded, block boxes
computed) and answers each request on the Unix socket ``WORKSPACE/.search.sock``.

Protocol: one JSON object per connection each way. Request ``{"args": {...}, "cwd": ...}``
(the command's options; relative paths are resolved against the client's working
directory), reply ``{"stdout": ..., "stderr": ..., "rc": ...}``, printed by the client as
if it had searched itself. The client (:func:`ask`) imports only the standard library.
Each connection is read in its own thread (a client has :data:`REQUEST_TIMEOUT` seconds to
send its request, :data:`MAX_REQUEST` bytes at most, else it is dropped: one stalled client
never blocks the others); the searches themselves run one at a time. A request is checked
(an option of the wrong type is an error, exit 2; one an older client does not send takes
the CLI's default). The server rebuilds its session when the workspace's index, features
or motions step was recomputed, and removes its socket when it stops; it deletes only a
stale socket at its path, never a file of another kind. The socket is made owner-only
(0600): the workspace's owner is the only client.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import socket
import stat
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

SOCKET_NAME = ".search.sock"
# request options the server takes from the client (the rest: its own plugin selection)
_FORWARDED = (
    "query",
    "index",
    "matcher",
    "count",
    "min_span",
    "rank_by",
    "paper",
    "mode",
    "k",
    "plot",
    "out",
    "exclude_self",
)


def socket_path(db: str | Path) -> Path:
    return Path(db).resolve() / SOCKET_NAME


#: options a client may omit (an older client): the CLI's defaults
_DEFAULTS = {"matcher": "search", "count": 10}
#: the JSON type of each forwarded option
_TYPES: dict[str, tuple[type, ...]] = {
    **{k: (str,) for k in ("query", "index", "matcher", "rank_by", "plot", "out", "mode", "exclude_self")},
    "count": (int,),
    "k": (int,),
    "min_span": (int, float),
    "paper": (bool,),
}
#: the least value of each numeric option (as the CLI's argparse types); upper bounds are the
#: components' own (a matcher's ``k``), checked when it is built from the options
_LEAST = {"count": 1, "k": 1, "min_span": 0}
#: seconds a client may take to send its request (a stalled one is dropped, never waited on)
REQUEST_TIMEOUT = 10.0
#: largest request accepted, bytes
MAX_REQUEST = 1 << 20
#: connections served at once (each reads its request in its own thread; searches run one at a time)
MAX_CLIENTS = 32


def _recv_all(conn: socket.socket, timeout: float | None = None, limit: int | None = None) -> bytes:
    """Everything the peer sends until it shuts down writing; ``timeout``: seconds in all
    (TimeoutError after), ``limit``: bytes (ValueError beyond)."""
    chunks: list[bytes] = []
    size = 0
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("request not received in time")
            conn.settimeout(left)
        b = conn.recv(1 << 16)
        if not b:
            return b"".join(chunks)
        size += len(b)
        if limit is not None and size > limit:
            raise ValueError(f"request larger than {limit} bytes")
        chunks.append(b)


def _request(raw: bytes) -> tuple[argparse.Namespace, Path]:
    """The options and working directory of a request; :class:`ConfigError` for a malformed
    one (not JSON, wrong shape, an option of the wrong type). An option an older client
    does not send takes the CLI's default."""
    from mocapflow.framework.bounded_json import JsonDepthError, loads
    from mocapflow.framework.errors import ConfigError

    try:
        req = loads(raw, max_depth=16)
    except JsonDepthError as exc:
        raise ConfigError(f"search server: malformed request ({exc}; expected one flat JSON object)") from None
    except ValueError:  # not UTF-8, not JSON
        raise ConfigError("search server: malformed request (expected one JSON object)") from None
    if not isinstance(req, dict) or not isinstance(req.get("args"), dict) or not isinstance(req.get("cwd"), str):
        raise ConfigError('search server: malformed request (expected {"args": {...}, "cwd": "..."})')
    vals = {}
    for k in _FORWARDED:
        v = req["args"].get(k)
        v = _DEFAULTS.get(k) if v is None else v
        if v is not None and (not isinstance(v, _TYPES[k]) or (isinstance(v, bool) and bool not in _TYPES[k])):
            want = " or ".join(t.__name__ for t in _TYPES[k])
            raise ConfigError(f"search server: request option {k!r}: expected {want}, got {v!r}")
        if k in _LEAST and v is not None and not (math.isfinite(float(v)) and float(v) >= _LEAST[k]):  # type: ignore[arg-type]
            raise ConfigError(f"search server: request option {k!r}: expected a number >= {_LEAST[k]}, got {v!r}")
        if isinstance(v, str) and "\x00" in v:
            raise ConfigError(f"search server: request option {k!r}: a NUL character in {v[:40]!r}")
        vals[k] = v
    if not vals["query"]:
        raise ConfigError("--query is required (except with --serve)")
    return argparse.Namespace(**vals), Path(req["cwd"])


def ask(args: argparse.Namespace, timeout: float | None = None) -> int | None:
    """Send the search of ``args`` to the workspace's server and print its answer.

    Returns the exit status, or ``None`` when no server answers (no socket, a stale one,
    or a server of another index step), so the caller searches itself.
    """
    path = socket_path(args.db)
    if not path.exists():
        return None
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.settimeout(1.0)  # connecting is instant for a live server; a dead one refuses
        s.connect(str(path))
        s.settimeout(timeout)
        req = {"args": {k: getattr(args, k, None) for k in _FORWARDED}, "cwd": os.getcwd()}
        s.sendall(json.dumps(req).encode())
        s.shutdown(socket.SHUT_WR)
        reply = json.loads(_recv_all(s).decode())
    except (OSError, ValueError):
        return None
    finally:
        s.close()
    if reply.get("rc") is None:  # the server declined (another --index): search here
        return None
    sys.stdout.write(reply.get("stdout", ""))
    sys.stdout.flush()
    sys.stderr.write(reply.get("stderr", ""))
    return int(reply["rc"])


def _handle(session_box: list[Any], raw: bytes, make_session: Callable[[], Any]) -> dict[str, Any]:
    """One request -> reply (errors become what the CLI would print, with its exit status)."""
    from mocapflow.framework.errors import ConfigError, MocapflowError, PluginError

    out, err = io.StringIO(), io.StringIO()
    try:
        args, cwd = _request(raw)
        if args.index and args.index != session_box[0].idx.step:
            return {"rc": None}
        if session_box[0].is_stale():
            session_box[0] = make_session()
        rc = session_box[0].answer(args, cwd, out, err)
    except MocapflowError as exc:
        print(f"mocapflow: error: {exc}", file=err)
        rc = 2 if isinstance(exc, (ConfigError, PluginError)) else 1
    except Exception as exc:  # a bug: the server goes on serving
        print(f"mocapflow: internal error: {type(exc).__name__}: {exc} (search server)", file=err)
        rc = 3
    return {"stdout": out.getvalue(), "stderr": err.getvalue(), "rc": rc}


def warm_up(session: Any) -> float:
    """Load the kernels a default search runs (one query cut from the database itself), the
    search space's block boxes and its subspace cells; returns the seconds it took."""
    import numpy as np

    t0 = time.perf_counter()
    args = argparse.Namespace(matcher="search", count=10, k=None, min_span=None, rank_by=None, paper=None)
    matcher = session.matcher(args)
    space = session.space(matcher)
    if space.features is not None and space.n_rows >= 30:
        matcher.match(np.array(space.features[:30]), space)
        from dataclasses import replace

        from .certified import DEFAULT_SETTINGS, certified_sdtw
        from .matcher_base import block_subspaces_of

        for size, p in zip(
            DEFAULT_SETTINGS.sizes(), DEFAULT_SETTINGS.bases(), strict=True
        ):  # the subspace cells a hard
            if p > 0:  # query switches on: built now
                block_subspaces_of(space, size, p)
        eager = replace(DEFAULT_SETTINGS, subspace_from=0.0)
        certified_sdtw(np.array(space.features[:30]), space, count=1, settings=eager)  # .. their kernel loaded
    try:  # a query file's path: forward kinematics and the feature set (a synthetic clip)
        from mocapflow.framework.synthetic import synthetic_motion

        session.feature_set().transform_motion(synthetic_motion(30))
    except Exception:  # a feature set that needs other joints: its kernels load on the first query
        pass
    return time.perf_counter() - t0


def _remove_stale_socket(path: Path) -> None:
    """Delete ``path`` only when it is a socket nobody answers on (left by a server that
    died); a live server, or anything that is not a socket, is a :class:`ConfigError`."""
    from mocapflow.framework.errors import ConfigError

    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(mode):
        raise ConfigError(
            f"--serve: {path} exists and is not a socket (a file of yours?); it is left as it is: "
            "move it away to start a search server"
        )
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(str(path))
    except OSError:
        path.unlink()  # left by a server that died
    else:
        raise ConfigError(f"--serve: a search server already answers on {path}")
    finally:
        probe.close()


def serve(args: argparse.Namespace, session_cls: Callable[..., Any]) -> int:
    """``mocapflow search --db WS --serve``: answer searches on ``WS/.search.sock`` with
    ``session_cls`` (:class:`~.search_command.SearchSession`, passed in: no import cycle)."""
    from mocapflow.framework.errors import ConfigError

    def make_session() -> Any:
        return session_cls(
            args.db,
            args.index,
            entry_points=not getattr(args, "no_entry_points", False),
            blocked=list(getattr(args, "block", None) or []),
        )

    path = socket_path(args.db)
    if len(str(path).encode()) > 88:  # sun_path holds 104-108 bytes, less the private suffix below
        raise ConfigError(f"--serve: socket path {path} is too long for a Unix socket; use a shorter workspace path")
    box = [make_session()]
    warm = warm_up(box[0])
    _remove_stale_socket(path)
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    # bound and listening under a private name, then renamed into place: a client that sees
    # the socket can always connect (bind-then-listen on the public name refused the early ones)
    pending = path.with_name(f"{path.name}.{os.getpid()}.{threading.get_ident() % 10**6}")
    old = os.umask(0o177)  # owner-only from the start, not chmod-ed after bind
    try:
        srv.bind(str(pending))
    finally:
        os.umask(old)
    try:
        srv.listen(128)  # a burst of clients waits in the backlog, never refused
        os.rename(pending, path)
    except BaseException:
        srv.close()
        with contextlib.suppress(OSError):
            pending.unlink()
        raise
    ino = path.stat().st_ino
    srv.settimeout(args.idle_timeout or None)
    print(
        f"mocapflow: search server on {path} ({box[0].idx.step!r}, warm in {warm:.2f} s); Ctrl-C stops it",
        file=sys.stderr,
        flush=True,
    )
    served = [0]
    lock = threading.Lock()  # one search at a time; requests are read concurrently
    slots = threading.BoundedSemaphore(MAX_CLIENTS)

    def serve_one(conn: socket.socket) -> None:
        try:
            with conn:
                try:
                    raw = _recv_all(conn, REQUEST_TIMEOUT, MAX_REQUEST)
                except (OSError, ValueError):  # stalled, gone or oversized: dropped, nobody waits
                    return
                with lock:
                    reply = _handle(box, raw, make_session)
                    served[0] += 1
                conn.settimeout(REQUEST_TIMEOUT)
                with contextlib.suppress(OSError):  # the client went away
                    conn.sendall(json.dumps(reply).encode())
        finally:
            slots.release()

    def stop(*_: object) -> NoReturn:
        raise KeyboardInterrupt

    import signal

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, signal.SIGINT):  # also when started in the background (SIGINT ignored)
            signal.signal(sig, stop)  # a service manager's stop cleans up as Ctrl-C does
    try:
        while True:
            try:
                conn, _ = srv.accept()
            except TimeoutError:
                print(f"mocapflow: search server idle for {args.idle_timeout:g} s: stopping", file=sys.stderr)
                break
            slots.acquire()
            threading.Thread(target=serve_one, args=(conn,), daemon=True).start()
    except KeyboardInterrupt:
        pass
    finally:
        srv.close()
        try:
            if path.stat().st_ino == ino:  # still ours (not a newer server's)
                path.unlink()
        except OSError:
            pass
    print(f"mocapflow: search server stopped after {served[0]} searches", file=sys.stderr)
    return 0
