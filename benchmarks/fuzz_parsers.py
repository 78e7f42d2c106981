"""Mutational fuzzer of the format readers on excerpts of the real corpus.

Each case takes the first frames of a real AMC (with its ASF), BVH or TRC file from
``../shared/data`` (or a whole small C3D file when the optional ``c3d`` package is
installed), applies one mutation (truncations, byte flips, inserted control bytes,
NaN/inf/1e308, CR/LF/CRLF mixes, BOMs, runs of blanks, wrong value counts, duplicated,
deleted and swapped lines, duplicated/undefined bones, huge lines, header values) and
checks the reader against the slow reference readers of ``tests/naive/readers.py``
(engine: ``tests/naive/fuzz.py``). Every case runs under a timeout in one of at most two
worker processes (``nice``); a case past it is a hang, its worker is replaced.

Prints the cases, crashes (exceptions other than ParseError), hangs, wrong acceptances,
wrong rejections and bad errors (no file or line), per mutation kind and per format, and
the first examples of each failure. Then the hostile inputs of ``benchmarks/_hostile.py``
(huge files, YAML alias bombs, hostile plugins, symbolic links, stalled and concurrent
search-server clients, outputs through links into a workspace, SQL past its limits), one line
per check; then the labels CSV and search-server request fuzzers of
``benchmarks/_fuzz_inputs.py`` (``--labels-cases``, ``--server-cases``). Exit status 1 if any
failure.

Usage::

    python benchmarks/fuzz_parsers.py                # 100,000 cases, seed 0
    python benchmarks/fuzz_parsers.py --quick        # 100 cases on the bundled examples/data (AMC, BVH; C3D, TRC with the corpus)
    python benchmarks/fuzz_parsers.py --cases N --seed S --jobs 2 --timeout 20

The scene formats (glTF, GLB, binary FBX) are fuzzed too (``--scene-cases``, default a tenth
of ``--cases``) by ``benchmarks/_fuzz_scenes.py`` on the Blender-made files of ``tests/data/blender``.
"""

from __future__ import annotations

import argparse
import contextlib
import multiprocessing as mp
import os
import resource
import shutil
import signal
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from _fuzz_scenes import FAILURES, fuzz_scenes, hwm_mb

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("MOCAPFLOW_DATA", ROOT.parent / "shared" / "data"))
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

#: Share of cases per format (C3D values checked against the c3d package when installed).
WEIGHTS = {"amc": 0.42, "bvh": 0.28, "trc": 0.25, "c3d": 0.05}
C3D_KINDS = ("truncate", "byte_flip", "control_byte")


class Cases:
    """Case ``i`` of a seed, reproducible on its own: ``(fmt, kind, base, data, asf)``."""

    def __init__(self, seed: int) -> None:
        from naive import fuzz

        self.fuzz = fuzz
        self.seed = seed
        self.sources = fuzz.corpus_sources(Path(os.environ.get("MOCAPFLOW_FUZZ_DATA", DATA)), True)
        w = np.array([WEIGHTS[f] for f in self.sources])
        self.formats, self.weights = list(self.sources), w / w.sum()
        self._loaded: dict[Path, tuple] = {}

    def make(self, i: int):
        rng = np.random.default_rng([self.seed, i])
        fmt = self.formats[int(rng.choice(len(self.formats), p=self.weights))]
        path = self.sources[fmt][int(rng.integers(0, len(self.sources[fmt])))]
        if path not in self._loaded:
            self._loaded[path] = self.fuzz.load_source(fmt, path)
        data, asf, asf_name = self._loaded[path]
        kinds = C3D_KINDS if fmt == "c3d" else self.fuzz.KINDS
        kind = kinds[int(rng.integers(0, len(kinds)))]
        if fmt == "c3d":
            base = self.fuzz.Base(fmt, path.name, data)
        else:
            base = self.fuzz.excerpt(fmt, path.name, data, rng, asf, asf_name)
        new, new_asf = self.fuzz.mutate(kind, base, rng)
        return fmt, kind, base, new, new_asf, path


def _worker(seed: int, indices: list[int], conn, slot, folder: str) -> None:
    os.nice(max(0, 10 - os.nice(0)))  # at least nice 10; not more when started with `nice -n 10`
    cases = Cases(seed)
    fuzz = cases.fuzz
    refs: dict[tuple, dict | None] = {}
    for i in indices:
        slot[0], slot[1] = i, time.time()
        try:
            fmt, kind, base, data, asf, src = cases.make(i)
            reference = None
            if kind in fuzz.SAME:
                key = (base.fmt, base.name, base.data)
                if key not in refs:
                    try:
                        p = fuzz.write_case(Path(folder) / "ref", base, base.data, base.asf)
                        refs.clear()
                        refs[key] = fuzz.arrays(fuzz.read(base.fmt, p))
                    except Exception:
                        refs[key] = None
                reference = refs[key]
            outcome, detail = fuzz.check(Path(folder) / "case", base, kind, data, asf, reference)
        except Exception as exc:
            fmt, kind, src = "?", "?", Path("?")
            outcome, detail = "fuzzer_error", f"{type(exc).__name__}: {exc}"
        conn.send((i, fmt, kind, outcome, detail, src.name))
    slot[0] = -1
    conn.send(None)


def run(n_cases: int, seed: int, jobs: int, timeout: float, echo=print) -> dict:
    """Run cases ``0..n_cases-1``; returns the counts and examples."""
    ctx = mp.get_context("fork" if sys.platform != "win32" else "spawn")
    todo = list(range(n_cases))
    parts = [todo[w::jobs] for w in range(jobs)]
    counts: Counter = Counter()
    by_kind: dict[str, Counter] = defaultdict(Counter)
    by_fmt: dict[str, Counter] = defaultdict(Counter)
    examples: dict[str, list[str]] = defaultdict(list)
    done = 0
    t0 = time.time()
    shm = Path("/dev/shm")  # a RAM file system when there is one: each case writes and reads files
    with tempfile.TemporaryDirectory(prefix="mocapflow-fuzz-", dir=shm if shm.is_dir() else None) as tmp:
        workers: list[dict] = []

        def start(w: int, indices: list[int]) -> None:
            parent, child = ctx.Pipe(duplex=False)
            slot = ctx.Array("d", [-1.0, time.time()], lock=False)
            p = ctx.Process(
                target=_worker, args=(seed, indices, child, slot, f"{tmp}/w{w}-{len(workers)}"), daemon=True
            )
            p.start()
            child.close()
            workers.append({"p": p, "conn": parent, "slot": slot, "indices": indices, "alive": True})

        def record(i: int, fmt: str, kind: str, outcome: str, detail: str, src: str) -> None:
            nonlocal done
            done += 1
            counts[outcome] += 1
            by_kind[kind][outcome] += 1
            by_fmt[fmt][outcome] += 1
            if outcome not in ("accepted", "rejected") and len(examples[outcome]) < 8:
                examples[outcome].append(f"case {i} ({fmt} {src}, {kind}): {detail}")

        try:
            _supervise(workers, start, record, parts, seed, timeout, n_cases, echo, t0, lambda: done)
        finally:  # workers first: they write into the case folder that is removed next
            for wk in workers:
                if wk["p"].is_alive():
                    wk["p"].kill()
                wk["p"].join()
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {
        "cpu": cpu.ru_utime + cpu.ru_stime,
        "counts": counts,
        "by_kind": by_kind,
        "by_fmt": by_fmt,
        "examples": examples,
        "cases": done,
        "seconds": time.time() - t0,
    }


def _supervise(workers, start, record, parts, seed, timeout, n_cases, echo, t0, done) -> None:
    """Start the workers, collect their results, replace a worker whose case runs past
    ``timeout`` (a hang) or that dies."""
    for w, part in enumerate(parts):
        start(w, part)
    last_echo = time.time()
    while any(wk["alive"] for wk in workers):
        for wk in workers:
            if not wk["alive"]:
                continue
            while wk["conn"].poll():
                try:
                    msg = wk["conn"].recv()
                except EOFError:
                    msg = None
                if msg is None:
                    wk["alive"] = False
                    break
                record(*msg)
            if wk["alive"] and wk["slot"][0] >= 0 and time.time() - wk["slot"][1] > timeout:
                i = int(wk["slot"][0])
                wk["p"].kill()
                wk["p"].join()
                wk["alive"] = False
                fmt, kind = "?", "?"
                with contextlib.suppress(Exception):
                    fmt, kind = Cases(seed).make(i)[:2]
                record(i, fmt, kind, "hang", f"no result after {timeout:g} s", "")
                rest = wk["indices"][wk["indices"].index(i) + 1 :]
                if rest:
                    start(len(workers), rest)
            elif wk["alive"] and not wk["p"].is_alive() and not wk["conn"].poll():
                wk["alive"] = False  # died without a word (killed for memory...)
                i = int(wk["slot"][0])
                record(i, "?", "?", "crash", f"worker died (exit {wk['p'].exitcode})", "")
                rest = wk["indices"][wk["indices"].index(i) + 1 :] if i >= 0 else []
                if rest:
                    start(len(workers), rest)
        if time.time() - last_echo > 30:
            n = done()
            echo(f"  ... {n:,} / {n_cases:,} cases ({n / (time.time() - t0):,.0f}/s)")
            last_echo = time.time()
        time.sleep(0.02)


def report(res: dict, echo=print) -> int:
    c = res["counts"]
    echo(
        f"cases {res['cases']:,} in {res['seconds']:.0f} s: accepted {c['accepted']:,}, rejected (ParseError) "
        f"{c['rejected']:,}"
    )
    per = res["cpu"] / max(res["cases"], 1)
    echo(
        f"worker CPU {res['cpu']:.0f} s ({1000 * per:.1f} ms per case; on two idle cores 100,000 cases would take "
        f"{per * 100_000 / 2 / 60:.0f} min)"
    )
    echo(
        "crashes {crash}, hangs {hang}, wrong acceptances {wrong_accept}, wrong rejections {wrong_reject}, "
        "bad errors {bad_error}, fuzzer errors {fuzzer_error}".format(**{k: c[k] for k in (*FAILURES, "fuzzer_error")})
    )
    cols = ("accepted", "rejected", *FAILURES)
    for title, table in (("mutation kind", res["by_kind"]), ("format", res["by_fmt"])):
        echo(f"\n{title:<16}" + "".join(f"{k:>13}" for k in cols))
        for key in sorted(table):
            echo(f"{key:<16}" + "".join(f"{table[key][k]:>13,}" for k in cols))
    for outcome, lines in res["examples"].items():
        echo(f"\nfirst {outcome} cases:")
        for ln in lines:
            echo("  " + ln)
    return int(any(c[k] for k in (*FAILURES, "fuzzer_error")))


REQUEST_KINDS = ("truncate", "byte_flip", "insert", "nest", "value", "duplicate")


def fuzz_requests(n_cases: int, seed: int, echo=print) -> int:
    """Fuzz the search server's request parsing (``search_server._request``, the bounded
    JSON loader): valid requests mutated (truncations, byte flips, inserted bytes and
    brackets, deep nesting, values of other types and sizes). Each must parse or raise
    ConfigError; anything else is a crash, over 10 s a hang."""
    import json

    from mocapflow.framework.errors import ConfigError
    from mocapflow.plugins.similarity.search.search_server import _request

    bases = [
        {"args": {"query": "q.bvh"}, "cwd": "/tmp"},
        {"args": {"query": "a b.bvh", "k": 5, "count": 3, "min_span": 0.5, "paper": True, "plot": "x.png"}, "cwd": "/"},
        {"args": {"query": "q.fbx", "index": "idx", "matcher": "search", "rank_by": "cost"}, "cwd": "/w"},
    ]
    counts: Counter = Counter()
    by_kind: dict[str, Counter] = defaultdict(Counter)
    examples: list[str] = []
    t0 = time.time()
    slowest = 0.0
    values = [None, -1, 10**9, 2**70, 1e308, "", "x" * 1000, [], {}, True, [[[[]]]], "[" * 1000]
    for i in range(n_cases):
        rng = np.random.default_rng([seed, 11, i])
        base = bases[int(rng.integers(0, len(bases)))]
        raw = json.dumps(base).encode()
        kind = REQUEST_KINDS[int(rng.integers(0, len(REQUEST_KINDS)))]
        at = int(rng.integers(0, len(raw)))
        if kind == "truncate":
            raw = raw[:at]
        elif kind == "byte_flip":
            b = bytearray(raw)
            for _ in range(int(rng.integers(1, 6))):
                b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
            raw = bytes(b)
        elif kind == "insert":
            ins = rng.choice(
                [b"[", b"]", b"{", b"}", b'"', b"\\", b",", b":", b"\x00", b"\xff"], int(rng.integers(1, 50))
            )
            raw = raw[:at] + b"".join(ins) + raw[at:]
        elif kind == "nest":
            d = int(rng.choice([10, 17, 100, 10_000, 200_000]))
            raw = raw[:-1] + b', "x": ' + b"[" * d + b"]" * d + b"}"
        elif kind == "value":
            req = json.loads(raw)
            key = list(req["args"])[int(rng.integers(0, len(req["args"])))]
            req["args"][key] = values[int(rng.integers(0, len(values)))]
            raw = json.dumps(req).encode()
        else:
            raw = raw[: at + 8] + raw[at:]
        t1 = time.perf_counter()
        try:
            _request(raw)
            outcome = "accepted"
        except ConfigError:
            outcome = "rejected"
        except Exception as exc:
            outcome = "crash"
            if len(examples) < 5:
                examples.append(f"case {i} ({kind}): {type(exc).__name__}: {str(exc)[:120]}")
        took = time.perf_counter() - t1
        slowest = max(slowest, took)
        if took > 10:
            outcome = "hang"
        counts[outcome] += 1
        by_kind[kind][outcome] += 1
    echo(
        f"\nsearch-server requests: {n_cases:,} cases in {time.time() - t0:.0f} s: accepted {counts['accepted']:,}, "
        f"rejected (ConfigError) {counts['rejected']:,}; crashes {counts['crash']}, hangs {counts['hang']}; slowest "
        f"{slowest * 1000:.1f} ms; peak RSS {hwm_mb():.0f} MB"
    )
    for kind in REQUEST_KINDS:
        echo(f"  {kind:<10}" + "".join(f"{k:>10} {by_kind[kind][k]:>7,}" for k in ("accepted", "rejected", "crash")))
    for ln in examples:
        echo("  " + ln)
    return int(counts["crash"] + counts["hang"] > 0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="100 cases on examples/data")
    ap.add_argument("--cases", type=int, default=None, help="number of cases (default 100,000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2, help="worker processes (at most 2: the machine is shared)")
    ap.add_argument("--timeout", type=float, default=20.0, help="seconds per case before it counts as a hang")
    ap.add_argument("--scene-cases", type=int, default=None, help="glTF/GLB/FBX cases (default: a tenth of --cases)")
    ap.add_argument("--request-cases", type=int, default=None, help="search-server requests (default: --cases)")
    ap.add_argument("--only", choices=("scenes", "requests"), help="run only the scene or the request fuzzer")
    ap.add_argument("--labels-cases", type=int, default=None, help="labels CSV cases (default: a tenth of --cases)")
    ap.add_argument(
        "--server-cases", type=int, default=None, help="search-server requests (default: a hundredth of --cases)"
    )
    args = ap.parse_args(argv)
    if not args.quick and not args.only and not DATA.exists():
        print(f"corpus not found at {DATA} (--quick runs on examples/data)", file=sys.stderr)
        return 1
    # a terminated run still removes its case folder and its workers
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    n = args.cases or (100 if args.quick else 100_000)
    jobs = max(1, min(args.jobs, 2))
    n_scene = args.scene_cases if args.scene_cases is not None else max(n // 10, 40 if args.quick else 0)
    n_req = args.request_cases if args.request_cases is not None else n
    if args.only == "scenes":
        return fuzz_scenes(n_scene, args.seed, args.timeout)
    if args.only == "requests":
        return fuzz_requests(n_req, args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        if args.quick:
            os.environ["MOCAPFLOW_FUZZ_DATA"] = str(_example_sources(Path(tmp)))
        print(
            f"fuzzing the format readers: {n:,} cases, seed {args.seed}, {jobs} processes, timeout {args.timeout:g} s"
        )
        status = report(run(n, args.seed, jobs, args.timeout))
        from _hostile import run_all

        hostile = Path(tmp) / "hostile"
        hostile.mkdir()
        status |= int(run_all(hostile, quick=args.quick) > 0)
        from _fuzz_inputs import fuzz_labels, fuzz_server

        n_labels = args.labels_cases if args.labels_cases is not None else max(n // 10, 200)
        n_server = args.server_cases if args.server_cases is not None else max(n // 100, 100)
        for name, fn, count in (("labels", fuzz_labels, n_labels), ("server", fuzz_server, n_server)):
            if count:
                sub = Path(tmp) / f"fuzz-{name}"
                sub.mkdir()
                status |= int(fn(count, args.seed, args.timeout, sub) > 0)
    status |= fuzz_requests(n_req, args.seed) if n_req else 0
    return status | (fuzz_scenes(n_scene, args.seed, args.timeout) if n_scene else 0)


def _example_sources(into: Path) -> Path:
    """The bundled CMU takes laid out as the corpus (``cmu/amc/<subject>/``), and BVH files
    written from two of them (``bvh/examples/``)."""

    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.bvh import write_bvh

    for subject in sorted((ROOT / "examples" / "data" / "cmu").iterdir()):
        if subject.is_dir():
            shutil.copytree(subject, into / "cmu" / "amc" / subject.name)
    (into / "bvh" / "examples").mkdir(parents=True)
    for f in sorted((into / "cmu" / "amc").glob("*/*.amc"))[:2]:
        write_bvh(read_amc(f).slice(0, 120), into / "bvh" / "examples" / f"{f.stem}.bvh")
    # C3D and TRC files of the corpus when it lies beside the repository (none are bundled)
    for f in sorted(DATA.glob("c3d/*/*.c3d")) + sorted(DATA.glob("trc/*/*.trc")):
        if f.stat().st_size < 1_500_000:
            (into / f.parent.parent.name / f.parent.name).mkdir(parents=True, exist_ok=True)
            shutil.copy(f, into / f.parent.parent.name / f.parent.name / f.name)
    return into


if __name__ == "__main__":
    sys.exit(main())
