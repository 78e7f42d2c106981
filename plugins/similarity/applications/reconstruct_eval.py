"""``analyses.reconstruction_eval``: Krüger et al. 2010 Tables 3 and 4 for our corpus.

For every test clip (left out of its prior database) the clip's synthetic markers (±1 mm)
are reconstructed (:mod:`.reconstruct`) and the error is reported in cm per joint as
"average (max)": average over joints and frames, max the largest per-frame average.

Tables
------
table3 : ``motion, n_frames, prior, prior_frames, avg_cm, max_cm, cell``
    prior ``HDM`` (every HDM05 clip but the test clip), ``CMU-`` (every CMU clip but those
    of the test clip's subject; the paper withholds collection 86), ``CMU`` (every CMU clip
    but the test clip); feature set F_E^15 (``features.end_effectors``, ``joints: 5``).
table4 : ``motion, feature_set, avg_cm, max_cm, cell``
    prior ``CMU``, one row per feature set of the kNN search (F_E^15/30/39, windowed
    F_E^{15x3}, F_E^{15x5}, F_E^{30x3}, F_pca^8/16/25 -- the PCA fitted on HDM05 as in the
    paper, or on the prior when no HDM05 input is given).
sizes : ``motion, fraction, prior_frames, avg_cm, max_cm``
    prior ``CMU`` reduced to a random ``fraction`` of its clips: how the error falls as
    the prior database grows (our corpus is ~2 % of the paper's).
joint_errors : ``motion, prior, joint, mean_cm, max_cm`` for table 3.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import (
    Analysis,
    DataError,
    FeatureSet,
    Index,
    Motion,
    MotionDatabase,
    Params,
    StepContext,
    StepOutput,
)
from mocapflow.framework.datasets import Dataset

from .reconstruct import PriorDatabase, ReconstructParams, prior_index, reconstruct_motion

#: Table 4's columns: label -> (features component, parameters).
FEATURE_SETS: dict[str, tuple[str, dict]] = {
    "F_E^15": ("end_effectors", {"joints": 5}),
    "F_pca^8": ("pca", {"n_components": 8}),
    "F_pca^16": ("pca", {"n_components": 16}),
    "F_pca^25": ("pca", {"n_components": 25}),
    "F_E^30": ("end_effectors", {"joints": 10}),
    "F_E^39": ("end_effectors", {"joints": 13}),
    "F_E^15x3": ("end_effectors", {"joints": 5, "samples": 3}),
    "F_E^15x5": ("end_effectors", {"joints": 5, "samples": 5}),
    "F_E^30x3": ("end_effectors", {"joints": 10, "samples": 3}),
}

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


def _find(dbs: Sequence[MotionDatabase | None], name: str) -> tuple[Motion, int]:
    for i, db in enumerate(dbs):
        for m in db.motions if db is not None else ():
            if m.name == name:
                return m, i
    raise DataError(f"test clip {name!r} is in neither database")


def _run(
    test: Motion, store: PriorDatabase, keep: np.ndarray, make_index: Callable[[], Index], params: ReconstructParams
) -> tuple[dict, int]:
    prior = store.prior(keep, make_index())
    _, e = reconstruct_motion(test, prior, params)
    return e, len(prior.poses)


def table3(
    tests: Sequence[str],
    cmu: PriorDatabase,
    hdm: PriorDatabase | None,
    cmu_db: MotionDatabase,
    hdm_db: MotionDatabase | None,
    make_index: Callable[[], Index],
    params: ReconstructParams,
) -> tuple[list[dict], list[dict]]:
    """Rows of Table 3 (and its per-joint errors) for the named test clips."""
    rows, joints = [], []
    for name in tests:
        m, _ = _find([cmu_db, hdm_db], name)
        configs = []
        if hdm is not None:
            configs.append(("HDM", hdm, ~hdm.withheld(m, "clip")))
        configs += [("CMU-", cmu, ~cmu.withheld(m, "subject")), ("CMU", cmu, ~cmu.withheld(m, "clip"))]
        for label, store, keep in configs:
            e, n = _run(m, store, keep, make_index, params)
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


def table4(
    tests: Sequence[str],
    cmu_db: MotionDatabase,
    hdm_db: MotionDatabase | None,
    feature_sets: Sequence[str],
    make_features: Callable[[str, dict], FeatureSet],
    make_index: Callable[[], Index],
    params: ReconstructParams,
) -> list[dict]:
    """Rows of Table 4: prior = CMU without the test clip, one column per feature set."""
    rows = []
    tests_m = [_find([cmu_db, hdm_db], n)[0] for n in tests]
    for label in feature_sets:
        comp, fparams = FEATURE_SETS[label]
        fs = make_features(comp, fparams)
        if fs.requires_fit:
            fs.fit(hdm_db if hdm_db is not None else cmu_db)
        store = PriorDatabase(cmu_db, fs)
        for name, m in zip(tests, tests_m, strict=True):
            e, _ = _run(m, store, ~store.withheld(m, "clip"), make_index, params)
            rows.append(
                {
                    "motion": name,
                    "feature_set": label,
                    "avg_cm": e["avg_cm"],
                    "max_cm": e["max_frame_cm"],
                    "cell": cell(e["avg_cm"], e["max_frame_cm"]),
                }
            )
    return rows


def size_sweep(
    tests: Sequence[str],
    cmu: PriorDatabase,
    cmu_db: MotionDatabase,
    hdm_db: MotionDatabase | None,
    fractions: Sequence[float],
    make_index: Callable[[], Index],
    params: ReconstructParams,
    seed: int = 0,
) -> list[dict]:
    """Error versus prior size: random clip subsets (nested: 10 % within 30 % within 100 %)."""
    order = np.random.default_rng(seed).permutation(len(cmu.names))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    rows = []
    for name in tests:
        m, _ = _find([cmu_db, hdm_db], name)
        base = ~cmu.withheld(m, "clip")
        for frac in fractions:
            keep = base & (rank < max(1, int(round(frac * len(order)))))
            e, n = _run(m, cmu, keep, make_index, params)
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
    feature_sets: tuple[str, ...] = Field(tuple(FEATURE_SETS), description=f"Table 4 columns, of {list(FEATURE_SETS)}")
    fractions: tuple[float, ...] = Field(
        (0.1, 0.3, 1.0), description="prior sizes of the size sweep (fractions of CMU clips)"
    )
    k: int = Field(64, ge=2, description="neighbours of the local linear model")


class ReconstructionEval(Analysis):
    """Reconstruction errors in the layout of Krüger 2010 Tables 3 and 4, plus error vs prior size."""

    name = "reconstruction_eval"
    inputs: Mapping[str, bool] = {"cmu": True, "hdm05": False}
    Params = ReconstructionEvalParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        p = self.params
        unknown = [f for f in p.feature_sets if f not in FEATURE_SETS]
        if unknown:
            raise DataError(f"unknown feature sets {unknown}; known: {list(FEATURE_SETS)}")
        cmu_db = inputs["cmu"].motions()
        hdm_db = inputs["hdm05"].motions() if "hdm05" in inputs else None
        reg = ctx.registries
        make_features = lambda comp, params: reg["features"].get(comp)(params)  # noqa: E731 - a one-line helper local to this function
        fe15 = make_features(*FEATURE_SETS["F_E^15"])
        cmu = PriorDatabase(cmu_db, fe15)
        hdm = PriorDatabase(hdm_db, fe15) if hdm_db is not None else None
        rp = ReconstructParams(k=p.k)
        t3, joints = table3(p.test_clips, cmu, hdm, cmu_db, hdm_db, prior_index, rp)
        t4 = table4(p.test_clips, cmu_db, hdm_db, p.feature_sets, make_features, prior_index, rp)
        sizes = size_sweep(p.test_clips, cmu, cmu_db, hdm_db, p.fractions, prior_index, rp)
        tables = {
            "table3": pa.Table.from_pylist(t3),
            "table4": pa.Table.from_pylist(t4),
            "sizes": pa.Table.from_pylist(sizes),
            "joint_errors": pa.Table.from_pylist(joints),
        }
        tables["data"] = tables["table3"]
        summary = {
            "cmu_frames": cmu_db.n_frames,
            "hdm05_frames": hdm_db.n_frames if hdm_db else 0,
            "table3_avg_cm": {r["prior"]: None for r in t3},
        }
        for label in summary["table3_avg_cm"]:
            summary["table3_avg_cm"][label] = float(np.mean([r["avg_cm"] for r in t3 if r["prior"] == label]))
        return StepOutput(tables, summary)
