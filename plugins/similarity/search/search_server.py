"""The search server of ``mocapflow search --serve`` and the client side of ``mocapflow search``.

A fresh Python process pays a fixed cost before the first match (measured at 1 M frames,
docs/knn.md): importing NumPy, pyarrow, pydantic and numba, loading the cached numba
kernels, building the registries. The server pays it once: it holds one
:class:`~.search_command.SearchSession` (index memory-mapped, kernels loaded, block boxes
computed) and answers each request on the Unix socket ``WORKSPACE/.search.sock``.

Protocol: one JSON object per connection each way. Request ``{"args": {...}, "cwd": ...}``
(the command's options; relative paths are resolved against the client's working
directory), reply ``{"stdout": ..., "stderr": ..., "rc": ...}``, printed by the client as
if it had searched itself. The client (:func:`ask`) imports only the standard library. The
server answers one request at a time, rebuilds its session when the workspace's index,
features or motions step was recomputed, and removes its socket when it stops. The socket
is made owner-only (0600): the workspace's owner is the only client.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import socket
import sys
import time
from pathlib import Path

SOCKET_NAME = ".search.sock"
# request options the server takes from the client (the rest: its own plugin selection)
_FORWARDED = ("query", "index", "matcher", "count", "min_span", "rank_by", "paper", "k", "plot", "out", "exclude_self")


def socket_path(db: str | Path) -> Path:
    return Path(db).resolve() / SOCKET_NAME


def _recv_all(conn: socket.socket) -> bytes:
    chunks = []
    while True:
        b = conn.recv(1 << 16)
        if not b:
            return b"".join(chunks)
        chunks.append(b)


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


def _handle(session_box: list, raw: bytes, make_session) -> dict:
    """One request -> reply (errors become what the CLI would print, with its exit status)."""
    from mocapflow.framework.errors import ConfigError, MocapflowError, PluginError

    out, err = io.StringIO(), io.StringIO()
    try:
        req = json.loads(raw.decode())
        # an option the client did not send (an older client) is unset
        args = argparse.Namespace(**{k: req["args"].get(k) for k in _FORWARDED})
        if args.index and args.index != session_box[0].idx.step:
            return {"rc": None}
        if session_box[0].is_stale():
            session_box[0] = make_session()
        rc = session_box[0].answer(args, Path(req["cwd"]), out, err)
    except MocapflowError as exc:
        print(f"mocapflow: error: {exc}", file=err)
        rc = 2 if isinstance(exc, (ConfigError, PluginError)) else 1
    except Exception as exc:  # a bug: the server goes on serving
        print(f"mocapflow: internal error: {type(exc).__name__}: {exc} (search server)", file=err)
        rc = 3
    return {"stdout": out.getvalue(), "stderr": err.getvalue(), "rc": rc}


def warm_up(session) -> float:
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


def serve(args: argparse.Namespace, session_cls) -> int:
    """``mocapflow search --db WS --serve``: answer searches on ``WS/.search.sock`` with
    ``session_cls`` (:class:`~.search_command.SearchSession`, passed in: no import cycle)."""
    from mocapflow.framework.errors import ConfigError

    def make_session():
        return session_cls(
            args.db,
            args.index,
            entry_points=not getattr(args, "no_entry_points", False),
            blocked=list(getattr(args, "block", None) or []),
        )

    path = socket_path(args.db)
    if len(str(path).encode()) > 100:  # sun_path holds 104-108 bytes
        raise ConfigError(f"--serve: socket path {path} is too long for a Unix socket; use a shorter workspace path")
    box = [make_session()]
    warm = warm_up(box[0])
    if path.exists():
        probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            probe.connect(str(path))
            raise ConfigError(f"--serve: a search server already answers on {path}")
        except OSError:
            path.unlink()  # left by a server that died
        finally:
            probe.close()
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    old = os.umask(0o177)  # owner-only from the start, not chmod-ed after bind
    try:
        srv.bind(str(path))
    finally:
        os.umask(old)
    ino = path.stat().st_ino
    srv.listen(16)
    srv.settimeout(args.idle_timeout or None)
    print(
        f"mocapflow: search server on {path} ({box[0].idx.step!r}, warm in {warm:.2f} s); Ctrl-C stops it",
        file=sys.stderr,
        flush=True,
    )
    served = 0

    def stop(*_):
        raise KeyboardInterrupt

    import signal
    import threading

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
            with conn:
                conn.settimeout(30.0)
                try:
                    reply = _handle(box, _recv_all(conn), make_session)
                    conn.sendall(json.dumps(reply).encode())
                except OSError:  # the client went away
                    continue
            served += 1
    except KeyboardInterrupt:
        pass
    finally:
        srv.close()
        try:
            if path.stat().st_ino == ino:  # still ours (not a newer server's)
                path.unlink()
        except OSError:
            pass
    print(f"mocapflow: search server stopped after {served} searches", file=sys.stderr)
    return 0
