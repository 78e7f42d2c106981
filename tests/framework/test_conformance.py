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


def test_every_matcher_and_cleaner_is_exercised():
    """Each matcher is checked on the synthetic space (match) or pipeline (own step); each cleaner by check_cleaner."""
    from mocapflow.framework import Cleaner, Matcher

    matchers = dict(_REGS["matchers"])
    assert {"lng", "sdtw", "logical", "relational", "template"} <= set(matchers)
    for name, cls in matchers.items():
        assert cls.match is not Matcher.match or getattr(cls, "test_pipeline", None), (
            f"matchers.{name} is not exercised"
        )
    cleaners = dict(_REGS["cleaners"])
    assert "mdm" in cleaners
    for name, cls in cleaners.items():
        assert cls.detect is not Cleaner.detect, f"cleaners.{name} is not exercised"
