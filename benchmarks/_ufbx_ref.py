"""ufbx as a reference FBX evaluator, isolated in a subprocess.

The ``ufbx`` 0.0.5 Python binding can crash the interpreter (segfault) when its objects are
freed, so it only ever runs in a child process started by :func:`ufbx_positions`, which
exits with ``os._exit`` before any object is freed. Used by the FBX parity tests and
benchmarks; ``ufbx`` is not a dependency of mocapflow.

Child protocol: ``_child(IN.json, OUT.npz)`` in a fresh interpreter; ``IN.json`` holds ``path``,
``names`` (node names) and ``times`` (seconds); ``OUT.npz`` gets ``pos`` (F, J, 3) world
positions in the file's own units and axes (NaN for a name ufbx does not have), ``local``
(F, J, 10) each node's local translation, rotation (w, x, y, z) and scale, ``fps``,
``begin``, ``end`` (the stack's time span, seconds), ``seconds`` (load + evaluation time).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def available() -> bool:
    """Whether the ufbx binding can be imported (checked in a child process)."""
    try:
        r = subprocess.run([sys.executable, "-c", "import ufbx, os; os._exit(0)"], capture_output=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return r.returncode == 0


def ufbx_positions(path: str | Path, names: list[str], times: np.ndarray, animation: int = 0, timeout: float = 600):
    """World positions of ``names`` at ``times`` (seconds) as ufbx evaluates them:
    a dict with ``pos`` (F, J, 3), ``fps``, ``begin``, ``end``, ``seconds``."""
    with tempfile.TemporaryDirectory() as tmp:
        src, out = Path(tmp) / "in.json", Path(tmp) / "out.npz"
        src.write_text(
            json.dumps({"path": str(path), "names": names, "times": [float(x) for x in times], "animation": animation})
        )
        here = str(Path(__file__).resolve().parent)
        code = f"import sys; sys.path.insert(0, {here!r}); import _ufbx_ref; _ufbx_ref._child(sys.argv[1], sys.argv[2])"
        r = subprocess.run(
            [sys.executable, "-c", code, str(src), str(out)], capture_output=True, text=True, timeout=timeout
        )
        if r.returncode != 0 or not out.exists():
            raise RuntimeError(f"ufbx child failed ({r.returncode}): {r.stderr[-500:]}")
        with np.load(out) as z:
            return {k: z[k] for k in z.files}


def _child(src: str, out: str) -> None:
    import ufbx

    job = json.loads(Path(src).read_text())
    t0 = time.perf_counter()
    scene = ufbx.load_file(job["path"])
    stack = scene.anim_stacks[job["animation"]]
    idx = {}
    for k, node in enumerate(scene.nodes):
        idx.setdefault(node.name, k)
    cols = [idx.get(n, -1) for n in job["names"]]
    times = job["times"]
    pos = np.full((len(times), len(cols), 3), np.nan)
    local = np.full((len(times), len(cols), 10), np.nan)  # translation, rotation (w, x, y, z), scale
    keep: list = []
    for f, t in enumerate(times):
        ev = ufbx.evaluate_scene(scene, stack.anim, t)
        nodes = ev.nodes
        keep.append(ev)
        for j, k in enumerate(cols):
            if k >= 0:
                node = nodes[k]  # one wrapper per node, kept alive: the binding crashes on a dropped one
                keep.append(node)
                c3 = node.node_to_world.c3
                pos[f, j] = (c3.x, c3.y, c3.z)
                lt = node.local_transform
                tr, q, sc = lt.translation, lt.rotation, lt.scale
                local[f, j] = (tr.x, tr.y, tr.z, q.w, q.x, q.y, q.z, sc.x, sc.y, sc.z)
    seconds = time.perf_counter() - t0
    np.savez(
        out,
        pos=pos,
        local=local,
        fps=scene.settings.frames_per_second,
        begin=stack.time_begin,
        end=stack.time_end,
        seconds=seconds,
    )
    sys.stdout.flush()
    os._exit(0)  # never free ufbx objects (the 0.0.5 binding may crash doing so)
