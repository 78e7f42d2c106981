"""First-run compile time: the kd-tree query kernel is compiled once per run,
not once per kind of argument array (read-only views, e.g. of ``exclude``'s broadcast groups, vs fresh arrays, a literal 0
vs an int64 chunk start)."""

from __future__ import annotations

import os
import subprocess
import sys

CODE = """
import numpy as np
from mocapflow.plugins.similarity.knn import _knn_kernels as kern
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

rng = np.random.default_rng(0)
x = rng.normal(size=(400, 6)).astype(np.float32)
groups, frames = np.repeat(np.arange(4), 100), np.tile(np.arange(100), 4)
ix = KDTreeIndex(method="kdtree").build(x, groups=groups, frames=frames)
ro_g, ro_f = groups[:3].copy(), frames[:3].copy()
ro_g.flags.writeable = ro_f.flags.writeable = False           # as Arrow columns are
ix.query(x[:3], 5, exclude=2, query_groups=ro_g, query_frames=ro_f, workers=1)
ix.query(x[:50], 5, exclude=2, query_groups=groups[:50].astype(np.int32), query_frames=frames[:50], workers=2)
ix.query_rows(np.arange(20), 5, exclude=2, workers=1)
ix.query(x[:3], 5, workers=1)                                  # no exclusion: fresh zero groups
ix.query(x[:50], 5, workers=2)
print(len(kern.query_tree.signatures), len(kern._query_rows.signatures))
"""


def test_kdtree_query_kernel_compiles_one_variant(tmp_path):
    # an empty numba cache: a kernel loaded from the cache does not compile the kernels it
    # calls, so the counts would depend on which tests ran before
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    out = subprocess.run(
        [sys.executable, "-c", CODE], capture_output=True, text=True, check=True, env=env
    ).stdout.split()
    assert out == ["1", "1"], f"query_tree, _query_rows variants: {out}"


READONLY = """
import numpy as np
from mocapflow.framework import _fk_kernels as fk
from mocapflow.plugins.similarity.knn import _knn_kernels as kern, _tree_kernels as tk
from mocapflow.plugins.similarity.knn.kdtree import KDTreeIndex

rng = np.random.default_rng(0)
x = rng.normal(size=(300, 6)).astype(np.float32)
ro = x.copy()
ro.flags.writeable = False                                     # as Arrow columns and mmapped features are
for data in (x, ro):
    ix = KDTreeIndex(method="kdtree").build(data)
    ix.query(data[:5], 3, workers=1)
    ix.query(data[:1], 3, workers=1)
rot = np.tile([1.0, 0, 0, 0], (4, 3, 1))
par, off = np.array([-1, 0, 1]), np.ones((3, 3))
for r in (rot, rot.copy()):
    r.flags.writeable = r is rot
    fk.fk(par, off, np.zeros((4, 3)), r, None)
print(len(tk.build_tree.signatures), len(kern.query_tree.signatures), len(fk.fk_kernel.signatures))
"""


def test_read_only_and_writable_inputs_compile_one_variant(tmp_path):
    """Features from Arrow are read-only, from NumPy writable: the kd-tree build and query
    and forward kinematics get read-only views, so one variant compiles for both."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    out = subprocess.run(
        [sys.executable, "-c", READONLY], capture_output=True, text=True, check=True, env=env
    ).stdout.split()
    assert out == ["1", "1", "1"], f"build_tree, query_tree, fk_kernel variants: {out}"
