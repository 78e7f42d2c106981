"""``features.pca``: F_pca^n, principal components of joint positions in the body frame.

Krüger et al. 2010 §3.1: "n principal components on joint positions in body frame,
pre-computed on a fixed database" (they fit on all of HDM05). The model (mean and
components) is fitted on the step's ``reference`` input (a motions dataset) or, without
one, on the motions themselves; it is saved in the step's output (``pca_model.npz``) and a
later step reuses it by naming this features step as its ``reference``::

    pca16:    {uses: features.pca, inputs: {motions: hdm05, reference: hdm05}, with: {n_components: 16}}
    pca16cmu: {uses: features.pca, inputs: {motions: cmu, reference: pca16}}
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar, cast

import numpy as np
from pydantic import Field

from mocapflow.framework import FeatureSet, MotionDatabase
from mocapflow.framework import Params as BaseParams
from mocapflow.framework.errors import DataError
from mocapflow.framework.joints import CANONICAL_JOINTS
from mocapflow.framework.motion import Motion

from .end_effectors import body_frame_positions

#: Canonical joints whose body-frame positions are compressed (present in CMU, HDM05 and
#: the common BVH skeletons; the root is the origin and carries no information).
_NOT_PCA = ("root", "upperback", "headtop", "lclavicle", "lfingers", "rclavicle", "rfingers")
PCA_JOINTS: tuple[str, ...] = tuple(j for j in CANONICAL_JOINTS if j not in _NOT_PCA)

MODEL_FILE = "pca_model.npz"


class PosePCA(FeatureSet):
    """Projection of body-frame joint positions on their first ``n_components`` principal axes.

    Attributes
    ----------
    mean_ : ndarray of shape (3 * len(joints),), metres
    components_ : ndarray of shape (n_components, 3 * len(joints))
        Orthonormal rows, by decreasing variance.
    explained_variance_ratio_ : ndarray of shape (n_components,)
    """

    name: ClassVar[str] = "pca"
    requires_fit: ClassVar[bool] = True

    class Params(BaseParams):
        n_components: int = Field(16, ge=1, description="principal components kept (paper: 8, 16, 25)")
        joints: tuple[str, ...] = Field(
            PCA_JOINTS, min_length=1, description="canonical joints whose positions are compressed"
        )

    params: Params

    @property
    def dim(self) -> int:
        return self.params.n_components

    def _poses(self, motion: Motion) -> np.ndarray:
        return body_frame_positions(motion, tuple(self.params.joints)).reshape(motion.n_frames, -1)

    def fit(self, data: MotionDatabase | Motion) -> PosePCA:
        """Fit mean and principal axes on every frame of ``data`` (covariance eigendecomposition)."""
        motions = [data] if isinstance(data, Motion) else list(data.motions)
        n_dim = 3 * len(self.params.joints)
        if self.params.n_components > n_dim:
            raise DataError(f"{self.key()}: n_components={self.params.n_components} > {n_dim} position coordinates")
        total, s1, s2 = 0, np.zeros(n_dim), np.zeros((n_dim, n_dim))
        for m in motions:  # streamed: the reference database never needs to be one array
            x = self._poses(m)
            total += len(x)
            s1 += x.sum(0)
            s2 += x.T @ x
        if total < 2:
            raise DataError(f"{self.key()}: need at least 2 reference frames to fit, got {total}")
        mean = s1 / total
        cov = (s2 - total * np.outer(mean, mean)) / (total - 1)
        val, vec = np.linalg.eigh(cov)
        order = np.argsort(val)[::-1][: self.params.n_components]
        comps = vec[:, order].T
        # deterministic signs: the largest |coefficient| of each axis is positive
        comps *= np.sign(comps[np.arange(len(comps)), np.abs(comps).argmax(1)])[:, None]
        self.mean_, self.components_ = mean, comps
        self.explained_variance_ratio_ = val[order] / max(val.sum(), 1e-300)
        self.n_fit_frames_ = total
        return self

    def transform_motion(self, motion: Motion) -> np.ndarray:
        if not hasattr(self, "components_"):
            raise DataError(f"{self.key()}: not fitted (fit() on a reference database or load_state())")
        return cast("np.ndarray", ((self._poses(motion) - self.mean_) @ self.components_.T).astype(np.float32))

    def save_state(self, directory: Path) -> None:
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        np.savez(
            d / MODEL_FILE,
            mean=self.mean_,
            components=self.components_,
            explained_variance_ratio=self.explained_variance_ratio_,
            joints=np.array(json.dumps(list(self.params.joints))),
            n_fit_frames=self.n_fit_frames_,
        )

    def load_state(self, directory: Path) -> PosePCA:
        p = Path(directory) / MODEL_FILE
        if not p.is_file():
            raise DataError(f"{self.key()}: {Path(directory)} holds no fitted PCA model ({MODEL_FILE})")
        with np.load(p) as z:
            joints = tuple(json.loads(str(z["joints"])))
            if joints != tuple(self.params.joints) or z["components"].shape[0] < self.params.n_components:
                raise DataError(
                    f"{self.key()}: model in {p} was fitted for joints {joints} with "
                    f"{z['components'].shape[0]} components; this step asks for {self.params.n_components}"
                )
            self.mean_ = z["mean"]
            self.components_ = z["components"][: self.params.n_components]
            self.explained_variance_ratio_ = z["explained_variance_ratio"][: self.params.n_components]
            self.n_fit_frames_ = int(z["n_fit_frames"])
        return self
