"""mocapflow.framework: the core. It knows no algorithm; plugins provide them.

The public surface is this facade (``__all__``) and :mod:`mocapflow.framework.testing`.
Importing it has no side effects: the plugin manager is built by
:func:`get_plugin_manager`.
"""
from __future__ import annotations

from .components import Analysis, Cleaner, Component, FeatureSet, Format, Index, Matcher, Params
from .context import StepContext
from .database import MotionDatabase
from .datasets import Dataset, FeatureMatrix, StepOutput
from .errors import ConfigError, DataError, MocapflowError, ParseError, PipelineError, PluginError
from .joints import CANONICAL_JOINTS
from .markers import Markers
from .motion import Motion, forward_kinematics
from .plugins import build_registries, get_plugin_manager, hookimpl, load_registries
from .registry import Registries, Registry
from .skeleton import Skeleton

__version__ = "0.1.0"

__all__ = [
    "Analysis", "CANONICAL_JOINTS", "Cleaner", "Component", "ConfigError", "DataError", "Dataset",
    "FeatureMatrix", "FeatureSet", "Format", "Index", "Markers", "Matcher", "MocapflowError", "Motion",
    "MotionDatabase", "Params", "ParseError", "PipelineError", "PluginError", "Registries",
    "Registry", "Skeleton", "StepContext", "StepOutput", "__version__", "build_registries",
    "forward_kinematics", "get_plugin_manager", "hookimpl", "load_registries",
]
