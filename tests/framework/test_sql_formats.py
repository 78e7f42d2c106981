"""``mocapflow sql --format csv|json``: every view of the quickstart workspace exports, list
and struct columns as JSON (text in CSV, arrays and objects in JSON), NaN as null."""

from __future__ import annotations

import csv
import io
import json
import math

import numpy as np
import pyarrow as pa
from report_workspaces import quickstart_workspace  # noqa: F401 (fixture)

from mocapflow.framework.cli import main
from mocapflow.framework.workspace import export_table, flat_table, write_json


def _num(v) -> np.ndarray:
    """A nested list of numbers (None as NaN) as a float array."""
    if isinstance(v, list):
        return np.array([_num(x) for x in v], float)
    return np.array(np.nan if v is None else v, float)


def _sql(capsys, *argv: str) -> str:
    assert main(["sql", *argv]) == 0, capsys.readouterr().err
    return capsys.readouterr().out


def test_every_quickstart_view_exports_to_csv_and_json(quickstart_workspace, capsys):
    from mocapflow.framework.catalog import Catalog

    ws = str(quickstart_workspace)
    with Catalog(ws) as cat:
        views = sorted(cat.views)
        tables = {v: cat.query(f"SELECT * FROM {v}") for v in views}
    assert {"search", "fe15", "clean", "motions_clips"} <= set(views)
    for view in views:
        table = tables[view]
        rows = list(csv.DictReader(io.StringIO(_sql(capsys, ws, f"SELECT * FROM {view}", "--format", "csv"))))
        assert len(rows) == table.num_rows, view
        got = json.loads(_sql(capsys, ws, f"SELECT * FROM {view}", "--format", "json"))
        assert len(got) == table.num_rows, view
        if not table.num_rows:
            continue
        first = table.slice(0, 1).to_pylist()[0]
        for name, field in zip(table.column_names, table.schema, strict=True):
            if pa.types.is_list(field.type) or pa.types.is_fixed_size_list(field.type):
                want = _num(first[name])
                np.testing.assert_allclose(_num(json.loads(rows[0][name])), want, err_msg=f"{view}.{name}")
                np.testing.assert_allclose(_num(got[0][name]), want, err_msg=f"{view}.{name}")


def test_nested_values_as_json_nan_as_null(tmp_path):
    t = pa.table(
        {
            "id": [1, 2],
            "path": pa.array([[[0, 1], [1, 2]], None], pa.list_(pa.list_(pa.int32()))),
            "pose": pa.array([{"x": 1.5, "y": float("nan")}, {"x": 0.0, "y": 2.0}]),
            "v": pa.array([[1.0, 2.0], [3.0, 4.0]], pa.list_(pa.float32(), 2)),
            "cost": [float("inf"), 0.5],
        }
    )
    flat = flat_table(t)
    assert flat["path"].to_pylist() == ["[[0,1],[1,2]]", None]
    assert flat["pose"].to_pylist()[0] == '{"x":1.5,"y":null}'
    buf = io.StringIO()
    write_json(t, buf)
    rows = json.loads(buf.getvalue())
    assert rows[0] == {"id": 1, "path": [[0, 1], [1, 2]], "pose": {"x": 1.5, "y": None}, "v": [1.0, 2.0], "cost": None}
    export_table(t, tmp_path / "t.json", "json")
    assert json.loads((tmp_path / "t.json").read_text()) == rows
    export_table(t, tmp_path / "t.csv", "csv")
    back = list(csv.DictReader((tmp_path / "t.csv").open()))
    assert json.loads(back[0]["v"]) == [1.0, 2.0] and back[1]["cost"] == "0.5"
    assert not math.isnan(float(back[0]["id"]))
