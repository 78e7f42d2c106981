"""Headless matplotlib for the PNGs that steps and commands write (imported lazily: matplotlib
is never loaded at start-up)."""

from __future__ import annotations

from typing import Any

from .errors import ConfigError


def pyplot(what: str = "plots") -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (runs have no screen).

    Parameters
    ----------
    what : str
        What needs it, for the error message (e.g. ``"MDM heatmaps"``).

    Raises
    ------
    ConfigError
        matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - matplotlib is a dependency
        raise ConfigError(f"{what} need matplotlib (a mocapflow dependency): pip install matplotlib") from exc
    return plt
