"""Leave-one-subject-out generalization of the cleaner (``benchmarks/cleaning.py loso`` and
``stability``): held-out subjects cleaned against other subjects' takes, scored per error
kind, magnitude and duration, and the edited share over random context choices; with the
reading helpers both scripts share."""

from __future__ import annotations

import json
import sys
import time
from collections import Counter
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
    """Leave-one-subject-out runs (``evaluation/generalization.py``): per injector family,
    seed and held-out subject, one of its takes (full length unless ``--take-s``) against
    ``--context-n`` takes of the other subjects (cropped to 15 s), corrupted and cleaned as
    ``mocapflow clean`` does, and the same take uncorrupted cleaned the same way (its own
    null: the clean take's KNN words choose it)."""
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner
    from mocapflow.plugins.selfsim.evaluation.generalization import inject_native, score_run

    if getattr(args, "cache", None):
        from cleaning import install_cache

        install_cache(args.cache)
    cleaner = MDMCleaner(**{"write_bvh": False, "heatmaps": False, **_sets(args.set)})
    runs = []
    clean_cache: dict = {}
    for cat in ["locomotion"] if args.quick else args.category or list(LOSO):
        groups = {"16": ("16_15", "16_35"), "02": ("02_01", "02_03"), "35": ("35_01",)} if args.quick else LOSO[cat]
        if args.subjects:
            groups = {g: v for g, v in groups.items() if g in args.subjects}
        folder = EXAMPLES if args.quick else CMU
        for sd in args.seed or range(args.seeds):
            for g, names in groups.items():
                rng = np.random.default_rng([sd, int(g)])
                name = names[sd % len(names)]
                take = _crop(_take(name, folder), args.take_s, rng) if args.take_s else _take(name, folder)
                pool = (
                    [n for h, ns in LOSO[cat].items() if h != g for n in ns]
                    if not args.quick
                    else [n for h, ns in groups.items() if h != g for n in ns]
                )
                if cat == "dance":  # a salsa partner's take of the same trial is never context
                    pool = [n for n in pool if n.split("_")[1] != name.split("_")[1] or n[:2] not in ("60", "61")]
                pick = rng.choice(len(pool), min(args.context_n, len(pool)), replace=False)
                ctx = [_crop(_take(pool[i], folder), 15.0, rng) for i in sorted(pick)]
                key = (name, tuple(pool[i] for i in sorted(pick)), sd)
                for fam in args.family or ["A", "B"]:
                    t0 = time.perf_counter()
                    bad, _, errors = inject_native(
                        take, seed=1000 * sd + int(g) + (500 if fam == "B" else 0), density=args.density, family=fam
                    )
                    out = cleaner.clean(bad, ctx)
                    if key not in clean_cache:
                        clean_cache[key] = cleaner.clean(take, ctx)
                    rec = score_run(take, bad, errors, out, clean_cache[key])
                    rec.update(
                        category=cat,
                        family=fam,
                        subject=g,
                        take=name,
                        seed=sd,
                        seconds=time.perf_counter() - t0,
                        context=[pool[i] for i in sorted(pick)],
                    )
                    runs.append(rec)
                    print(
                        f"  loso {cat} {fam} {g} {name} seed {sd}: {rec['seconds']:.1f} s", file=sys.stderr, flush=True
                    )
    return runs


#: Subjects whose runs were in view while the design was chosen (their figures are training figures).
DEV_SUBJECTS = {"locomotion": ("02", "09", "16", "35")}

STABILITY_TAKES = {"locomotion": ("16_15", "02_01", "35_01", "09_01"), "dance": ("60_07", "05_10")}


def stability(args) -> None:
    """One clean take (full length) against 6 random contexts of 2-8 takes: the first three of
    its own category's other subjects, the last three with takes of the other category (other
    motion kinds) mixed in; the share of its input cells edited, the spread over the contexts,
    and which null each used."""
    from mocapflow.framework import quaternions as quat
    from mocapflow.plugins.selfsim.cleaner import MDMCleaner

    if getattr(args, "cache", None):
        from cleaning import install_cache

        install_cache(args.cache)
    cleaner = MDMCleaner(**{"write_bvh": False, "heatmaps": False, **_sets(args.set)})
    for cat in ["locomotion"] if args.quick else args.category or list(LOSO):
        groups = {"16": ("16_15", "16_35"), "02": ("02_01", "02_03"), "35": ("35_01",)} if args.quick else LOSO[cat]
        other = [] if args.quick else [n for c, gs in LOSO.items() if c != cat for ns in gs.values() for n in ns]
        folder = EXAMPLES if args.quick else CMU
        print(f"\nstability, {cat}: edited share of a clean take over 6 random contexts of 2-8 takes (3 mixed)")
        for name in ("16_15",) if args.quick else STABILITY_TAKES[cat]:
            g = name.split("_")[0]
            pool = [n for h, ns in groups.items() if h != g for n in ns]
            rng = np.random.default_rng(int(g))
            take = _take(name, folder)
            shares, big, src = [], [], []
            for i in range(2 if args.quick else 6):
                k = int(rng.integers(2, min(8, len(pool)) + 1))
                names = [pool[x] for x in sorted(rng.choice(len(pool), k, replace=False))]
                if i >= 3 and other:
                    names = names[: max(1, k // 2)] + [
                        other[x] for x in rng.choice(len(other), k - max(1, k // 2), replace=False)
                    ]
                ctx = [_crop(_take(n, folder), 15.0, rng) for n in names]
                out = cleaner.clean(take, ctx)
                cols = out.analysis.texture.joint_index
                ang = np.degrees(quat.geodesic_angle(take.rotations[:, cols], out.cleaned.rotations[:, cols]))
                shares.append(float((ang > 1e-4).mean()))
                big.append(float(ang.max(initial=0.0)))
                src.append(out.calibration.source if out.calibration is not None else "-")
            sh = 100 * np.array(shares)
            print(
                f"  {name}: edited {sh.min():.3f}-{sh.max():.3f} % (spread {sh.max() - sh.min():.3f} %), largest "
                f"edit {max(big):.1f} deg; null {', '.join(src)}"
            )


def loso(args) -> None:
    """Print the leave-one-subject-out figures per category and injector family: (word, joint)
    recall of errors >= 10 degrees and precision with the clean takes' changed pairs counted
    as false alarms, on the output at the input rate and on the flags, each with the lower
    95 % bound over runs; eq. 2; the clean takes' edits; the rate curve; per kind."""
    from mocapflow.plugins.selfsim.evaluation.generalization import CURVE_RATES, bootstrap

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
        for fam in dict.fromkeys(r.get("family", "A") for r in runs):
            rs = [r for r in runs if r["category"] == cat and r.get("family", "A") == fam]
            if not rs:
                continue
            fresh = [r for r in rs if r["subject"] not in DEV_SUBJECTS.get(cat, ())]
            if fresh and len(fresh) < len(rs):
                c = {k: np.array([r["output"][k] for r in fresh]) for k in ("tp", "fn", "fp")}
                cf = np.array([r.get("clean_fp", 0) for r in fresh])
                print(
                    f"\nloso, {cat}, family {fam}, subjects never in view while designing "
                    f"({', '.join(sorted({r['subject'] for r in fresh}))}, {len(fresh)} runs): (word, joint) on the "
                    f"output R {ci(c['tp'], c['tp'] + c['fn'])}, P {ci(c['tp'], c['tp'] + c['fp'] + cf)}"
                )
            subj = sorted({r["subject"] for r in rs})
            print(
                f"\nloso, {cat}, injector family {fam}: {len(rs)} runs, full-length takes, subjects {', '.join(subj)}, "
                f"seeds {len({r['seed'] for r in rs})}; figure (lower 95 % bound over runs)"
            )
            cfp = np.array([r.get("clean_fp", 0) for r in rs])
            for part in ("output", "flags"):
                c = {k: np.array([r[part][k] for r in rs]) for k in rs[0][part]}
                extra = cfp if part == "output" else 0
                print(
                    f"  (word, joint), errors >= 10 deg, on the {part:6s}: R {ci(c['tp'], c['tp'] + c['fn'])}, "
                    f"P {ci(c['tp'], c['tp'] + c['fp'] + extra)}"
                    + (" (clean takes' changed pairs counted)" if part == "output" else "")
                )
            fell = np.array([r["eq2_after"] < r["eq2_before"] for r in rs], float)
            print(f"  eq. 2 fell on {ci(fell, np.ones_like(fell))} of the runs")
            print(
                f"  edges: input frames next to an error changed > 5 deg in {sum(r['edge_max_deg'] > 5 for r in rs)} "
                f"of {len(rs)} runs (largest {max(r['edge_max_deg'] for r in rs):.1f})"
            )
            kinds = dict.fromkeys(e["kind"] for r in rs for e in r["errors"])
            print("  per kind: (w, j) R on the output, errors >= 10 deg | 5-10 deg (reported, not counted)")
            for k in kinds:
                row = []
                for big in (True, False):
                    es = [[e for e in r["errors"] if e["kind"] == k and e.get("big", True) == big] for r in rs]
                    ho = np.array([sum(e["hit_output"] for e in x) for x in es])
                    no = np.array([sum(e["wj"] for e in x) for x in es])
                    n = sum(len(x) for x in es)
                    row.append(f"n={n:4d} {ci(ho, no)}" if no.sum() else f"n={n:4d} -")
                print(f"    {k:10s} {row[0]:26s} | {row[1]}")
        rs = [r for r in runs if r["category"] == cat and "clean_share" in r]
        seen, clean = set(), []
        for r in rs:  # a clean take is cleaned once per seed, shared by the families
            key = (r["take"], r["seed"])
            if key not in seen:
                seen.add(key)
                clean.append(r)
        ed = np.array([r.get("clean_edited", r["clean_share"]) for r in clean])
        print(
            f"  clean takes ({len(clean)}), through the mocapflow clean path: cells edited {100 * ed.mean():.3f} % "
            f"(worst {100 * ed.max():.3f} %), >= 1 deg {100 * np.mean([r['clean_share'] for r in clean]):.3f} %; "
            f"largest edit {max(r['clean_max_deg'] for r in clean):.1f} deg; takes with an edit > 15 deg "
            f"{sum(r.get('clean_big', 0) > 0 for r in clean)}; null {dict(Counter(r.get('null_source') for r in clean))}"
        )
        if clean and "curve" in clean[0]:
            cur = np.array([r["curve"] for r in clean])
            print(
                "  rate curve (false_alarm_rate -> flagged share of clean cells, mean over takes; ratio): "
                + ", ".join(f"{a:g} -> {m:.2e} (x{m / a:.2f})" for a, m in zip(CURVE_RATES, cur.mean(0), strict=True))
            )
