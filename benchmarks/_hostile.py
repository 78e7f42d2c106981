"""Hostile inputs beyond mutated files, run by ``benchmarks/fuzz_parsers.py``: huge files,
YAML alias bombs, hostile plugins, symbolic links, concurrent and stalled search-server
clients, hostile search-server requests, hostile glTF/GLB/FBX files (one per class of
``tests/naive/hostile_scenes.py``), outputs aimed at a workspace through links, SQL queries
past their limits. Each check records its outcome (``ok`` or what went wrong), its wall time
and, for the readers, the peak of traced memory (scene files: the peak resident memory of the
process that read it); any outcome but ``ok`` is a failure.
"""

from __future__ import annotations

import argparse
import json
import socket
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

#: A file rejected at its header may cost at most this much memory (the issue's target).
HEADER_REJECT_MB = 200.0


def _peak(fn) -> tuple[Any, float, float]:
    """``(outcome of fn, seconds, peak traced MB)``."""
    tracemalloc.start()
    t0 = time.perf_counter()
    try:
        out = fn()
    finally:
        sec = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    return out, sec, peak


def _sparse(path: Path, size: int, head: bytes) -> Path:
    with open(path, "wb") as f:
        f.write(head)
        f.truncate(size)
    return path


def huge_files(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Sparse files of 300 MB and 2 GB per reader, with an invalid first byte or a valid
    header: each must be a ParseError naming the file, fast and in bounded memory."""
    from mocapflow.framework.errors import ParseError
    from mocapflow.plugins.formats.bvh import read_bvh
    from mocapflow.plugins.formats.trc import read_trc

    readers: dict[str, Any] = {"bvh": read_bvh, "trc": read_trc}
    heads = {"bvh": (b"\x00HIERARCHY\n", b"HIERARCHY\nROOT a\n"), "trc": (b"\x01Path", b"PathFileType\t4\n")}
    try:
        from mocapflow.plugins.formats.c3d import read_c3d

        readers["c3d"] = read_c3d
        heads["c3d"] = (b"\x02\x00", b"\x02\x50")
    except ImportError:  # pragma: no cover - the optional reader
        pass
    out = []
    for fmt, read in readers.items():
        for size in (300 * 2**20, 2 * 2**30):
            for valid, head in zip((False, True), heads[fmt], strict=True):
                if valid and size < 2**30:
                    continue  # a valid header within the limit is read (and refused later): not this class
                path = _sparse(tmp / f"huge.{fmt}", size, head)

                def go(path=path, read=read):
                    try:
                        read(path)
                    except ParseError as exc:
                        return "ok" if exc.path == str(path) else "error without the file"
                    return "accepted"

                outcome, sec, peak = _peak(go)
                path.unlink()
                if outcome == "ok" and peak > HEADER_REJECT_MB:
                    outcome = f"peak {peak:.0f} MB"
                if outcome == "ok" and sec > 10:
                    outcome = f"took {sec:.1f} s"
                what = f"{fmt} {size / 2**20:,.0f} MiB, {'valid header' if valid else 'invalid first byte'}"
                out.append(("huge file", f"{what}: {outcome}", sec, peak))
    return out


def alias_bombs(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Nested anchors of 3 to 9 levels (9**9 values from ~1 kB): a ConfigError naming
    file and line, fast."""
    from mocapflow.framework.config import load_pipeline
    from mocapflow.framework.errors import ConfigError

    out = []
    for levels in (3, 6, 9):
        lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
        lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, levels)]
        lines.append(f"name: bomb\nsteps:\n  s: {{uses: analyses.summary, with: {{n: *a{levels - 1}}}}}")
        p = tmp / "bomb.yaml"
        p.write_text("\n".join(lines) + "\n")

        def go(p=p, levels=levels):
            try:
                load_pipeline(p)
            except ConfigError as exc:
                expands = 9**levels > 100_000
                if expands:
                    return "ok" if "bomb.yaml:" in str(exc) and "expand" in str(exc) else f"other error: {exc}"
                return "ok"  # small expansions: refused for another reason (unknown parameter) is fine
            return "ok" if 9**levels <= 100_000 else "accepted"

        outcome, sec, peak = _peak(go)
        if outcome == "ok" and sec > 10:
            outcome = f"took {sec:.1f} s"
        out.append(("alias bomb", f"{levels} levels, {p.stat().st_size} bytes: {outcome}", sec, peak))
    return out


def hostile_plugins(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Plugins raising Exception, SystemExit or KeyboardInterrupt in a registration or a
    lifecycle hook: recorded as that plugin's failure (registration) or a PluginError naming
    it (lifecycle), never ending the process."""
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.errors import PluginError
    from mocapflow.framework.plugins import build_registries, call_lifecycle, hookimpl

    out = []
    for exc in (RuntimeError("boom"), SystemExit(3), KeyboardInterrupt()):

        class Register:
            @hookimpl
            def register_analyses(self, exc=exc):
                raise exc

        class Lifecycle:
            @hookimpl
            def before_step(self, step_id, component, workspace, exc=exc):
                raise exc

        t0 = time.perf_counter()
        try:
            pm = get_plugin_manager(entry_points=False, extra=[Register()])
            build_registries(pm)
            got = [f for f in pm.failures if type(exc).__name__ in f.error]
            outcome = "ok" if got else "not recorded"
            pm = get_plugin_manager(builtins=False, entry_points=False)
            pm.register(Lifecycle(), name="hostile")
            try:
                call_lifecycle(pm.hook, "before_step", step_id="s", component=None, workspace=str(tmp))
                outcome = "lifecycle error swallowed"
            except PluginError as err:
                outcome = outcome if "'hostile'" in str(err) else "plugin not named"
        except BaseException as escaped:  # what this check looks for
            outcome = f"escaped: {type(escaped).__name__}"
        out.append(("hostile plugin", f"{type(exc).__name__}: {outcome}", time.perf_counter() - t0, 0.0))
    return out


def symlinks(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Output paths reaching a dataset through a link, and report assets that are links
    (to a file outside, to a folder): refused or skipped."""
    from mocapflow.framework.errors import ConfigError
    from mocapflow.framework.output_paths import refuse_dataset_path
    from mocapflow.framework.workspace import MANIFEST
    from mocapflow.plugins.report.model import owned_file

    ws = tmp / "ws"
    step = ws / "step"
    step.mkdir(parents=True)
    (step / MANIFEST).write_text("{}")
    (tmp / "secret").write_text("x")
    (tmp / "to_step").symlink_to(step, target_is_directory=True)
    (step / "leak.png").symlink_to(tmp / "secret")
    (step / "dir").symlink_to(tmp, target_is_directory=True)
    (step / "real.png").write_bytes(b"png")
    out = []
    t0 = time.perf_counter()
    for target in (tmp / "to_step" / "data.parquet", step / "data.parquet", ws / ".." / "ws" / "step" / "x.csv"):
        try:
            refuse_dataset_path(target, "--out")
            outcome = "accepted"
        except ConfigError:
            outcome = "ok"
        out.append(("symlink", f"output {target.relative_to(tmp)}: {outcome}", time.perf_counter() - t0, 0.0))
    for name, want in (("leak.png", False), ("dir/secret", False), ("real.png", True)):
        got = owned_file(step, step / name)
        out.append(("symlink", f"report asset {name}: {'ok' if got == want else 'wrong'}", 0.0, 0.0))
    return out


class _Session:
    idx = argparse.Namespace(step="index")

    def is_stale(self) -> bool:
        return False

    def answer(self, args, cwd, out, err) -> int:
        time.sleep(0.01)  # a search
        print("match", file=out)
        return 0


def concurrent_clients(tmp: Path, stalled: int = 8, good: int = 16) -> list[tuple[str, str, float, float]]:
    """A search server (a stand-in session: the protocol and the threads are what is
    measured) with ``stalled`` clients that never finish their request and ``good`` clients
    asking at once: every good one answered, the slowest within 5 s."""
    from mocapflow.plugins.similarity.search import search_server as srv

    real_warm = srv.warm_up
    srv.warm_up = lambda s: 0.0
    sock = tmp / srv.SOCKET_NAME
    args = argparse.Namespace(db=str(tmp), index=None, idle_timeout=2.0, no_entry_points=True, block=[])
    server = threading.Thread(target=srv.serve, args=(args, lambda *a, **k: _Session()), daemon=True)
    server.start()
    try:
        for _ in range(200):
            if sock.exists():
                break
            time.sleep(0.05)
        hold = []
        for _ in range(stalled):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(str(sock))
            s.sendall(b'{"args": ')
            hold.append(s)
        took: list[float] = []
        answers: list[bool] = []

        def ask() -> None:
            t0 = time.perf_counter()
            c = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            c.settimeout(30)
            c.connect(str(sock))
            c.sendall(json.dumps({"args": {"query": "q.bvh"}, "cwd": str(tmp)}).encode())
            c.shutdown(socket.SHUT_WR)
            reply = json.loads(srv._recv_all(c).decode())
            c.close()
            took.append(time.perf_counter() - t0)
            answers.append(reply.get("rc") == 0)

        threads = [threading.Thread(target=ask) for _ in range(good)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        for s in hold:
            s.close()
        worst = max(took) if took else float("inf")
        ok = len(answers) == good and all(answers) and worst < 5.0
        outcome = "ok" if ok else f"{sum(answers)} of {good} answered, slowest {worst:.1f} s"
        server.join(10)
        return [("concurrent clients", f"{stalled} stalled + {good} at once: {outcome}", worst, 0.0)]
    finally:
        srv.warm_up = real_warm


#: Peak resident memory of a fresh process reading one hostile scene file (imports
#: included), and of one refusing an invalid 900 MiB file (the issue's targets).
SCENE_PEAK_MB = 300.0
SCENE_SECONDS = 10.0

_CHILD = r"""
import json, os, resource, sys, time
sys.path[:0] = [{tests!r}]
from pathlib import Path
import mocapflow
from mocapflow.framework.errors import ParseError
mocapflow.read(Path({tests!r}) / "data" / "blender" / "jump_60.glb")  # lazy imports before recording
mocapflow.read(Path({tests!r}) / "data" / "blender" / "walk_120.fbx")
try:
    import c3d  # the optional C3D reader's package, imported lazily: before recording
except ImportError:
    pass
folder = Path(sys.argv[1]).resolve()
opened = []
def audit(event, args):
    if event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
        p = os.path.realpath(os.fsdecode(args[0]))
        if not p.startswith(str(folder) + os.sep):
            opened.append(p)
sys.addaudithook(audit)
t0 = time.perf_counter()
try:
    mocapflow.read(sys.argv[2])
    out = {{"outcome": "accepted"}}
except ParseError as exc:
    out = {{"outcome": "refused", "path": exc.path, "message": exc.message}}
except BaseException as exc:
    out = {{"outcome": "crash", "message": f"{{type(exc).__name__}}: {{exc}}"[:300]}}
out["sec"] = time.perf_counter() - t0
out["outside"] = opened[:5]
# VmHWM: this process image's own peak (ru_maxrss keeps the forking parent's across exec)
hwm = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM:")]
out["rss_mb"] = int(hwm[0].split()[1]) / 1024 if hwm else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def scene_files(tmp: Path, cases: list | None = None) -> list[tuple[str, str, float, float]]:
    """The hostile glTF/GLB/FBX classes of ``tests/naive/hostile_scenes.py`` (uris out of
    the folder, FIFOs, devices, big sidecars, declared sizes, nested JSON, deep and wide
    node trees, far keys, zlib bombs, 900 MiB files with an invalid header): each read by
    a fresh process (``mocapflow.read``, imports warmed) that audits every file opened.
    A check passes when the file is refused with a ParseError naming it and matching the
    class, within :data:`SCENE_SECONDS`, at most :data:`SCENE_PEAK_MB` peak resident
    memory (:data:`HEADER_REJECT_MB` for the 900 MiB files) and nothing opened outside the
    case's folder. The last column is the process's peak RSS, not traced memory."""
    import re
    import subprocess
    import sys

    tests = Path(__file__).resolve().parent.parent / "tests"
    sys.path.insert(0, str(tests))
    from naive import hostile_scenes as hs

    child = _CHILD.format(tests=str(tests))
    makers = cases if cases is not None else hs.GLTF_CASES + hs.FBX_CASES + hs.BIG_CASES
    out = []
    for k, make in enumerate(makers):
        folder = tmp / f"scene{k}" / "case"
        folder.mkdir(parents=True)
        case = make(folder)
        try:
            proc = subprocess.run(
                [sys.executable, "-c", child, str(folder), str(case.path)],
                capture_output=True,
                text=True,
                timeout=60,
            )
            res = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.stdout.strip() else None
        except subprocess.TimeoutExpired:
            res = {"outcome": "hang", "sec": 60.0, "rss_mb": 0.0, "outside": []}
        finally:
            if case.big:
                for f in folder.iterdir():
                    if f.is_file() and not f.is_symlink() and f.stat().st_size > 2**27:
                        f.unlink()
        if res is None:
            outcome, res = f"child died: {proc.stderr.strip()[-200:]}", {"sec": 0.0, "rss_mb": 0.0}
        elif res["outside"]:
            outcome = f"opened outside its folder: {res['outside']}"
        elif res["outcome"] != "refused":
            outcome = f"{res['outcome']} {res.get('message', '')}"
        elif res["path"] != str(case.path) or not re.search(case.expect, res["message"]):
            outcome = f"other error: {res['message'][:160]}"
        elif res["sec"] > SCENE_SECONDS:
            outcome = f"took {res['sec']:.1f} s"
        elif res["rss_mb"] > (HEADER_REJECT_MB if case.big else SCENE_PEAK_MB):
            outcome = f"peak {res['rss_mb']:.0f} MB"
        else:
            outcome = "ok"
        out.append(("scene file", f"{case.name}: {outcome}", res["sec"], res["rss_mb"]))
    return out


def server_requests(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Hostile search-server requests (100,000-deep JSON, huge integers, bytes that are not
    UTF-8): a ConfigError answered with exit status 2, never an internal error."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    from naive import hostile_scenes as hs

    from mocapflow.plugins.similarity.search.search_server import _handle

    out = []
    for name, raw, valid in hs.server_requests():

        def go(raw=raw, valid=valid):
            reply = _handle([_Session()], raw, lambda: _Session())
            if valid:
                return "ok" if reply["rc"] == 0 else f"refused: {reply['stderr'][:100]}"
            return "ok" if reply["rc"] == 2 and "internal" not in reply["stderr"] else f"rc {reply['rc']}"

        outcome, sec, peak = _peak(go)
        out.append(("server request", f"{name}: {outcome}", sec, peak))
    return out


def _toy_workspace(tmp: Path) -> Path:
    import textwrap

    from toy_components import ToyPlugin

    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import run_pipeline

    pipe = tmp / "p.yaml"
    pipe.write_text(
        textwrap.dedent("""
        name: toy
        workspace: ws
        steps:
          motions: {uses: analyses.toy_motions, with: {clips: 2, frames: 20}}
          summary: {uses: analyses.clip_summary, input: motions}
        """)
    )
    run_pipeline(pipe, pm=get_plugin_manager(entry_points=False, extra=[ToyPlugin()]))
    return tmp / "ws"


def _digest(ws: Path) -> dict[str, str]:
    import hashlib

    return {str(p.relative_to(ws)): hashlib.sha256(p.read_bytes()).hexdigest() for p in ws.rglob("*") if p.is_file()}


def output_links(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Every writing command aimed at a workspace through another name: a hard link to a
    dataset file, a symbolic link on the path, a folder holding a link into a step folder.
    Each must be refused (exit 2) with the workspace byte-identical (SHA-256 of every file)."""
    import contextlib
    import io

    from mocapflow.framework.cli import main

    ws = _toy_workspace(tmp)
    hard = tmp / "hard.bvh"
    hard.hardlink_to(ws / "summary" / "data.parquet")
    (tmp / "mid").symlink_to(ws / "summary", target_is_directory=True)
    folder = tmp / "folder"
    folder.mkdir()
    (folder / "index.csv").symlink_to(ws / "summary" / "data.parquet")
    (folder / "q0").symlink_to(ws / "motions", target_is_directory=True)
    take = tmp / "take.trc"
    take.write_text("not read: the output is refused first")
    cmds = {
        "sql -o hard link": ["sql", str(ws), "SELECT 1", "--format", "csv", "-o", str(hard)],
        "sql -o through a link": ["sql", str(ws), "SELECT 1", "--format", "csv", "-o", str(tmp / "mid" / "x.csv")],
        "export -o folder with links": ["export", str(ws), "--step", "summary", "-o", str(folder)],
        "report -o folder with links": ["report", str(ws), "-o", str(folder)],
        "clean --output hard link": ["clean", str(take), "--output", str(hard)],
        "clean --report folder with links": [
            "clean",
            str(take),
            "--output",
            str(tmp / "c.bvh"),
            "--report",
            str(folder),
        ],
        "reconstruct -o hard link": ["reconstruct", str(take), "--prior", str(tmp), "-o", str(hard)],
        "reconstruct -o through a link": [
            "reconstruct",
            str(take),
            "--prior",
            str(tmp),
            "-o",
            str(tmp / "mid" / "a.bvh"),
        ],
    }
    out = []
    for what, argv in cmds.items():
        before = _digest(ws)
        err = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            rc = main(["--no-entry-points", *argv])
        sec = time.perf_counter() - t0
        same = _digest(ws) == before
        ok = rc == 2 and same and "internal error" not in err.getvalue()
        out.append(("output link", f"{what}: {'ok' if ok else f'exit {rc}, workspace changed: {not same}'}", sec, 0.0))
    return out


def sql_limits(tmp: Path) -> list[tuple[str, str, float, float]]:
    """Queries past ``--timeout 10 --memory-limit 500MB`` as a user runs them (a fresh
    process): each ended within timeout + 5 s at a peak <= limit + 500 MB, the message naming
    the limit."""
    import resource
    import subprocess
    import sys

    ws = _toy_workspace(tmp)
    queries = {
        "SELECT length(repeat('x', 2000000000))": "memory",
        "SELECT list(repeat('x', 1000)) FROM range(10000000)": "memory",
        "SELECT count(*) FROM range(10000000000000)": "longer than",
    }
    out = []
    for q, want in queries.items():
        cmd = [sys.executable, "-m", "mocapflow", "sql", str(ws), q, "--timeout", "10", "--memory-limit", "500MB"]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
        sec = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest child so far
        ok = r.returncode == 1 and want in r.stderr and sec <= 15 and peak <= 1000
        out.append(("sql limit", f"{q[:50]}: {'ok' if ok else r.stderr.strip()[-120:]}", sec, peak))
    return out


def run_all(tmp: Path, echo=print, quick: bool = False) -> int:
    """Every class; prints one line per check, returns the number of failures. ``quick``:
    the scene files of five representative classes only (a process each)."""
    rows = []
    for fn in (
        huge_files,
        alias_bombs,
        hostile_plugins,
        symlinks,
        concurrent_clients,
        server_requests,
        scene_files,
        output_links,
        sql_limits,
    ):
        if fn is sql_limits and quick:  # 3 queries run to their 10 s limits: benchmarks/sql_limits.py
            continue
        sub = tmp / fn.__name__
        sub.mkdir()
        if fn is scene_files and quick:
            from naive import hostile_scenes as hs

            rows += fn(sub, [hs.uri_etc_passwd, hs.uri_fifo, hs.json_nested, hs.fbx_array_bomb, hs.huge_invalid("glb")])
        else:
            rows += fn(sub)
    bad = 0
    echo(f"\n{'hostile input':<20} {'seconds':>8} {'peak MB':>8}  check")
    for cls, what, sec, peak in rows:
        ok = what.endswith(": ok")
        bad += not ok
        echo(f"{cls:<20} {sec:>8.2f} {peak:>8.1f}  {what}{'' if ok else '   <-- FAILURE'}")
    echo(f"hostile inputs: {len(rows)} checks, {bad} failures")
    return bad
