"""Fuzzers of the inputs beyond motion files, run by ``benchmarks/fuzz_parsers.py``: labels
CSV files (:func:`fuzz_labels`) and search-server requests (:func:`fuzz_server`).

A labels case mutates a valid CSV (extra and missing fields, nan/inf/huge/negative times,
reversed spans, times past the clip, latin-1 and NUL bytes, unterminated quotes, BOMs,
CR/LF mixes, byte flips, truncations): the reader must return a table whose spans lie in
their clip or raise ParseError naming ``file:line`` (a ConfigError/DataError for the whole
file), within the timeout. A server case sends one request (option values from hostile pools:
zero, negative, 10^9, 10^30, floats, wrong types, empty, long and NUL strings, nested JSON,
non-UTF-8 and truncated bytes) through the server's own request handler with a real search
session: the reply must come within the timeout with exit status 0, 1 or 2, never 3 (an
internal error) or an exception.
"""

from __future__ import annotations

import argparse
import json
import shutil
import signal
import textwrap
import time
from collections import Counter
from contextlib import contextmanager
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

CLIPS = [
    {"clip_id": 1, "name": "walk1", "path": "/d/a/walk1.bvh", "fps": 30.0, "n_frames": 400},
    {"clip_id": 2, "name": "run2", "path": "/d/b/run2.amc", "fps": 120.0, "n_frames": 90},
]
BASE_CSV = "clip,label,start,end\nwalk1,walk,0.5,1.5\nrun2,run,,\na/walk1.bvh,turn,1,13.3\nother,x,1,2\n"
LABEL_KINDS = (
    "extra_field",
    "missing_field",
    "number",
    "encoding",
    "quote",
    "byte_flip",
    "truncate",
    "newlines",
    "duplicate_line",
)
NUMBERS = ("nan", "inf", "-inf", "-1", "1e308", "1e6", "13.4", "1e-300", "0x10", "", " ", "1,5", "٣", "1_0", "-0")


def _pick(rng: np.random.Generator, seq):
    return seq[int(rng.integers(len(seq)))]


class _Timeout(Exception):
    pass


@contextmanager
def _deadline(seconds: float):
    def fire(*_):
        raise _Timeout

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _label_case(rng: np.random.Generator) -> tuple[str, bytes]:
    kind = LABEL_KINDS[int(rng.integers(len(LABEL_KINDS)))]
    lines = BASE_CSV.splitlines()
    i = int(rng.integers(1, len(lines)))
    fields = lines[i].split(",")
    if kind == "extra_field":
        fields.append(str(_pick(rng, ["x", "", "1", '"a,b"'])))
    elif kind == "missing_field":
        fields = fields[: int(rng.integers(0, len(fields)))]
    elif kind == "number":
        fields[int(rng.integers(2, 4))] = _pick(rng, NUMBERS)
    elif kind == "quote":
        fields[int(rng.integers(len(fields)))] = '"' + fields[0]
    lines[i] = ",".join(fields)
    data = ("\n".join(lines) + "\n").encode()
    if kind == "encoding":
        bad = [b"\xe9", b"\x00", b"\xff\xfe", b"\xef\xbb\xbf", b"\x80", "é".encode("latin-1")]
        at = int(rng.integers(len(data)))
        data = data[:at] + bad[int(rng.integers(len(bad)))] + data[at:]
    elif kind == "byte_flip":
        arr = bytearray(data)
        for _ in range(int(rng.integers(1, 4))):
            arr[int(rng.integers(len(arr)))] = int(rng.integers(256))
        data = bytes(arr)
    elif kind == "truncate":
        data = data[: int(rng.integers(len(data)))]
    elif kind == "newlines":
        data = data.replace(b"\n", _pick(rng, [b"\r\n", b"\r", b"\n\n"]))
    elif kind == "duplicate_line":
        data = data + (lines[i] + "\n").encode() * int(rng.integers(1, 1000))
    return kind, data


def fuzz_labels(n_cases: int, seed: int, timeout: float, folder: Path, echo=print) -> int:
    """``n_cases`` mutated labels CSVs; returns the number of failures."""
    from mocapflow.framework.errors import ConfigError, DataError, ParseError
    from mocapflow.framework.labels import csv_labels

    rng = np.random.default_rng(seed)
    counts: Counter = Counter()
    examples: list[str] = []
    path = folder / "labels.csv"
    n_of = {c["clip_id"]: c["n_frames"] for c in CLIPS}
    t0 = time.perf_counter()
    for _ in range(n_cases):
        kind, data = _label_case(rng)
        path.write_bytes(data)
        outcome = "accepted"
        try:
            with _deadline(timeout):
                table = csv_labels(path, CLIPS)
            for r in table.to_pylist():
                s, e = r["start_frame"], r["end_frame"]
                if s is not None and not (0 <= s < e <= n_of[r["clip_id"]]):
                    outcome = "wrong_accept"
        except ParseError as exc:
            outcome = "rejected" if f"{path}:" in str(exc) and exc.line else "bad_error"
        except (ConfigError, DataError):
            outcome = "rejected"
        except _Timeout:
            outcome = "hang"
        except Exception as exc:  # the failure being counted
            outcome = "crash"
            kind = f"{kind}: {type(exc).__name__}: {exc}"
        counts[outcome] += 1
        if outcome not in ("accepted", "rejected") and len(examples) < 5:
            examples.append(f"{outcome} [{kind}] {data[:120]!r}")
    bad = sum(counts[k] for k in ("crash", "hang", "wrong_accept", "bad_error"))
    echo(
        f"\nlabels CSV: {n_cases:,} cases in {time.perf_counter() - t0:.1f} s: "
        + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    )
    for line in examples:
        echo(f"  {line}")
    return bad


# --- search-server requests

VALUES = [
    0,
    -1,
    1,
    10**9,
    10**30,
    -(10**30),
    1.5,
    1e308,
    -0.0,
    True,
    None,
    "",
    "x" * 5000,
    "a\x00b",
    "../../etc/passwd",
    "/dev/zero",
    "02_01.amc:20-80",
    "02_01.amc:80-20",
    "02_01.amc:-5-10",
    "02_01.amc:0-999999999",
    "02_01.amc:1e9s-2e9s",
    "02_01.amc:nan-inf",
    "16_15.amc:1s-3s",
    "nosuch.amc",
    "lng",
    "logical",
    "sdtw",
    "search",
    "exact",
    "fast",
    "cost",
    "normalized",
    "span",
    "clip",
    "off",
    "é",
    [],
    {},
    [[[[1]]]],
    {"a": 1},
]
#: per option, values of the right JSON type that a client should not send (and a few it may)
POOLS: dict[str, list] = {
    "query": [
        "02_01.amc:20-80",
        "02_01.amc:80-20",
        "02_01.amc:0-999999999",
        "02_01.amc:1e9s-2e9s",
        "02_01.amc:0s-0.001s",
        "16_15.amc:1s-3s",
        "02_01",
        "02_01:5-6",
        "nosuch.amc",
        "nosuch",
        "x" * 300,
        "x" * 5000,
        "a\x00b",
        "../../etc/passwd",
        "/dev/zero",
        "/",
        ".",
        "é.amc",
        " ",
        ":",
        "02_01.amc:",
        "02_01.amc:1-2-3",
    ],
    "index": ["tree", "motions", "fe15", "nosuch", "", "x" * 300],
    "matcher": ["search", "lng", "logical", "sdtw", "nosuch", "", "formats.load"],
    "count": [0, -1, 1, 2, 4097, 10**9, 10**30, 2**63],
    "k": [0, -1, 1, 2, 4096, 4097, 10**9, 10**30],
    "min_span": [0, -1, 0.5, 10, 11, 1e-300, 1e308, 2**70],
    "rank_by": ["cost", "normalized", "x"],
    "paper": [True, False],
    "mode": ["exact", "fast", "x", ""],
    "exclude_self": ["span", "clip", "off", "x"],
    "out": ["a.csv", "b.parquet", "c.txt", "", "sub/d.csv"],
}


def _request(rng: np.random.Generator, tmp: Path) -> bytes:
    args: dict = {"query": _pick(rng, POOLS["query"][:8])}
    for _ in range(int(rng.integers(1, 4))):
        key = _pick(rng, list(POOLS))
        v = _pick(rng, POOLS[key]) if rng.random() < 0.85 else _pick(rng, VALUES)
        if key == "out" and isinstance(v, str) and v:
            v = str(tmp / "out" / v)
        args[key] = v
    req: object = {"args": args, "cwd": str(tmp)}
    r = rng.random()
    if r < 0.03:
        depth = int(_pick(rng, [10, 1000, 100_000]))
        return b"[" * depth + b"]" * depth
    if r < 0.06:
        req = _pick(rng, [[], "x", 1, None, {"args": [], "cwd": 1}, {"args": {}, "cwd": "\x00"}])
    raw = json.dumps(req).encode()
    if r > 0.97:
        raw = raw[: int(rng.integers(len(raw)))] + _pick(rng, [b"", b"\xff", b"\x00"])
    return raw


def _tiny_workspace(folder: Path) -> Path:
    from mocapflow.framework.runner import run_pipeline

    pipe = folder / "p.yaml"
    pipe.write_text(
        textwrap.dedent(f"""
        name: fuzzserver
        workspace: ws
        steps:
          motions: {{uses: formats.load, with: {{paths: ["{ROOT}/examples/data/cmu/**/*.amc"], fps: 30}}}}
          fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
          tree: {{uses: indexes.kdtree, input: fe15}}
        """)
    )
    run_pipeline(pipe)
    return folder / "ws"


def fuzz_server(n_cases: int, seed: int, timeout: float, folder: Path, echo=print) -> int:
    """``n_cases`` hostile requests through the server's handler with a real session on a
    workspace of the bundled examples; returns the number of failures."""
    from mocapflow.plugins.similarity.search.search_command import SearchSession
    from mocapflow.plugins.similarity.search.search_server import _handle

    ws = _tiny_workspace(folder)
    (folder / "work").mkdir()
    for f in (ROOT / "examples" / "data" / "cmu").glob("*/*.a[ms][cf]"):  # query files beside their ASF
        shutil.copyfile(f, folder / "work" / f.name)
    box = [SearchSession(ws, None, entry_points=False)]
    rng = np.random.default_rng(seed)
    counts: Counter = Counter()
    examples: list[str] = []
    t0 = time.perf_counter()
    for _ in range(n_cases):
        raw = _request(rng, folder / "work")
        try:
            with _deadline(timeout):
                reply = _handle(box, raw, lambda: SearchSession(ws, None, entry_points=False))
            outcome = {0: "answered", 1: "error", 2: "refused", None: "declined"}.get(reply.get("rc"), "internal")
        except _Timeout:
            outcome, reply = "hang", {}
        except Exception as exc:  # the failure being counted
            outcome, reply = "crash", {"stderr": f"{type(exc).__name__}: {exc}"}
        counts[outcome] += 1
        if outcome in ("internal", "hang", "crash") and len(examples) < 8:
            examples.append(f"{outcome}: {raw[:160]!r} -> {reply.get('stderr', '').strip()[:200]}")
    bad = sum(counts[k] for k in ("internal", "hang", "crash"))
    echo(
        f"\nsearch-server requests: {n_cases:,} cases in {time.perf_counter() - t0:.1f} s: "
        + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    )
    for line in examples:
        echo(f"  {line}")
    return bad


def main() -> int:
    import tempfile

    ap = argparse.ArgumentParser(description="labels CSV and search-server request fuzzers")
    ap.add_argument("--quick", action="store_true", help="200 labels cases, 100 requests")
    ap.add_argument("--labels", type=int, default=None, help="labels CSV cases (default 100,000)")
    ap.add_argument("--server", type=int, default=None, help="search-server requests (default 100,000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=10.0)
    a = ap.parse_args()
    a.labels = a.labels if a.labels is not None else 200 if a.quick else 100_000
    a.server = a.server if a.server is not None else 100 if a.quick else 100_000
    with tempfile.TemporaryDirectory() as tmp:
        bad = fuzz_labels(a.labels, a.seed, a.timeout, Path(tmp))
        if a.server:
            bad += fuzz_server(a.server, a.seed, a.timeout, Path(tmp))
    return int(bad > 0)


if __name__ == "__main__":
    raise SystemExit(main())
