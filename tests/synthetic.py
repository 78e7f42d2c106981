"""Test aliases for the synthetic humanoid of :mod:`mocapflow.framework.testing`."""

from __future__ import annotations

from mocapflow.framework.testing import synthetic_motion as random_motion
from mocapflow.framework.testing import synthetic_skeleton as humanoid

__all__ = ["humanoid", "random_motion"]
