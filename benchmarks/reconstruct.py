"""Reconstruction from 6 sparse markers (Krüger et al. 2010 §5.2): speed and Tables 3/4.

    python benchmarks/reconstruct.py            # Tables 3, 4, size sweep, frames/s
    python benchmarks/reconstruct.py --quick    # the bundled examples/data clips, 2 test clips, 3 feature sets

Prints frames reconstructed per second (one query per frame and iteration, single thread)
against a baseline measured in the same run (the bare kNN query rate, i.e. the search's
share of the cost), then the error tables in the paper's "average (max)" cm-per-joint layout.
Paper reference: 1.3-3.4 cm average per joint on databases of 380 k (HDM05) to 1 M (CMU)
frames; our corpus has ~27 k frames at 30 Hz, so larger errors are expected.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from corpus import REPO, load_corpus

from mocapflow.framework import MotionDatabase, load_registries
from mocapflow.plugins.similarity.applications.reconstruct import (
    MODEL,
    PriorDatabase,
    ReconstructParams,
    prior_index,
    reconstruct_motion,
)
from mocapflow.plugins.similarity.applications.reconstruct_eval import (
    DEFAULT_TESTS,
    FEATURE_SETS,
    size_sweep,
    table3,
    table4,
)


def pivot(rows: list[dict], row_key: str, col_key: str, cols: list[str]) -> str:
    names = list(dict.fromkeys(r[row_key] for r in rows))
    width = max(len(n) for n in names) + 2
    out = [f"{'motion':<{width}}" + "".join(f"{c:>16}" for c in cols)]
    for n in names:
        cells = {r[col_key]: r["cell"] for r in rows if r[row_key] == n}
        out.append(f"{n:<{width}}" + "".join(f"{cells.get(c, '-'):>16}" for c in cols))
    return "\n".join(out)


def examples_db() -> MotionDatabase:
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc

    return MotionDatabase([resample(read_amc(f), 30.0) for f in sorted((REPO / "examples/data/cmu").glob("*/*.amc"))])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    reg = load_registries(entry_points=False)
    make_index = prior_index
    make_features = lambda comp, params: reg["features"].get(comp)(params)  # noqa: E731 - a one-line helper local to this function
    params = ReconstructParams()

    t0 = time.perf_counter()
    db = examples_db() if args.quick else load_corpus(fps=30)
    cmu_db = MotionDatabase([m for m in db.motions if not m.name.startswith("HDM")])
    hdm_db = MotionDatabase([m for m in db.motions if m.name.startswith("HDM")]) if not args.quick else None
    print(
        f"corpus: CMU {cmu_db.n_frames} frames ({cmu_db.n_clips} clips), HDM05 "
        f"{hdm_db.n_frames if hdm_db else 0} frames at 30 Hz, loaded in {time.perf_counter() - t0:.1f} s"
    )
    tests = ["16_15", "02_01"] if args.quick else list(DEFAULT_TESTS)
    fsets = ["F_E^15", "F_E^30", "F_pca^8"] if args.quick else list(FEATURE_SETS)

    fe15 = make_features(*FEATURE_SETS["F_E^15"])
    cmu = PriorDatabase(cmu_db, fe15)
    hdm = PriorDatabase(hdm_db, fe15) if hdm_db else None

    # --- speed: frames per second against the bare kNN query rate ----------------------
    test = next(m for m in cmu_db.motions if m.name == tests[0])
    prior = cmu.prior(~cmu.withheld(test, "clip"), make_index())
    reconstruct_motion(test, prior, params)  # warm-up (numba compile of the index)
    _, e = reconstruct_motion(test, prior, params)
    fps = test.n_frames / e["seconds"]
    q = prior.features[:2000]
    t = time.perf_counter()
    for i in range(len(q)):
        prior.index.query(q[i : i + 1], params.k)
    qps = len(q) / (time.perf_counter() - t)
    print(
        f"\nspeed ({test.name}, {test.n_frames} frames, prior {len(prior.poses)} frames, k={params.k}, "
        f"{MODEL.iterations} searches/frame):"
    )
    print(f"  reconstruction  {fps:9.0f} frames/s")
    print(f"  kNN query alone {qps:9.0f} queries/s  -> search share {MODEL.iterations * fps / qps:.0%} of the time")

    t = time.perf_counter()
    rows3, _ = table3(tests, cmu, hdm, cmu_db, hdm_db, make_index, params)
    print(f"\nTable 3 (F_E^15; avg (max) cm per joint; {time.perf_counter() - t:.0f} s)")
    print("  HDM: HDM05 without the test clip; CMU-: CMU without the test subject; CMU: CMU without the test clip")
    print(pivot(rows3, "motion", "prior", ["HDM", "CMU-", "CMU"]))
    for label in ("HDM", "CMU-", "CMU"):
        v = [r["avg_cm"] for r in rows3 if r["prior"] == label]
        print(f"  mean over test clips, {label:>4}: {np.mean(v):.2f} cm")

    t = time.perf_counter()
    rows4 = table4(tests, cmu_db, hdm_db, fsets, make_features, make_index, params)
    print(f"\nTable 4 (prior: CMU without the test clip; PCA fitted on HDM05; {time.perf_counter() - t:.0f} s)")
    print(pivot(rows4, "motion", "feature_set", fsets))

    rows = size_sweep(tests, cmu, cmu_db, hdm_db, (0.1, 0.3, 1.0), make_index, params)
    print("\nerror vs prior size (CMU clips, nested random subsets)")
    for frac in (0.1, 0.3, 1.0):
        sel = [r for r in rows if r["fraction"] == frac]
        print(
            f"  {frac:4.0%}: prior {np.mean([r['prior_frames'] for r in sel]):8.0f} frames  "
            f"avg {np.mean([r['avg_cm'] for r in sel]):.2f} cm  max {np.mean([r['max_cm'] for r in sel]):.2f} cm"
        )


if __name__ == "__main__":
    main()
