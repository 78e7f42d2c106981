"""The Python API (``mocapflow.read/features/Database/clean``) and ``python -m mocapflow``."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "examples" / "data" / "cmu"


def test_readme_python_api_example_runs_verbatim(tmp_path, monkeypatch):
    text = (ROOT / "README.md").read_text()
    section = text.split("## Python API", 1)[1]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    assert (tmp_path / "runs" / "api" / "walk.clean.bvh").stat().st_size > 0


def test_facade_agrees_with_the_components():
    import mocapflow
    from mocapflow.framework.database import MotionDatabase

    walk = mocapflow.read(DATA / "16" / "16_15.amc")
    regs = mocapflow.registries()
    fs = regs["features"].get("end_effectors")({"joints": 10})
    db = MotionDatabase([walk])
    np.testing.assert_array_equal(mocapflow.features("end_effectors", walk, joints=10), fs.fit(db).transform(db))
    q = walk.slice(30, 90)
    hits = mocapflow.Database([walk], fps=None).search(q, count=3, exclude_self="off")
    assert hits.column_names[:3] == ["query_id", "rank", "clip_id"] and hits.num_rows >= 1
    best = hits.slice(0, 1).to_pylist()[0]
    assert (best["clip"], best["start_frame"], best["end_frame"]) == ("16_15", 30, 90)
    assert best["cost"] == pytest.approx(0.0, abs=1e-6)


def test_read_write_round_trip_and_unknown_extension(tmp_path):
    import mocapflow
    from mocapflow.framework.errors import ConfigError

    walk = mocapflow.read(DATA / "16" / "16_15.amc")
    mocapflow.write(walk, tmp_path / "w.bvh")
    back = mocapflow.read(tmp_path / "w.bvh")
    assert back.n_frames == walk.n_frames
    np.testing.assert_allclose(back.positions, walk.positions, atol=1e-3)
    with pytest.raises(ConfigError, match="no registered reader"):
        mocapflow.read(tmp_path / "w.xyz")


def test_python_dash_m_mocapflow():
    out = subprocess.run([sys.executable, "-m", "mocapflow", "--version"], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    import mocapflow

    assert mocapflow.__version__ in out.stdout + out.stderr
