"""The null of the fused evidence: what the detectors (:mod:`.detectors`) give on clean motion
similar to the take, and the conformal test that holds a stated false-alarm rate.

1. *Per-joint robust standardisation*: each detector's evidence at joint ``j`` becomes
   ``z = (e - median_j) / scale_j`` with the median and the 0.95 quantile over the median
   (floored at :data:`.detectors.SCALE_FLOOR`) of that detector at that joint on the null
   cells.
2. *Fusion*: one statistic per (frame, joint), ``S = max_k z_k`` (the deciding detector is
   the argmax).
3. *Conformal p-value* against the null pooled over joints: ``p = (1 + #{S_null >= S}) /
   (n + 1)``; a cell is flagged when ``p <= false_alarm_rate``, i.e. ``S`` above the null's
   ``1 - rate`` quantile. Where the context null holds fewer than :data:`MIN_EXCEEDANCES`
   cells beyond that quantile (a small context, a small rate), the quantile comes from the
   null shipped with the package (``null.json``: the same statistic on development takes no
   evaluation holds out, :func:`build_shipped`), scaled to the context null at the
   smallest rate it resolves.
4. *Carried to the take*: the threshold times the ratio of the take's :data:`BULK` quantile
   of ``S`` to the null's (:meth:`Null.take_threshold`).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, cast

import numpy as np

from .detectors import DETECTORS, SCALE_FLOOR

#: The context null sets a quantile only when at least this many of its cells lie beyond it.
MIN_EXCEEDANCES = 10

#: The quantile of the fused statistic that carries a null's threshold to the take.
BULK = 0.9

SHIPPED = Path(__file__).with_name("null.json")


@dataclass
class Null:
    """``center``, ``scale`` (m, K) per joint and detector; ``pooled`` the sorted fused
    statistics of the null cells (n,); ``alphas`` / ``taus`` the shipped quantile table
    (rate -> threshold, rates descending); ``source`` (``context``, ``shipped``), ``cells``,
    ``clips`` (the context spans used), ``fallback`` (why the shipped null was used)."""

    center: np.ndarray
    scale: np.ndarray
    pooled: np.ndarray
    alphas: np.ndarray
    taus: np.ndarray
    source: str
    clips: list[str] = field(default_factory=list)
    fallback: str = ""

    @property
    def cells(self) -> int:
        return int(len(self.pooled))

    def statistic(self, ev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fused statistic (T, m) and the index of the deciding detector (T, m) of the
        evidence ``ev`` (T, m, K)."""
        z = (ev - self.center) / self.scale
        return z.max(axis=-1), np.argmax(z, axis=-1)

    def bulk(self) -> float:
        """The null's :data:`BULK` quantile of the fused statistic."""
        if len(self.pooled):
            return float(np.quantile(self.pooled, BULK))
        return shipped_threshold(self.alphas, self.taus, 1.0 - BULK)

    def take_threshold(self, rate: float, s: np.ndarray) -> float:
        """:meth:`threshold` carried to the take by the ratio of the take's :data:`BULK`
        quantile of its statistics ``s`` to the null's (errors touch a few per cent of the
        cells at most, so the bulk is the take's clean motion: a livelier take than its null
        is not an error everywhere, a calmer one keeps its power)."""
        tau = self.threshold(rate)
        if s.size < 100:
            return tau
        return tau * max(float(np.quantile(s, BULK)), 1e-6) / max(self.bulk(), 1e-6)

    def threshold(self, rate: float) -> float:
        """The level of ``S`` flagged at ``rate`` (module doc, step 3): the context null's
        ``1 - rate`` quantile, or below its resolution ``a0`` (:data:`MIN_EXCEEDANCES` cells
        beyond) its quantile at ``a0`` carried by the shipped tail's shape,
        ``tau(a0) * tau_shipped(rate) / tau_shipped(a0)``; the shipped table alone without
        a context null."""
        n = len(self.pooled)
        if not n:
            return shipped_threshold(self.alphas, self.taus, rate)
        a0 = max(rate, min(MIN_EXCEEDANCES / (n + 1.0), 0.5))
        k = int(np.ceil((n + 1) * (1.0 - a0))) - 1
        tau0 = float(self.pooled[min(max(k, 0), n - 1)])
        if a0 <= rate:
            return tau0
        return tau0 * shipped_threshold(self.alphas, self.taus, rate) / shipped_threshold(self.alphas, self.taus, a0)

    def p_values(self, s: np.ndarray) -> np.ndarray:
        """Conformal p-values of the statistics ``s`` against the pooled null (the shipped
        table beyond the context null's resolution)."""
        n = len(self.pooled)
        p = (1.0 + n - np.searchsorted(self.pooled, s, side="left")) / (n + 1.0) if n else np.ones(np.shape(s))
        tail = np.interp(-np.asarray(s, float), -self.taus, np.log(self.alphas))
        lo = MIN_EXCEEDANCES / (n + 1.0)
        return np.where(p < lo, np.minimum(p, np.exp(tail)), p) if n else np.exp(tail)

    def summary(self) -> dict[str, Any]:
        return {
            "source": self.source,
            "fallback": self.fallback or None,
            "clips": list(self.clips),
            "cells": self.cells,
            "detectors": list(DETECTORS),
        }


def shipped_threshold(alphas: np.ndarray, taus: np.ndarray, rate: float) -> float:
    """Threshold at ``rate`` by log-linear interpolation of the shipped table (extrapolated
    linearly in log rate beyond its ends)."""
    la = np.log(alphas)
    x = np.log(rate)
    if x >= la[0]:
        return float(taus[0])
    if x <= la[-1]:
        slope = (taus[-1] - taus[-2]) / (la[-1] - la[-2])
        return float(taus[-1] + slope * (x - la[-1]))
    return float(np.interp(-x, -la, taus))


@lru_cache(maxsize=1)
def _shipped_data() -> dict[str, Any]:
    return cast("dict[str, Any]", json.loads(SHIPPED.read_text()))


def robust_units(ev: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per joint and detector, the median and the floored robust scale (the 0.95 quantile over
    the median: a joint's tail, not its bulk, sets its unit) of null evidence ``ev`` (n, m, K)."""
    center = np.median(ev, axis=0)
    return center, np.maximum(np.quantile(ev, 0.95, axis=0) - center, SCALE_FLOOR)


def shipped_null(joints: Sequence[str], fallback: str = "") -> Null:
    """The null shipped with the package for the texture ``joints`` (a joint it lacks takes
    the median units over its joints)."""
    d = _shipped_data()
    units = d["joints"]
    med_c = np.median([u["center"] for u in units.values()], axis=0)
    med_s = np.median([u["scale"] for u in units.values()], axis=0)
    center = np.array([units[j]["center"] if j in units else med_c for j in joints], float)
    scale = np.array([units[j]["scale"] if j in units else med_s for j in joints], float)
    return Null(
        center,
        np.maximum(scale, SCALE_FLOOR),
        np.zeros(0),
        np.array(d["alphas"], float),
        np.array(d["taus"], float),
        "shipped",
        [],
        fallback,
    )


def context_null(evs: list[np.ndarray], masks: list[np.ndarray], joints: Sequence[str], clips: list[str]) -> Null:
    """The null of the evidence ``evs`` (T_i, m, K) on the cells ``masks`` (T_i,) of the
    context spans (module doc), with the shipped table for small rates."""
    pool = np.concatenate([e[m] for e, m in zip(evs, masks, strict=True)], axis=0)  # (n, m, K)
    center, scale = robust_units(pool)
    s = ((pool - center) / scale).max(axis=-1).ravel()
    d = _shipped_data()
    return Null(center, scale, np.sort(s), np.array(d["alphas"], float), np.array(d["taus"], float), "context", clips)


#: Rates of the shipped quantile table.
ALPHAS = np.array([0.1, 0.05, 0.02, 0.01, 0.005, 0.002, 0.001, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5])


def build_shipped(evs: list[np.ndarray], joints_list: list[Any], takes: list[str]) -> dict[str, Any]:
    """The shipped null (JSON-friendly) from the evidence (T_i, m_i, K) of clean development
    takes of the texture joints ``joints_list[i]``: per joint the median units over the
    takes' robust units, and the rate table of the pooled fused statistic, each take
    standardised on its own cells."""
    per: dict[str, list[Any]] = {}
    stats = []
    for ev, joints in zip(evs, joints_list, strict=True):
        c, s = robust_units(ev)
        for i, j in enumerate(joints):
            per.setdefault(j, []).append((c[i], s[i]))
        stats.append(((ev - c) / s).max(axis=-1).ravel())
    pooled = np.sort(np.concatenate(stats))
    taus = [float(np.quantile(pooled, 1.0 - a)) for a in ALPHAS]
    return {
        "detectors": list(DETECTORS),
        "alphas": ALPHAS.tolist(),
        "taus": taus,
        "cells": int(len(pooled)),
        "takes": takes,
        "joints": {
            j: {
                "center": np.median([u[0] for u in v], axis=0).round(6).tolist(),
                "scale": np.median([u[1] for u in v], axis=0).round(6).tolist(),
            }
            for j, v in per.items()
        },
    }
