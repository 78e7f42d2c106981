"""The scene-format fuzzer of ``benchmarks/fuzz_parsers.py`` (``--scene-cases``): the glTF, GLB
and binary FBX readers on mutated copies of the Blender-made files of ``tests/data/blender``.

Truncations, byte flips, inserted, deleted and duplicated byte runs; for glTF, JSON values
replaced (negative, huge, wrong type, null, paths outside the folder) or keys deleted, and
re-indented JSON (content kept: the arrays must not change). There is no reference reader to
agree with: the reader must return finite arrays of consistent shapes or raise ParseError
naming the file, within the timeout, and open nothing outside the case's folder (audit hook).
"""

from __future__ import annotations

import contextlib
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

ROOT = Path(__file__).resolve().parent.parent
#: outcomes that fail the fuzzer (the format and scene fuzzers share them)
FAILURES = ("crash", "hang", "wrong_accept", "wrong_reject", "bad_error")


SCENE_KINDS = ("truncate", "byte_flip", "insert", "delete", "duplicate", "json_value", "json_key", "json_indent")
#: Values a JSON mutation writes: negative, huge, wrong types, and for strings paths out of
#: the file's folder, a device, nested arrays.
_JSON_VALUES = [-1, 0, 1e308, 2**31, 2**62, -(2**62), 0.5, "x", None, [], {}, True]
_JSON_STRINGS = ["../secret.bin", "/etc/passwd", "/dev/zero", "%2e%2e/secret.bin", "file:///etc/passwd", "data:,"]


def _array_headers(data: bytes) -> list[int]:
    """Offsets of what look like FBX array property headers (type code, count, encoding
    0/1, byte length within the file): the fields a ``fbx_array`` mutation rewrites."""
    import re
    import struct

    out = []
    for m in re.finditer(rb"[fdlib]", data):
        p = m.start() + 1
        if p + 12 <= len(data):
            count, enc, n = struct.unpack_from("<III", data, p)
            if enc in (0, 1) and 0 < n <= len(data) - p - 12 and count <= 1 << 24 and (enc == 1 or n >= count):
                out.append(p)
    return out


_HEADERS: dict[bytes, list[int]] = {}


def _glb_json(data: bytes, mutate) -> bytes:
    """A GLB file with its JSON chunk passed through ``mutate`` (lengths kept consistent)."""
    import struct

    n = struct.unpack_from("<I", data, 12)[0]
    text = mutate(data[20 : 20 + n])
    text += b" " * (-len(text) % 4)
    rest = data[20 + n :]
    return (
        struct.pack("<III", 0x46546C67, 2, 28 + len(text) - 8 + len(rest))
        + struct.pack("<II", len(text), 0x4E4F534A)
        + text
        + rest
    )


def _scene_case(src: Path, data: bytes, rng: np.random.Generator) -> tuple[str, bytes]:
    """One mutation of a scene file's bytes (JSON kinds on the JSON of a .gltf or of a GLB's
    JSON chunk, array-header kinds on FBX)."""
    extra = {".gltf": SCENE_KINDS[5:], ".glb": ("json_value", "json_key"), ".fbx": ("fbx_array", "fbx_array")}
    kinds = SCENE_KINDS[:5] + extra.get(src.suffix, ())
    kind = kinds[int(rng.integers(0, len(kinds)))]
    if src.suffix == ".glb" and kind.startswith("json"):
        return kind, _glb_json(data, lambda text: _json_mutation(kind, text, rng))
    if kind == "fbx_array":
        import struct

        if data not in _HEADERS:
            _HEADERS[data] = _array_headers(data)
        heads = _HEADERS[data]
        p = heads[int(rng.integers(0, len(heads)))]
        b = bytearray(data)
        field = int(rng.integers(0, 3))
        value = [0, 1, 2, 2**31, 2**32 - 1, 1 << 28, int(rng.integers(0, 2**32))][int(rng.integers(0, 7))]
        struct.pack_into("<I", b, p + 4 * field, value)
        return kind, bytes(b)
    n = len(data)
    at = int(rng.integers(0, n))
    run = int(rng.integers(1, 64))
    if kind == "truncate":
        return kind, data[:at]
    if kind == "byte_flip":
        b = bytearray(data)
        for _ in range(int(rng.integers(1, 9))):
            b[int(rng.integers(0, n))] = int(rng.integers(0, 256))
        return kind, bytes(b)
    if kind == "insert":
        return kind, data[:at] + rng.integers(0, 256, run, dtype=np.uint8).tobytes() + data[at:]
    if kind == "delete":
        return kind, data[:at] + data[at + run :]
    if kind == "duplicate":
        return kind, data[: at + run] + data[at : at + run] + data[at + run :]
    return kind, _json_mutation(kind, data, rng)


def _json_mutation(kind: str, data: bytes, rng: np.random.Generator) -> bytes:
    import json

    doc = json.loads(data)
    if kind == "json_indent":
        return json.dumps(doc, indent=int(rng.integers(0, 5))).encode()
    spots: list[tuple[object, object]] = []

    def walk(o: object) -> None:
        items = o.items() if isinstance(o, dict) else enumerate(o) if isinstance(o, list) else []
        for k, v in items:
            spots.append((o, k))
            walk(v)

    walk(doc)
    parent, key = spots[int(rng.integers(0, len(spots)))]
    if kind == "json_key" and isinstance(parent, dict):
        del parent[key]
    else:
        old = parent[key]  # type: ignore[index]
        choices = _JSON_STRINGS if isinstance(old, str) and rng.random() < 0.5 else _JSON_VALUES
        new = choices[int(rng.integers(0, len(choices)))]
        if rng.random() < 0.02:
            new = "NEST"  # replaced by 5,000 nested arrays below
        parent[key] = new  # type: ignore[index]
    text = json.dumps(doc)
    return text.replace('"NEST"', "[" * 5000 + "]" * 5000).encode()


def _scene_outcome(read, case: Path, kind: str, reference: np.ndarray, timeout: float) -> tuple[str, str]:
    """Outcome of reading one mutated scene file (module doc: finite arrays of consistent
    shapes, or a ParseError naming the file; re-indented JSON must read as the original)."""
    from mocapflow.framework.errors import ParseError

    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        m = read(case)
        pos = m.positions
        ok = np.all(np.isfinite(pos)) and pos.shape == (m.n_frames, m.n_joints, 3) and m.fps > 0
        if kind == "json_indent" and (pos.shape != reference.shape or np.abs(pos - reference).max() > 0):
            return "wrong_accept", "re-indented JSON changed the arrays"
        return ("accepted", "") if ok else ("wrong_accept", "non-finite or misshapen arrays")
    except ParseError as exc:
        if kind == "json_indent":
            return "wrong_reject", str(exc)[:200]
        bad = exc.path != str(case) or not exc.message.strip()
        return ("bad_error", str(exc)[:200]) if bad else ("rejected", "")
    except TimeoutError:
        return "hang", f"over {timeout:g} s"
    except Exception as exc:
        return "crash", f"{type(exc).__name__}: {exc}"[:200]
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)


def fuzz_scenes(n_cases: int, seed: int, timeout: float, echo=print) -> int:
    """Fuzz the glTF/GLB/FBX readers on the Blender-made test files (module doc)."""
    from mocapflow.plugins.formats.fbx import read_fbx
    from mocapflow.plugins.formats.gltf import read_gltf

    sources = sorted(
        p for p in (ROOT / "tests" / "data" / "blender").iterdir() if p.suffix in (".gltf", ".glb", ".fbx")
    )
    counts: Counter = Counter()
    by_kind: dict[str, Counter] = defaultdict(Counter)
    examples: dict[str, list[str]] = defaultdict(list)
    reference = {}
    t0 = time.time()

    def on_alarm(*_: object) -> None:
        raise TimeoutError

    old = signal.signal(signal.SIGALRM, on_alarm)
    outside: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        raw = {src: src.read_bytes() for src in sources}
        for src in sources:  # references, copies and lazy imports before the audit starts
            reference[src] = (read_fbx if src.suffix == ".fbx" else read_gltf)(src).positions
            shutil.copy(src, Path(tmp) / src.name)
            if src.with_suffix(".bin").exists():
                shutil.copy(src.with_suffix(".bin"), Path(tmp) / src.with_suffix(".bin").name)
        case_dir = str(Path(tmp).resolve()) + os.sep

        def audit(event: str, args: tuple) -> None:  # a reader must open nothing outside the case's folder
            if event == "open" and isinstance(args[0], (str, bytes, os.PathLike)):
                p = os.path.realpath(os.fsdecode(args[0]))
                if not p.startswith(case_dir):
                    outside.append(p)

        sys.addaudithook(audit)
        for i in range(n_cases):
            rng = np.random.default_rng([seed, 7, i])
            src = sources[int(rng.integers(0, len(sources)))]
            read = read_fbx if src.suffix == ".fbx" else read_gltf
            kind, data = _scene_case(src, raw[src], rng)
            case = Path(tmp) / f"case{src.suffix}"
            case.write_bytes(data)
            outcome, detail = _scene_outcome(read, case, kind, reference[src], timeout)
            if outside:
                outcome, detail = "outside_read", f"opened {outside[:3]}"
                outside.clear()
            counts[outcome] += 1
            by_kind[f"{src.suffix[1:]}:{kind}"][outcome] += 1
            if outcome not in ("accepted", "rejected") and len(examples[outcome]) < 5:
                examples[outcome].append(f"case {i} ({src.name}, {kind}): {detail}")
    signal.signal(signal.SIGALRM, old)
    echo(
        f"\nscene formats (glTF, GLB, FBX): {n_cases:,} cases in {time.time() - t0:.0f} s: accepted "
        f"{counts['accepted']:,}, rejected (ParseError) {counts['rejected']:,}; crashes {counts['crash']}, hangs "
        f"{counts['hang']}, wrong acceptances {counts['wrong_accept']}, wrong rejections {counts['wrong_reject']}, "
        f"bad errors {counts['bad_error']}, reads outside the folder {counts['outside_read']}; peak RSS of the "
        f"process {hwm_mb():.0f} MB"
    )
    cols = ("accepted", "rejected", *FAILURES, "outside_read")
    echo(f"{'mutation kind':<18}" + "".join(f"{k:>13}" for k in cols))
    for key in sorted(by_kind):
        echo(f"{key:<18}" + "".join(f"{by_kind[key][k]:>13,}" for k in cols))
    for outcome, lines in examples.items():
        echo(f"first {outcome} cases:")
        for ln in lines:
            echo("  " + ln)
    return int(any(counts[k] for k in (*FAILURES, "outside_read")))


def hwm_mb() -> float:
    """Peak resident memory of this process, MB (VmHWM; ru_maxrss elsewhere)."""
    with contextlib.suppress(OSError):
        for ln in Path("/proc/self/status").read_text().splitlines():
            if ln.startswith("VmHWM:"):
                return int(ln.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
