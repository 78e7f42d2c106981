"""Every registered component, built-in or installed, passes the conformance suite."""
from __future__ import annotations

from mocapflow.framework import load_registries
from mocapflow.framework.registry import KINDS
from mocapflow.framework.testing import parametrize_with_checks

_REGS = load_registries(entry_points=False)
ALL = [cls for kind in KINDS for _, cls in _REGS[kind]]


@parametrize_with_checks(ALL)
def test_builtin_component_conforms(component_class, check):
    check(component_class)


def test_every_kind_is_registered_through_hooks():
    assert "load" in _REGS["formats"] and "clip_summary" in _REGS["analyses"]
