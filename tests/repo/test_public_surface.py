"""The deprecation policy, enforced (docs/pipelines.md, "Deprecation policy"): the public
surface (facade names and parameters, CLI commands and options, every component's
parameters) against its committed snapshot ``tests/data/public_surface.json``; and the shims
of last month's breaks: ``Motion.write``, ``matchers.lng``'s ``plots``, ``matchers.template``'s
``features`` and ``cutoff``."""

from __future__ import annotations

import json
import warnings
from importlib.util import find_spec
from pathlib import Path

import public_surface  # tests/ is on the path (rootdir conftest)
import pytest

ROOT = Path(__file__).resolve().parents[2]

#: components that exist only with an optional dependency: (name prefix, module it needs)
OPTIONAL = (("indexes.hnsw", "hnswlib"),)


@pytest.fixture(scope="module")
def surfaces() -> tuple[dict, dict]:
    snap = json.loads(public_surface.SNAPSHOT.read_text())
    for prefix, module in OPTIONAL:
        if find_spec(module) is None:
            snap["components"] = [n for n in snap["components"] if not n.startswith(prefix)]
    return snap, public_surface.surface()


def test_nothing_public_was_removed_without_a_shim(surfaces) -> None:
    snap, now = surfaces
    removed, _ = public_surface.diff(snap, now)
    lines = [f"  {section}: {name}" for section, names in removed.items() for name in names]
    assert not lines, (
        "public names removed without a shim (docs/pipelines.md, 'Deprecation policy'): keep each for one release "
        "with a warning naming its replacement (a method or function that warns, a hidden CLI option that warns, "
        "Params.removed for a parameter); once a shim has served its release, record its removal with "
        "`python tests/public_surface.py --write`:\n" + "\n".join(lines)
    )


def test_the_snapshot_records_every_public_name(surfaces) -> None:
    """Additions are recorded, so that removing them later is caught too."""
    snap, now = surfaces
    _, added = public_surface.diff(snap, now)
    lines = [f"  {section}: {name}" for section, names in added.items() for name in names]
    assert not lines, "new public names: record them with `python tests/public_surface.py --write`:\n" + "\n".join(
        lines
    )


def test_motion_write_warns_and_writes(tmp_path) -> None:
    import mocapflow

    walk = mocapflow.read(ROOT / "examples" / "data" / "cmu" / "16" / "16_15.amc").slice(0, 10)
    with pytest.warns(DeprecationWarning, match=r"mocapflow\.write\(motion, path\)"):
        walk.write(tmp_path / "walk.bvh")
    assert mocapflow.read(tmp_path / "walk.bvh").n_frames == 10


def test_removed_parameters_warn_name_their_replacement_and_refuse_what_has_none(registries) -> None:
    from mocapflow.framework.errors import ConfigError

    template = registries.resolve("matchers.template")
    with pytest.warns(DeprecationWarning) as got:
        t = template({"features": "key", "cutoff": "rivals"})
    text = " ".join(str(w.message) for w in got)
    assert "'features'" in text and "key features" in text and "'cutoff'" in text and "rival rule" in text
    assert t.get_params() == template().get_params()  # the same step, the same fingerprint
    assert len(t.params.deprecations()) == 2
    for bad in ({"features": "all"}, {"cutoff": "threshold"}):
        with pytest.raises(ConfigError, match="has no equivalent"):
            template(bad)

    lng = registries.resolve("matchers.lng")
    with pytest.warns(DeprecationWarning, match=r"matchers\.search's `plots`"):
        m = lng({"plots": 2, "exact": False})
    assert m.params.removed_values() == {"plots": 2}


def test_a_pipeline_of_last_month_plans_with_a_warning_at_its_line(tmp_path) -> None:
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import plan_pipeline

    cmu = ROOT / "examples" / "data" / "cmu"
    p = tmp_path / "old.yaml"
    p.write_text(
        f"""name: old
workspace: {tmp_path / "ws"}
steps:
  motions: {{uses: formats.load, with: {{paths: ["{cmu}/16/16_15.amc"], fps: 30}}}}
  fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
  tree: {{uses: indexes.kdtree, input: fe15}}
  lng:
    uses: matchers.lng
    inputs: {{database: tree, query: motions}}
    with: {{queries: ["16_15:0-30"], exact: false, plots: 1}}
"""
    )
    from mocapflow.framework.plugins import build_registries

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        plan = plan_pipeline(p, registries=build_registries(get_plugin_manager(entry_points=False)))
    assert any("old.yaml:10" in w and "'plots' is deprecated" in w for w in plan.warnings), plan.warnings
