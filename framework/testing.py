"""The conformance suite that every component (built-in or third-party) should pass.

In the spirit of scikit-learn's ``parametrize_with_checks``::

    from mocapflow.framework.testing import parametrize_with_checks
    from my_plugin import MyFeatures, MyMatcher

    @parametrize_with_checks([MyFeatures, MyMatcher])
    def test_conformance(component_class, check):
        check(component_class)

Components with required parameters define ``test_params``; matchers and cleaners are
checked by :mod:`.conformance`. The synthetic humanoid mocapflow tests with is here too.
"""

from __future__ import annotations

import pickle
import tempfile
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from .components import Component, FeatureSet, Format, Index, Params
from .conformance import ReferenceIndex, check_cleaner, check_matcher, check_matcher_pipeline, synthetic_space
from .database import MotionDatabase
from .registry import KINDS
from .synthetic import _instance, synthetic_motion, synthetic_skeleton


def check_declaration(cls: type[Component]) -> None:
    """Name, kind, version, docstring and input slots are declared properly."""
    assert issubclass(cls, Component), f"{cls} does not derive from mocapflow.framework.Component"
    assert cls.kind in KINDS, f"{cls.__name__}.kind {cls.kind!r} is not one of {KINDS}"
    assert isinstance(cls.name, str) and cls.name.isidentifier() and cls.name == cls.name.lower(), (
        f"{cls.__name__}.name {cls.name!r} must be a snake_case identifier"
    )
    assert isinstance(cls.version, str) and cls.version, f"{cls.__name__}.version must be a non-empty str"
    assert (cls.__doc__ or "").strip(), (
        f"{cls.__name__} needs a docstring (its first line is shown by `mocapflow plugins`)"
    )
    assert isinstance(cls.inputs, Mapping) and all(
        isinstance(k, str) and isinstance(v, bool) for k, v in cls.inputs.items()
    ), f"{cls.__name__}.inputs must map slot names to required flags"


def check_params_model(cls: type[Component]) -> None:
    """``Params`` is a frozen pydantic model that rejects unknown keys."""
    assert isinstance(cls.Params, type) and issubclass(cls.Params, Params), (
        f"{cls.__name__}.Params must subclass mocapflow.framework.Params"
    )
    assert cls.Params.model_config.get("frozen"), f"{cls.__name__}.Params must be frozen"
    assert cls.Params.model_config.get("extra") == "forbid", f"{cls.__name__}.Params must forbid unknown keys"
    try:
        cls.Params(**{**(cls.test_params or {}), "surely_not_a_parameter__": 1})
    except ValidationError:
        pass
    else:  # pragma: no cover - reached only by a broken component
        raise AssertionError(f"{cls.__name__}.Params accepted an unknown key")


def check_init_and_clone(cls: type[Component]) -> None:
    """``__init__`` only stores params; ``get_params`` round-trips; clones and pickles are equal."""
    inst = _instance(cls)
    if inst is None:
        return
    assert inst.params == cls(inst.get_params()).params, f"{cls.__name__}: get_params() does not round-trip"
    assert inst.clone().params == inst.params
    fitted = [k for k in vars(inst) if k.endswith("_") and not k.startswith("_")]
    assert not fitted, f"{cls.__name__}.__init__ sets fitted attributes {fitted}: fit state belongs to fit()/build()"
    again = pickle.loads(pickle.dumps(inst))
    assert again.params == inst.params, f"{cls.__name__} does not survive pickling (needed by process pools)"


def check_feature_set(cls: type[Component]) -> None:
    """Transform gives (T, dim) finite float32, deterministic, clip by clip."""
    if not issubclass(cls, FeatureSet):
        return
    inst = _instance(cls)
    if inst is None:
        return
    db = MotionDatabase([synthetic_motion(50, seed=1), synthetic_motion(1, seed=2), synthetic_motion(20, seed=3)])
    if cls.requires_fit:
        inst.fit(db)
    x = inst.transform(db)
    assert x.dtype == np.float32 and x.shape == (db.n_frames, inst.dim), f"{cls.__name__}: got {x.dtype} {x.shape}"
    assert np.all(np.isfinite(x)), f"{cls.__name__}: non-finite features"
    np.testing.assert_array_equal(
        x[db.offsets[2] :], inst.transform(db.motions[2]), err_msg="features must not depend on other clips"
    )


def check_index(cls: type[Component]) -> None:
    """Exact kNN equals brute force; results are sorted and padded; save/load keeps answers."""
    if not issubclass(cls, Index) or not cls.supports_knn:
        return
    inst = _instance(cls)
    if inst is None or type(inst).query is Index.query:
        return
    rng = np.random.default_rng(0)
    data = rng.normal(size=(300, 6)).astype(np.float32)
    q = rng.normal(size=(7, 6)).astype(np.float32)
    inst.build(data)
    dist, ids = inst.query(q, 5)
    assert dist.shape == ids.shape == (7, 5)
    brute = np.sqrt(((q[:, None, :].astype(np.float64) - data[None].astype(np.float64)) ** 2).sum(-1))
    np.testing.assert_allclose(dist, np.sort(brute, axis=1)[:, :5], rtol=1e-4, atol=1e-4)
    assert np.all(np.diff(dist, axis=1) >= 0)
    with tempfile.TemporaryDirectory() as tmp:
        inst.save(Path(tmp))
        loaded = type(inst).load(Path(tmp))
        d2, i2 = loaded.query(q, 5)
    np.testing.assert_allclose(d2, dist, rtol=1e-6)


def check_format_round_trip(cls: type[Component]) -> None:
    """A writer's output read back by the same format gives the same joint positions."""
    if not (issubclass(cls, Format) and cls.can_write() and cls.read is not Format.read and cls.produces == "motion"):
        return
    inst = _instance(cls)
    if inst is None or not cls.extensions:
        return
    m = synthetic_motion(10, seed=4)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"clip{cls.extensions[0]}"
        try:
            inst.write(m, path)
        except NotImplementedError:
            return
        back = inst.read(path)
    assert back.n_frames == m.n_frames
    np.testing.assert_allclose(back.canonical_positions(), m.canonical_positions(), atol=1e-4)


CHECKS: tuple[Callable[[type[Component]], None], ...] = (
    check_declaration,
    check_params_model,
    check_init_and_clone,
    check_feature_set,
    check_index,
    check_format_round_trip,
    check_matcher,
    check_matcher_pipeline,
    check_cleaner,
)


def check_component(cls: type[Component]) -> None:
    """Run every check on one component class (raises AssertionError on the first failure)."""
    for check in CHECKS:
        check(cls)


def parametrize_with_checks(classes: Iterable[type[Component]]) -> Any:
    """A ``pytest.mark.parametrize`` over (component_class, check) pairs."""
    import pytest

    classes = list(classes)
    cases = [(cls, check) for cls in classes for check in CHECKS]
    ids = [f"{cls.kind}.{cls.name}-{check.__name__}" for cls, check in cases]
    return pytest.mark.parametrize("component_class, check", cases, ids=ids)


__all__ = [
    "CHECKS",
    "ReferenceIndex",
    "check_cleaner",
    "check_component",
    "check_matcher",
    "check_matcher_pipeline",
    "parametrize_with_checks",
    "synthetic_motion",
    "synthetic_skeleton",
    "synthetic_space",
]
