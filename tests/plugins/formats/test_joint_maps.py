"""Skeleton naming dialects are plugins (``register_joint_maps``): the built-in dialects map
the corpus exactly as before, and a third-party dialect makes a new rig readable."""

from __future__ import annotations

import types

import pytest
from test_formats_bvh import REST, tiny_bvh

from mocapflow.framework import hookimpl, plugins
from mocapflow.framework.errors import PluginError
from mocapflow.framework.joints import JointMap, canonical_map
from mocapflow.framework.plugins import build_registries, get_plugin_manager
from mocapflow.plugins.formats.bvh import read_bvh
from mocapflow.plugins.formats.joint_maps import ACCLAIM, BVH_COMMON, JOINT_MAPS

STUDIO = {"Hips": "pelvis_jnt", "Spine": "spine_jnt", "Head": "skull_jnt", "LeftUpLeg": "thigh_l_jnt"}


def _studio_bvh(tmp_path):
    text = tiny_bvh([REST] * 3)
    for a, b in STUDIO.items():
        text = text.replace(f" {a}\n", f" {b}\n")
    path = tmp_path / "studio.bvh"
    path.write_text(text)
    return path


def _plugin(*maps):
    mod = types.ModuleType("studio_rig")

    @hookimpl
    def register_joint_maps():
        return list(maps)

    mod.register_joint_maps = register_joint_maps
    return mod


@pytest.fixture
def fresh_maps(monkeypatch):
    monkeypatch.setattr(plugins, "_JOINT_MAPS", {})


def test_builtin_dialects():
    names = ["Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "Spine", "Spine1", "Head"]
    m = canonical_map(names, "bvh", maps=JOINT_MAPS)
    assert m["root"] == 0 and m["lhip"] == 1 and m["lankle"] == 3 and m["head"] == 6
    # Acclaim names: only the exact ASF dialect applies to ASF files
    asf = ["root", "lfemur", "ltibia", "lfoot", "rfemur", "lhumerus", "rhumerus"]
    assert canonical_map(asf, "amc", maps=JOINT_MAPS) == ACCLAIM.apply(asf)
    assert canonical_map(asf, "bvh", maps=JOINT_MAPS)["lknee"] == 2  # a BVH written from an ASF
    # a skeleton named with the canonical vocabulary maps to itself
    assert BVH_COMMON.apply(["root", "lhip", "head"]) == {"root": 0, "lhip": 1, "head": 2}
    # one source joint never gets two canonical names (chest/upperback share candidates)
    m = canonical_map(["Hips", "Spine"], "bvh", maps=JOINT_MAPS)
    assert len(set(m.values())) == len(m)


def test_namespace_prefixes_are_tried_without_the_prefix():
    names = ["Hips", "LeftUpLeg", "LeftLeg", "LeftFoot", "Spine", "Spine1", "Head", "LeftArm", "LeftHand"]
    bare = canonical_map(names, "bvh", maps=JOINT_MAPS)
    assert canonical_map(["mixamorig:" + n for n in names], "bvh", maps=JOINT_MAPS) == bare
    assert canonical_map(["a:b:" + n for n in names], None, maps=JOINT_MAPS) == bare


def test_a_plugin_adds_a_dialect(tmp_path, fresh_maps):
    path = _studio_bvh(tmp_path)
    build_registries(get_plugin_manager(entry_points=False))
    assert "root" not in read_bvh(path).skeleton.canonical  # nobody knows this rig yet
    studio = JointMap(
        "studio",
        {"root": ("pelvis_jnt",), "lowerback": ("spine_jnt",), "head": ("skull_jnt",), "lhip": ("thigh_l_jnt",)},
        formats=("bvh",),
    )
    regs = build_registries(get_plugin_manager(entry_points=False, extra=[_plugin(studio)]))
    assert regs.joint_map_providers["studio"] == "studio_rig"
    skel = read_bvh(path).skeleton
    assert {c: skel.names[i] for c, i in skel.canonical.items()} == {
        "root": "pelvis_jnt",
        "lowerback": "spine_jnt",
        "head": "skull_jnt",
        "lhip": "thigh_l_jnt",
    }


def test_bad_joint_map_plugins_are_reported(fresh_maps):
    pm = get_plugin_manager(entry_points=False, extra=[_plugin("not a map")])
    build_registries(pm)
    assert any(f.plugin == "studio_rig" and "JointMap" in f.error for f in pm.failures)
    with pytest.raises(PluginError, match="registered by both"):
        build_registries(get_plugin_manager(entry_points=False, extra=[_plugin(JointMap("acclaim", {}))]))
    with pytest.raises(ValueError, match="unknown canonical joints"):
        JointMap("x", {"tail": ("Tail",)})
