"""Validation before anything runs: nested component parameters, dataset
kinds of inputs, the executor, and components' own plan-time checks (globs)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from toy_components import NestedPlugin, ToyPlugin

from mocapflow.framework import ConfigError, get_plugin_manager
from mocapflow.framework.cli import main
from mocapflow.framework.plugins import build_registries
from mocapflow.framework.runner import plan_pipeline, run_pipeline

REPO = Path(__file__).resolve().parents[2]
AMC = sorted((REPO / "examples" / "data" / "cmu").rglob("*.amc"))


def pm():
    return get_plugin_manager(entry_points=False, extra=[ToyPlugin(), NestedPlugin()])


def write(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "p.yaml"
    p.write_text(textwrap.dedent(body))
    return p


def plan(p, overrides=()):
    return plan_pipeline(p, overrides, registries=build_registries(pm()))


EVAL = f"""
name: ev
workspace: ws
steps:
  takes:
    uses: formats.load
    with: {{paths: [{str(AMC[0])!r}], fps: 24}}
  evaluation:
    uses: analyses.clean_eval
    inputs: {{locomotion: takes}}
    with:
      n_test: 1
"""


def test_nested_cleaner_parameters_are_validated_at_plan_time_via_set(tmp_path):
    p = write(tmp_path, EVAL)
    item = 'evaluation.cleaner={"treshold": 0.6}'
    with pytest.raises(ConfigError) as err:
        plan(p, [item])
    msg = str(err.value)
    assert f"{p}:11" in msg and f"--set {item!r}" in msg, msg  # the step's `with:` line and the --set item
    assert "step 'evaluation'" in msg and "unknown parameter 'cleaner.treshold'" in msg, msg
    assert "parameters of cleaners.mdm" in msg and "did you mean 'threshold'" in msg, msg
    assert main(["--no-entry-points", "plan", str(p), "--set", item]) == 2
    plan(p, ['evaluation.cleaner={"threshold": 0.6}'])  # the right spelling plans


def test_nested_parameters_in_yaml_point_at_their_line(tmp_path):
    p = write(tmp_path, EVAL + "      cleaner:\n        k: 5\n        mode: avg\n")
    with pytest.raises(ConfigError) as err:
        plan(p)
    msg = str(err.value)
    assert f"{p}:15" in msg and "parameter 'cleaner.mode'" in msg and "'avg'" in msg, msg


def test_nested_key_may_name_a_sibling_parameter(tmp_path):
    body = """
    name: n
    steps:
      a: {uses: analyses.toy_nested, with: {target: toy_add, options: {ad: 1}}}
    """
    with pytest.raises(ConfigError, match=r"unknown parameter 'options.ad'.*analyses.toy_add.*did you mean 'add'"):
        plan(write(tmp_path, body))
    with pytest.raises(ConfigError, match=r"'options.n'.*greater than or equal to 1"):
        plan(write(tmp_path, body.replace("target: toy_add, options: {ad: 1}", "options: {n: 0}")))
    with pytest.raises(ConfigError, match=r"p.yaml:4.*'options'.*unknown component 'analyses.toy_nope'"):
        plan(write(tmp_path, body.replace("toy_add", "toy_nope")))
    with pytest.raises(ConfigError, match="'fixed.sclae'"):
        plan(write(tmp_path, body.replace("options: {ad: 1}", "fixed: {sclae: 2}")))
    planned = plan(write(tmp_path, body.replace("ad: 1", "add: 1")))
    assert planned["a"].component.params.options == {"add": 1}  # still the dict the user gave


@pytest.mark.parametrize(
    "body, line, words",
    [
        # an index over a summary table
        (
            """
     motions: {uses: analyses.toy_motions}
     summary: {uses: analyses.clip_summary, input: motions}
     tree: {uses: indexes.kdtree, input: summary}
     """,
            5,
            [
                "input 'features' of indexes.kdtree takes a features dataset",
                "step 'summary' (analyses.clip_summary) writes a table dataset",
            ],
        ),
        # features of an index
        (
            """
     motions: {uses: analyses.toy_motions}
     fe: {uses: features.end_effectors, input: motions}
     tree: {uses: indexes.kdtree, input: fe}
     again: {uses: features.end_effectors, input: tree}
     """,
            6,
            ["takes a motions dataset", "writes an index dataset"],
        ),
        # a matcher whose database is a motions dataset
        (
            """
     motions: {uses: formats.load, with: {paths: ["AMC"]}}
     lng: {uses: matchers.search, inputs: {database: motions, query: motions}}
     """,
            4,
            ["input 'database' of matchers.search takes an index or features dataset", "writes a motions dataset"],
        ),
    ],
)
def test_inputs_of_the_wrong_kind_are_refused_at_plan_time(tmp_path, body, line, words):
    p = write(
        tmp_path,
        "name: k\nsteps:\n"
        + textwrap.indent(textwrap.dedent(body).strip("\n"), "  ").replace("AMC", str(AMC[0]))
        + "\n",
    )
    with pytest.raises(ConfigError) as err:
        plan(p)
    msg = str(err.value)
    assert f"{p}:{line}" in msg, msg
    for w in words:
        assert w in msg, msg


def test_undeclared_kinds_are_not_checked(tmp_path):
    # toy_motions (an analysis declaring no output kind) feeds a feature set and a summary
    p = write(
        tmp_path,
        """
    name: ok
    steps:
      motions: {uses: analyses.toy_motions}
      fe: {uses: features.end_effectors, input: motions}
      tree: {uses: indexes.kdtree, input: fe}
      lng: {uses: matchers.search, inputs: {database: tree, query: motions}}
      summary: {uses: analyses.clip_summary, input: motions}
    """,
    )
    assert [s.step_id for s in plan(p).steps] == ["motions", "fe", "tree", "lng", "summary"]


def test_unknown_executor_is_a_plan_time_error(tmp_path):
    p = write(
        tmp_path,
        """
    name: x
    executor: daks
    steps:
      a: {uses: analyses.toy_source}
    """,
    )
    with pytest.raises(
        ConfigError, match=rf"{p}:3: unknown executor 'daks' \(did you mean 'dask'\?\); registered: .*local"
    ):
        plan(p)
    assert main(["--no-entry-points", "plan", str(p)]) == 2
    with pytest.raises(ConfigError, match="unknown executor 'daks'"):
        run_pipeline(p, pm=pm())
    assert not (tmp_path / "runs").exists()


def test_glob_matching_no_file_warns_at_plan_time(tmp_path, caplog, capsys):
    p = write(
        tmp_path,
        f"""
    name: g
    steps:
      motions:
        uses: formats.load
        with: {{paths: [{str(AMC[0])!r}, "nowhere/**/*.bvh"]}}
      markers:
        uses: formats.load_markers
        with: {{paths: ["*.trc"]}}
    """,
    )
    planned = plan(p)
    assert planned.warnings == [
        f"{p}:6: step 'motions': pattern 'nowhere/**/*.bvh' of `paths` matches no file (relative to {tmp_path})",
        f"{p}:9: step 'markers': pattern '*.trc' of `paths` matches no file (relative to {tmp_path})",
    ]
    assert planned.warnings[0] in caplog.text
    caplog.clear()
    assert main(["--no-entry-points", "plan", str(p)]) == 0
    assert "matches no file" in caplog.text and "plan is valid" in capsys.readouterr().out


def test_typos_in_model_typed_parameters_suggest_from_the_nested_model():
    p = REPO / "pipelines" / "clean.yaml"
    with pytest.raises(
        ConfigError,
        match=r"unknown parameter 'calibrated.false_alarmm'.*did you mean 'false_alarm'\?\); known: false_alarm",
    ):
        plan(p, ["mdm.calibrated.false_alarmm=0.01"])
