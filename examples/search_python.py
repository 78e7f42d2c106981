"""Search the bundled CMU takes from Python and export the best hits (docs/python-api.md).

    python examples/search_python.py [OUT_DIR]

A Database of every AMC take under examples/data/cmu (resampled to 30 Hz for the search),
one second of the walk 16_15 as the query, the five best segments printed in each take's own
frames and seconds, then the same hit searched again from its printed numbers (it is now
the query's own span, so it is excluded), and the top three written as clips to OUT_DIR
(default: a temporary folder).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import mocapflow

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    cmu = HERE / "data" / "cmu"
    db = mocapflow.Database(cmu)
    walk = mocapflow.read(cmu / "16" / "16_15.amc")
    hits = db.search(walk.slice(120, 240), count=5)  # frames 120-240 of the 120-Hz file: one second
    print(f"query {hits.query}: {len(hits)} matches")
    for r in hits.select(["rank", "clip", "fps", "start_frame", "end_frame", "start_s", "cost"]).to_pylist():
        print(f"  {r['rank']}  {r['clip']:<8} frames [{r['start_frame']}, {r['end_frame']}) at {r['fps']:g} fps, "
              f"{r['start_s']:.2f} s, cost {r['cost']:.3g}")  # fmt: skip
    best = hits.to_pylist()[0]
    take = mocapflow.read(next(cmu.rglob(f"{best['clip']}.amc")))
    again = db.search(take.slice(best["start_frame"], best["end_frame"]), count=1)
    top = again.to_pylist()
    print(f"the best hit as the next query: {again.query} -> {top[0]['clip'] if top else again.reason}")
    out = Path(argv[0]) if argv else Path(tempfile.mkdtemp(prefix="mocapflow-hits-"))
    index = hits.export(out, top=3, handle=6)
    print(f"wrote {index.num_rows} clips to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
