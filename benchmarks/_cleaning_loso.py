"""Leave-one-subject-out generalization of the cleaner (``benchmarks/cleaning.py loso`` and
``stability``): held-out subjects cleaned against other subjects' takes, scored per error
kind, magnitude and duration, and the edited share over random context choices; with the
reading helpers both scripts share."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from corpus import DATA

REPO = Path(__file__).resolve().parent.parent
CMU = DATA / "cmu" / "amc"
EXAMPLES = REPO / "examples" / "data" / "cmu"
_TAKES: dict = {}  # takes read once per run
LOSO = {
    "locomotion": {
        "02": ("02_01", "02_02", "02_03"),
        "03": ("03_01", "03_02"),
        "05": ("05_01",),
        "07": ("07_05",),
        "09": tuple(f"09_{i:02d}" for i in range(1, 12)),
        "16": (
            "16_11",
            "16_13",
            "16_15",
            "16_17",
            "16_19",
            "16_21",
            "16_31",
            "16_33",
            "16_35",
            "16_36",
            "16_41",
            "16_43",
            "16_45",
            "16_55",
            "16_57",
        ),
        "35": ("35_01",),
        "49": ("49_01", "49_04", "49_05"),
    },
    "dance": {
        "05": ("05_02", "05_03", "05_06", "05_08", "05_10", "05_11", "05_13"),
        "131": ("131_04",),
        "60": tuple(f"60_{t}" for t in ("01", "02", "04", "05", "06", "07", "10", "11")),
        "61": tuple(f"61_{t}" for t in ("01", "02", "04", "05", "06", "07", "10", "11")),
    },
}


def _read(files) -> list:
    from mocapflow.plugins.formats.asf_amc import read_amc

    return [read_amc(f) for f in files]


def _sets(items: list[str]) -> dict:
    """``--set KEY=VALUE`` as cleaner parameters; ``a.b=V`` sets ``{"a": {"b": V}}``."""
    out: dict = {}
    for kv in items:
        k, _, v = kv.partition("=")
        try:
            val = json.loads(v)
        except json.JSONDecodeError:
            val = v
        *head, last = k.split(".")
        d = out
        for h in head:
            d = d.setdefault(h, {})
        d[last] = val
    return out


def _take(name: str, folder: Path = CMU):
    if name not in _TAKES:
        _TAKES[name] = _read([folder / name.split("_")[0] / f"{name}.amc"])[0]
    return _TAKES[name]


def _crop(m, seconds: float, rng: np.random.Generator):
    n = int(seconds * m.fps)
    if m.n_frames <= n:
        return m
    s = int(rng.integers(0, m.n_frames - n + 1))
    return m.slice(s, s + n).with_arrays(name=m.name)


def loso_runs(args) -> list[dict]:
    """Leave-one-subject-out runs (``evaluation/generalization.py``): per seed and held-out
    subject, one of its takes (cropped to ``--take-s``) against ``--context-n`` takes of the
    other subjects (cropped to 15 s), cleaned as ``mocapflow clean`` does, and the same take
    uncorrupted."""
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner, clean_motion
    from mocapflow.plugins.selfsim.evaluation.generalization import inject_native, score_run

    cleaner = MDMCleaner(**{"write_bvh": False, "heatmaps": False, **_sets(args.set)})
    runs = []
    for cat in ["locomotion"] if args.quick else args.category or list(LOSO):
        groups = {"16": ("16_15", "16_35"), "02": ("02_01", "02_03"), "35": ("35_01",)} if args.quick else LOSO[cat]
        folder = EXAMPLES if args.quick else CMU
        for sd in args.seed or range(args.seeds):
            for g, names in groups.items():
                rng = np.random.default_rng([sd, int(g)])
                name = names[sd % len(names)]
                take = _crop(_take(name, folder), args.take_s, rng)
                pool = [n for h, ns in groups.items() if h != g for n in ns]
                if cat == "dance":  # a salsa partner's take of the same trial is never context
                    pool = [n for n in pool if n.split("_")[1] != name.split("_")[1] or n[:2] not in ("60", "61")]
                pick = rng.choice(len(pool), min(args.context_n, len(pool)), replace=False)
                ctx = [_crop(_take(pool[i], folder), 15.0, rng) for i in sorted(pick)]
                t0 = time.perf_counter()
                bad, _, errors = inject_native(take, seed=1000 * sd + int(g), density=args.density)
                out = cleaner.clean(bad, ctx)
                cal = out.calibration if out.calibration is not None and out.calibration.source == "context" else None
                clean_out = clean_motion(cleaner, take, ctx, calibration=cal)
                rec = score_run(take, bad, errors, out, clean_out)
                rec.update(
                    category=cat,
                    subject=g,
                    take=name,
                    seed=sd,
                    seconds=time.perf_counter() - t0,
                    context=[pool[i] for i in sorted(pick)],
                )
                runs.append(rec)
                print(f"  loso {cat} {g} {name} seed {sd}: {rec['seconds']:.1f} s", file=sys.stderr, flush=True)
    return runs


STABILITY_TAKES = {"locomotion": ("16_15", "02_01", "35_01", "09_01"), "dance": ("60_07", "05_10")}


def stability(args) -> None:
    """One clean take against 10 random contexts of 2-8 takes of the other subjects: the share
    of its input cells edited (any change, and >= 1 degree), the spread over the contexts, and
    which calibration each used."""
    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner

    cleaner = MDMCleaner(**{"write_bvh": False, "heatmaps": False, **_sets(args.set)})
    for cat in ["locomotion"] if args.quick else args.category or list(LOSO):
        groups = {"16": ("16_15", "16_35"), "02": ("02_01", "02_03"), "35": ("35_01",)} if args.quick else LOSO[cat]
        folder = EXAMPLES if args.quick else CMU
        print(f"\nstability, {cat}: edited share of a clean take over 10 random contexts of 2-8 other takes")
        for name in ("16_15",) if args.quick else STABILITY_TAKES[cat]:
            g = name.split("_")[0]
            pool = [n for h, ns in groups.items() if h != g for n in ns]
            rng = np.random.default_rng(int(g))
            take = _crop(_take(name, folder), args.take_s, rng)
            shares, big, src = [], [], []
            for _ in range(2 if args.quick else 10):
                k = int(rng.integers(2, min(8, len(pool)) + 1))
                ctx = [
                    _crop(_take(pool[i], folder), 15.0, rng) for i in sorted(rng.choice(len(pool), k, replace=False))
                ]
                out = cleaner.clean(take, ctx)
                cols = out.analysis.texture.joint_index
                ang = np.degrees(quat.geodesic_angle(take.rotations[:, cols], out.cleaned.rotations[:, cols]))
                shares.append(out.edits.num_rows / ang.size)
                big.append(float((ang >= 1.0).mean()))
                src.append(out.calibration.source if out.calibration is not None else "-")
            sh = 100 * np.array(shares)
            print(
                f"  {name}: edited {sh.min():.2f}-{sh.max():.2f} % (spread {sh.max() - sh.min():.2f} %), >= 1 deg "
                f"{100 * min(big):.2f}-{100 * max(big):.2f} %; calibration {', '.join(sorted(set(src)))}"
            )


_MAG_BINS = ((10, 25), (25, 45), (45, 90), (90, 181))
_DUR_BINS = ((1, 2), (2, 4), (4, 9), (9, 21), (21, 41))  # 24-fps frames, [lo, hi)


def loso(args) -> None:
    """Print the leave-one-subject-out figures (recall / precision with the lower 95 % bound
    over runs, per category, on the flags and on the output; per kind; the sweep)."""
    from mocapflow.plugins.selfsim.evaluation.generalization import UNTUNED, bootstrap

    runs = []
    for f in args.load or []:
        runs += json.loads(Path(f).read_text())
    if not args.load:
        runs = loso_runs(args)
    if args.json:
        Path(args.json).write_text(json.dumps(runs, default=float))

    def ci(num, den) -> str:
        v, lo, _ = bootstrap(num, den)
        return f"{v:.3f} ({lo:.3f})"

    for cat in dict.fromkeys(r["category"] for r in runs):
        rs = [r for r in runs if r["category"] == cat]
        subj = sorted({r["subject"] for r in rs})
        print(
            f"\nloso, {cat}: {len(rs)} runs, subjects {', '.join(subj)}, seeds {len({r['seed'] for r in rs})}; "
            "figure (lower 95 % bound over runs)"
        )
        for part in ("flags", "output"):
            c = {k: np.array([r[part][k] for r in rs]) for k in rs[0][part]}
            print(
                f"  (word, joint) on the {part:6s}: R {ci(c['tp'], c['tp'] + c['fn'])}, "
                f"P {ci(c['tp'], c['tp'] + c['fp'])}; cell P {ci(c['cell_tp'], c['cell_tp'] + c['cell_fp'])}"
            )
        fell = np.array([r["eq2_after"] < r["eq2_before"] for r in rs], float)
        ratio = ci([r["cells_after"] for r in rs], [r["cells_before"] for r in rs])
        print(f"  eq. 2 fell on {ci(fell, np.ones_like(fell))} of the runs; erroneous cells after / before {ratio}")
        share = np.array([r["clean_share"] for r in rs])
        print(
            f"  clean takes: cells changed >= 1 deg {100 * share.mean():.2f} % (worst {100 * share.max():.2f} %), "
            f"largest {max(r['clean_max_deg'] for r in rs):.1f} deg; edges: input frames next to an error "
            f"changed > 5 deg in {sum(r['edge_max_deg'] > 5 for r in rs)} of {len(rs)} runs "
            f"(largest {max(r['edge_max_deg'] for r in rs):.1f})"
        )
        for s in subj:
            ss = [r for r in rs if r["subject"] == s]
            tp = np.array([r["output"]["tp"] for r in ss])
            fn = np.array([r["output"]["fn"] for r in ss])
            tf = np.array([r["flags"]["tp"] for r in ss])
            ff = np.array([r["flags"]["fn"] for r in ss])
            print(f"    held out {s:4s}: (w, j) R flags {ci(tf, tf + ff)}, output {ci(tp, tp + fn)}")
        kinds = dict.fromkeys(e["kind"] for r in rs for e in r["errors"])
        print("  per kind, errors >= 25 deg (flip: all), (w, j) R on the flags / output; found = any pair hit")
        for k in kinds:

            def per(lo_deg, hi_deg=999.0, d0=1, d1=41, k=k, rs=rs):
                es = [
                    [
                        e
                        for e in r["errors"]
                        if e["kind"] == k and lo_deg <= e["peak"] < hi_deg and d0 <= e["dur24"] < d1
                    ]
                    for r in rs
                ]
                return (
                    np.array([sum(e["hit_flags"] for e in x) for x in es]),
                    np.array([sum(e["wj24"] for e in x) for x in es]),
                    np.array([sum(e["hit_output"] for e in x) for x in es]),
                    np.array([sum(e["wj"] for e in x) for x in es]),
                    np.array([sum(e["hit_output"] > 0 for e in x) for x in es]),
                    np.array([len(x) for x in es]),
                )

            hf, nf, ho, no, found, n = per(25.0)
            tag = " (untuned)" if k in UNTUNED else ""
            print(
                f"    {k + tag:16s} n={int(n.sum()):4d}  flags {ci(hf, nf)}  output {ci(ho, no)}  found {ci(found, n)}"
            )
            if args.sweep:
                for m0, m1 in _MAG_BINS:
                    cells = []
                    for d0, d1 in _DUR_BINS:
                        hf, nf, ho, no, _, n = per(m0, m1, d0, d1)
                        cells.append(f"{ho.sum() / no.sum():.2f}/{n.sum():d}" if no.sum() else "   -   ")
                    print(f"      {m0:3d}-{m1:3d} deg | " + " | ".join(f"{c:>8s}" for c in cells))
        if args.sweep:
            print(
                "    (sweep rows: peak angle; columns: 24-fps frames "
                + ", ".join(f"[{a}, {b})" for a, b in _DUR_BINS)
                + "; cells: output (w, j) R / errors)"
            )
