"""The reconstruction's pipeline steps: ``analyses.reconstruction_prior`` (the prior store,
built once) and ``analyses.reconstruct`` (synthetic markers of test takes, with errors);
the model is :mod:`.reconstruct`, marker takes :mod:`.reconstruct_markers`."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import pyarrow as pa
from pydantic import Field

from mocapflow.framework import Analysis, Params, StepContext, StepOutput
from mocapflow.framework.datasets import Dataset

from .reconstruct import Reconstruction, ReconstructParams
from .reconstruct_prior import PriorStore, build_store
from .reconstruct_synthetic import PriorCache, reconstruct_motion

ERRORS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("joint", pa.string()),
        ("mean_cm", pa.float64()),
        ("max_cm", pa.float64()),
    ]
)
CLIP_ERRORS = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("name", pa.string()),
        ("n_frames", pa.int32()),
        ("prior_frames", pa.int64()),
        ("avg_cm", pa.float64()),
        ("max_cm", pa.float64()),
        ("max_joint_cm", pa.float64()),
        ("fk_avg_cm", pa.float64()),
        ("frames_per_s", pa.float64()),
        ("confidence_mean", pa.float64()),
        ("confidence_min", pa.float64()),
        ("low_confidence_share", pa.float64()),
    ]
)
#: Per frame of every reconstruction: its confidence and the terms behind it (:class:`.reconstruct.Reconstruction`).
CONFIDENCE = pa.schema(
    [
        ("clip_id", pa.int32()),
        ("frame", pa.int32()),
        ("confidence", pa.float64()),
        ("novelty", pa.float64()),
        ("misfit_cm", pa.float64()),
        ("reach_cm", pa.float64()),
        ("limit", pa.float64()),
    ]
)
#: Frames below this confidence count as low in ``clip_errors.low_confidence_share``.
LOW_CONFIDENCE = 0.5


def confidence_table(clip_id: int, rec: Reconstruction) -> pa.Table:
    """The per-frame ``confidence`` table of one reconstruction (schema :data:`CONFIDENCE`)."""
    n = len(rec.confidence)
    return pa.Table.from_arrays(
        [
            pa.array(np.full(n, clip_id, np.int32)),
            pa.array(np.arange(n, dtype=np.int32)),
            pa.array(rec.confidence),
            pa.array(rec.novelty),
            pa.array(rec.misfit * 100.0),
            pa.array(rec.reach * 100.0),
            pa.array(rec.limit),
        ],
        schema=CONFIDENCE,
    )


#: Folder of a prior store inside a ``reconstruction_prior`` step's dataset.
PRIOR_FOLDER = "prior"


def open_prior(ds: Dataset, fps: float = 30.0) -> PriorStore:
    """The prior store of a ``reconstruction_prior`` dataset (memory-mapped), or one built
    from a motions dataset (resampled to ``fps``, mirrored)."""
    folder = ds.path / PRIOR_FOLDER
    if (folder / "clips.json").is_file():
        return PriorStore.load(folder)
    return build_store(ds.motions().motions, fps=fps)


class ReconstructionPriorParams(Params):
    fps: float = Field(30.0, gt=0, description="frame rate every prior take is resampled to")
    mirrored: bool = Field(True, description="add every take's left/right mirror image")


class ReconstructionPrior(Analysis):
    """The reconstruction's prior database, built once: every take as bone directions
    (:mod:`.reconstruct_prior`), memory-mapped by ``analyses.reconstruct``."""

    name = "reconstruction_prior"
    inputs: ClassVar[Mapping[str, bool]] = {"motions": True}
    Params = ReconstructionPriorParams
    params: ReconstructionPriorParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        p = self.params
        store = build_store(inputs["motions"].motions().motions, fps=p.fps, mirrored=p.mirrored)
        store.save(ctx.out_dir / PRIOR_FOLDER)
        takes = pa.Table.from_pylist(
            [{**c, "n_frames": int(store.clip_rows[i + 1] - store.clip_rows[i])} for i, c in enumerate(store.clips)]
        )
        summary = {"takes": len(store.clips), "frames": store.n_frames, "fps": store.fps, "joints": list(store.joints)}
        return StepOutput({"data": takes}, summary)


class Reconstruct(Analysis):
    """Full-body motion from 6 sparse markers with kNN local linear pose priors (Krüger 2010 §5.2)."""

    name = "reconstruct"
    inputs: ClassVar[Mapping[str, bool]] = {"prior": True, "test": True}
    Params = ReconstructParams
    params: ReconstructParams

    def run(self, inputs: Mapping[str, Dataset], ctx: StepContext) -> StepOutput:
        from mocapflow.framework.motion_tables import motions_to_tables

        p = self.params
        test_db = inputs["test"].motions()
        store = open_prior(inputs["prior"])
        cache = PriorCache(store)
        motions, err_rows, clip_rows, conf_tables = [], [], [], []
        for cid, m in zip(
            test_db.clip_ids, ctx.progress(test_db.motions, total=test_db.n_clips, desc=ctx.step_id), strict=True
        ):
            prior = cache.for_motion(m, p.leave_out)
            rec, e = reconstruct_motion(m, prior, p)
            motions.append(rec)
            conf = e["confidence"]
            conf_tables.append(confidence_table(int(cid), e["reconstruction"]))
            err_rows += [
                {"clip_id": int(cid), "name": m.name, "joint": j, "mean_cm": float(a), "max_cm": float(b)}
                for j, a, b in zip(e["joints"], e["mean_cm"], e["max_cm"], strict=True)
                if np.isfinite(a)
            ]
            clip_rows.append(
                {
                    "clip_id": int(cid),
                    "name": m.name,
                    "n_frames": m.n_frames,
                    "prior_frames": len(prior.poses),
                    "avg_cm": e["avg_cm"],
                    "max_cm": e["max_frame_cm"],
                    "max_joint_cm": e["max_joint_cm"],
                    "fk_avg_cm": e["fk_avg_cm"],
                    "frames_per_s": m.n_frames / max(e["seconds"], 1e-9),
                    "confidence_mean": float(conf.mean()) if len(conf) else None,
                    "confidence_min": float(conf.min()) if len(conf) else None,
                    "low_confidence_share": float((conf < LOW_CONFIDENCE).mean()) if len(conf) else None,
                }
            )
        tables = motions_to_tables(motions, list(test_db.clip_ids))
        tables["errors"] = pa.Table.from_pylist(err_rows, schema=ERRORS)
        tables["clip_errors"] = pa.Table.from_pylist(clip_rows, schema=CLIP_ERRORS)
        tables["confidence"] = pa.concat_tables(conf_tables) if conf_tables else CONFIDENCE.empty_table()
        summary = {
            "clips": len(clip_rows),
            "frames": sum(r["n_frames"] for r in clip_rows),
            "avg_cm": float(np.mean([r["avg_cm"] for r in clip_rows])) if clip_rows else None,
            "prior_takes": len(store.clips),
            "backend": "retargeted bone-direction prior + indexes.kdtree",
        }
        return StepOutput(tables, summary)
