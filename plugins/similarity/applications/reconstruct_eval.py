"""``analyses.reconstruction_eval``: Krüger et al. 2010 Table 3 for our corpus, and error vs prior size.

For every test clip (left out of its prior database) the clip's synthetic markers (±1 mm)
are reconstructed (:mod:`.reconstruct`, the prior retargeted to the clip's skeleton) and
the error is reported in cm per joint as "average (max)": average over joints and frames,
max the largest per-frame average.

Tables
------
table3 : ``motion, n_frames, prior, prior_frames, avg_cm, max_cm, cell``
    prior ``HDM`` (every HDM05 take but the test clip), ``CMU-`` (every CMU take but those
    of the test clip's subject; the paper withholds collection 86), ``CMU`` (every CMU take
    but the test clip); each take with its mirror image.
sizes : ``motion, fraction, prior_frames, avg_cm, max_cm``
    prior ``CMU`` reduced to a random ``fraction`` of its takes: how the error falls as
    the prior database grows (our corpus is ~2 % of the paper's).
joint_errors : ``motion, prior, joint, mean_cm, max_cm`` for table 3.

The paper's Table 4 (kNN feature sets) has no counterpart: the query is the control
signal, F_E^15 plus its velocity (:mod:`.reconstruct`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import (
    Analysis,
    DataError,
    Motion,
    MotionDatabase,
    Params,
    StepContext,
    StepOutput,
)
from mocapflow.framework.datasets import Dataset

from .reconstruct import PosePrior, ReconstructParams
from .reconstruct_prior import PriorStore, bone_lengths, build_store
from .reconstruct_synthetic import reconstruct_motion, withheld

#: Default test clips: two CMU subjects with many clips, two HDM05 takes of actor bk.
DEFAULT_TESTS: tuple[str, ...] = (
    "16_15",
    "09_06",
    "49_02",
    "HDM_bk_squat1Reps_013_120",
    "HDM_bk_jogLeftCircle4StepsRstart_003_120",
)


def cell(avg: float, mx: float) -> str:
    """Table cell as printed in the paper: ``"2.63 (6.47)"``."""
    return f"{avg:.2f} ({mx:.2f})"


def _find(dbs: Sequence[MotionDatabase | None], name: str) -> Motion:
    for db in dbs:
        for m in db.motions if db is not None else ():
            if m.name == name:
                return m
    raise DataError(f"test clip {name!r} is in neither database")


def _run(test: Motion, store: PriorStore, keep: np.ndarray, params: ReconstructParams) -> tuple[dict[str, Any], int]:
    prior = PosePrior.build(store, bone_lengths(test.canonical_positions(store.joints), store.joints), keep)
    _, e = reconstruct_motion(test, prior, params)
    return e, len(prior.poses)


def table3(
    tests: Sequence[str],
    cmu: PriorStore,
    hdm: PriorStore | None,
    cmu_db: MotionDatabase,
    hdm_db: MotionDatabase | None,
    params: ReconstructParams,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Rows of Table 3 (and its per-joint errors) for the named test clips."""
    rows, joints = [], []
    for name in tests:
        m = _find([cmu_db, hdm_db], name)
        configs = []
        if hdm is not None:
            configs.append(("HDM", hdm, ~withheld(hdm, m, "clip")))
        configs += [("CMU-", cmu, ~withheld(cmu, m, "subject")), ("CMU", cmu, ~withheld(cmu, m, "clip"))]
        for label, store, keep in configs:
            e, n = _run(m, store, keep, params)
            rows.append(
                {
                    "motion": name,
                    "n_frames": m.n_frames,
                    "prior": label,
                    "prior_frames": n,
                    "avg_cm": e["avg_cm"],
                    "max_cm": e["max_frame_cm"],
                    "cell": cell(e["avg_cm"], e["max_frame_cm"]),
                }
            )
            joints += [
                {"motion": name, "prior": label, "joint": j, "mean_cm": float(a), "max_cm": float(b)}
                for j, a, b in zip(e["joints"], e["mean_cm"], e["max_cm"], strict=True)
                if np.isfinite(a)
            ]
    return rows, joints


def size_sweep(
    tests: Sequence[str],
    cmu: PriorStore,
    cmu_db: MotionDatabase,
    hdm_db: MotionDatabase | None,
    fractions: Sequence[float],
    params: ReconstructParams,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """Error versus prior size: random take subsets (nested: 10 % within 30 % within 100 %)."""
    order = np.random.default_rng(seed).permutation(len(cmu.clips))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    rows = []
    for name in tests:
        m = _find([cmu_db, hdm_db], name)
        base = ~withheld(cmu, m, "clip")
        for frac in fractions:
            keep = base & (rank < max(1, int(round(frac * len(order)))))
            e, n = _run(m, cmu, keep, params)
            rows.append(
                {
                    "motion": name,
                    "fraction": float(frac),
                    "prior_frames": n,
                    "avg_cm": e["avg_cm"],
                    "max_cm": e["max_frame_cm"],
                }
            )
    return rows


class ReconstructionEvalParams(Params):
    test_clips: tuple[str, ...] = Field(DEFAULT_TESTS, min_length=1, description="names of the test clips")
    fractions: tuple[float, ...] = Field(
        (0.1, 0.3, 1.0), description="prior sizes of the size sweep (fractions of CMU takes)"
    )
    k: int = Field(128, ge=2, description="neighbours of the local linear model")


class ReconstructionEval(Analysis):
    """Reconstruction errors in the layout of Krüger 2010 Table 3, plus error vs prior size."""

    name = "reconstruction_eval"
    inputs: ClassVar[Mapping[str, bool]] = {"cmu": True, "hdm05": False}
    Params = ReconstructionEvalParams
    params: ReconstructionEvalParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        p = self.params
        cmu_db = inputs["cmu"].motions()
        hdm_db = inputs["hdm05"].motions() if "hdm05" in inputs else None
        fps = cmu_db.motions[0].fps if cmu_db.motions else 30.0
        cmu = build_store(cmu_db.motions, fps=fps)
        hdm = build_store(hdm_db.motions, fps=fps) if hdm_db is not None else None
        rp = ReconstructParams(k=p.k)
        t3, joints = table3(p.test_clips, cmu, hdm, cmu_db, hdm_db, rp)
        sizes = size_sweep(p.test_clips, cmu, cmu_db, hdm_db, p.fractions, rp)
        tables = {
            "table3": pa.Table.from_pylist(t3),
            "sizes": pa.Table.from_pylist(sizes),
            "joint_errors": pa.Table.from_pylist(joints),
        }
        tables["data"] = tables["table3"]
        summary: dict[str, Any] = {
            "cmu_frames": cmu_db.n_frames,
            "hdm05_frames": hdm_db.n_frames if hdm_db else 0,
            "table3_avg_cm": {},
        }
        for label in dict.fromkeys(r["prior"] for r in t3):
            summary["table3_avg_cm"][label] = float(np.mean([r["avg_cm"] for r in t3 if r["prior"] == label]))
        return StepOutput(tables, summary)
