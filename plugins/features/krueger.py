"""Plugin module: the feature sets of Krüger et al. 2010 (end-effector and PCA features)."""
from __future__ import annotations

from mocapflow.framework import hookimpl

from .end_effectors import EndEffectorFeatures
from .pca import PosePCA


@hookimpl
def register_features() -> list[type]:
    return [EndEffectorFeatures, PosePCA]
