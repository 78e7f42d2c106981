"""mocapflow.framework: the core. It knows no algorithm; plugins provide them.

The public surface is this facade (``__all__``) and :mod:`mocapflow.framework.testing`.
Importing it has no side effects and is cheap: each name is imported from its module on
first use (PEP 562), so ``mocapflow --help`` or a plugin module that only needs
``hookimpl`` does not pay for NumPy, PyArrow and pydantic. The plugin manager is built by
:func:`get_plugin_manager`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

# public name -> the submodule that defines it
_EXPORTS: dict[str, str] = {
    **dict.fromkeys(
        ("Analysis", "Cleaner", "Component", "FeatureSet", "Format", "Index", "Matcher", "Params"), "components"
    ),
    "CleanedClip": "cleaning",
    "StepContext": "context",
    "MotionDatabase": "database",
    **dict.fromkeys(("Dataset", "FeatureMatrix", "StepOutput"), "datasets"),
    **dict.fromkeys(
        ("ConfigError", "DataError", "MocapflowError", "ParseError", "PipelineError", "PluginError"), "errors"
    ),
    "CANONICAL_JOINTS": "joints",
    "Markers": "markers",
    **dict.fromkeys(("MatchParams", "QueryMatches", "SearchSpace"), "matching"),
    **dict.fromkeys(("Motion", "forward_kinematics"), "motion"),
    **dict.fromkeys(("build_registries", "get_plugin_manager", "hookimpl", "load_registries"), "plugins"),
    **dict.fromkeys(("Registries", "Registry"), "registry"),
    "Removed": "params",
    "Skeleton": "skeleton",
}

# a literal list, so type checkers take these names as exported (tests check it against _EXPORTS)
__all__ = [
    "Analysis",
    "CANONICAL_JOINTS",
    "CleanedClip",
    "Cleaner",
    "Component",
    "ConfigError",
    "DataError",
    "Dataset",
    "FeatureMatrix",
    "FeatureSet",
    "Format",
    "Index",
    "Markers",
    "MatchParams",
    "Matcher",
    "MocapflowError",
    "Motion",
    "MotionDatabase",
    "Params",
    "ParseError",
    "PipelineError",
    "PluginError",
    "QueryMatches",
    "Registries",
    "Registry",
    "Removed",
    "SearchSpace",
    "Skeleton",
    "StepContext",
    "StepOutput",
    "__version__",
    "build_registries",
    "forward_kinematics",
    "get_plugin_manager",
    "hookimpl",
    "load_registries",
]


def __getattr__(name: str) -> Any:
    if name == "__version__":
        try:
            from mocapflow import __version__
        except ImportError:  # an editable install older than the top-level package: its metadata
            from importlib.metadata import version

            return version("mocapflow")
        return __version__
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})


if TYPE_CHECKING:  # for type checkers and IDEs; never executed
    from .cleaning import CleanedClip
    from .components import Analysis, Cleaner, Component, FeatureSet, Format, Index, Matcher, Params
    from .context import StepContext
    from .database import MotionDatabase
    from .datasets import Dataset, FeatureMatrix, StepOutput
    from .errors import ConfigError, DataError, MocapflowError, ParseError, PipelineError, PluginError
    from .joints import CANONICAL_JOINTS
    from .markers import Markers
    from .matching import MatchParams, QueryMatches, SearchSpace
    from .motion import Motion, forward_kinematics
    from .params import Removed
    from .plugins import build_registries, get_plugin_manager, hookimpl, load_registries
    from .registry import Registries, Registry
    from .skeleton import Skeleton
