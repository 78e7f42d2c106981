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
