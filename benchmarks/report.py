"""Page weight and load time of ``mocapflow report`` in headless Chromium.

Claim: the player's data for a 10-minute take at 30 fps (18 000 frames, 25 joints) loads in
under a second from ``file://``. A workspace is built around one such take (a bundled CMU
walk repeated end to end, written as BVH, ingested, F_E^15 kd-tree, one LNG search whose
hits lie in the long take), its report written, and Chromium opens it ``--rounds`` times:

* page: navigation to the load event of index.html;
* take: clicking a hit -> the long take's data script loaded and decoded (``MocapReport.timings``);
* first frame: clicking a hit -> the player's first frame drawn;
* baseline, same page: the same positions as a JSON array in a script (what a plain JSON
  export would cost the page), parsed; the ratio is baseline / compact binary.

    python benchmarks/report.py            # 10-minute take, 5 rounds
    python benchmarks/report.py --quick    # 15-second take, 1 round (page weight only without Chromium)
    python benchmarks/report.py --workspace runs/quickstart   # an existing workspace's report
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

PIPELINE = """
name: report-load
workspace: {ws}
steps:
  motions: {{uses: formats.load, with: {{paths: ["{take}"], fps: 30}}}}
  fe15: {{uses: features.end_effectors, input: motions, with: {{joints: 5}}}}
  tree: {{uses: indexes.kdtree, input: fe15}}
  search:
    uses: matchers.search
    inputs: {{database: tree, query: motions}}
    with: {{queries: ["long_take:1s-2s"], count: 3}}
"""


def long_take(minutes: float, path: Path) -> int:
    """Write a BVH of a CMU walk repeated for ``minutes`` at 30 fps; returns its frames."""
    from mocapflow.framework.normalize import resample
    from mocapflow.plugins.formats.asf_amc import read_amc
    from mocapflow.plugins.formats.bvh import write_bvh

    walk = resample(read_amc(str(REPO / "examples" / "data" / "cmu" / "16" / "16_15.amc")), 30.0)
    n = int(round(minutes * 60 * 30))
    reps = -(-n // walk.n_frames)
    step = walk.root_translation[-1] - walk.root_translation[0]
    step[1] = 0.0
    root = np.concatenate([walk.root_translation + i * step for i in range(reps)])[:n]
    rot = np.concatenate([walk.rotations] * reps)[:n]
    write_bvh(walk.with_arrays(root_translation=root, rotations=rot, name="long_take"), path)
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="15-second take, 1 round")
    ap.add_argument("--minutes", type=float, default=None)
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("--workspace", help="measure the report of this workspace (its first search hit) instead")
    args = ap.parse_args()
    if args.workspace:
        return measure_workspace(Path(args.workspace), args.rounds or 5)
    minutes = args.minutes or (0.25 if args.quick else 10.0)
    rounds = args.rounds or (1 if args.quick else 5)

    from mocapflow.plugins.report.browser import find_chromium

    chromium = find_chromium() is not None
    if not chromium and not args.quick:
        raise SystemExit("no Chromium installed (apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="report-load-") as tmp_s:
        measure_take(Path(tmp_s), minutes, rounds, chromium)


def measure_take(tmp: Path, minutes: float, rounds: int, chromium: bool) -> None:
    """A workspace around one long take, its report, page weight and (with Chromium) load times."""
    from mocapflow.framework import get_plugin_manager
    from mocapflow.framework.runner import run_pipeline
    from mocapflow.plugins.report.browser import Browser
    from mocapflow.plugins.report.plugin import build_report

    take = tmp / "long_take.bvh"
    n = long_take(minutes, take)
    yaml = tmp / "p.yaml"
    yaml.write_text(PIPELINE.format(ws=tmp / "ws", take=take))
    t0 = time.perf_counter()
    run_pipeline(yaml, workspace=tmp / "ws", pm=get_plugin_manager(entry_points=False))
    t_run = time.perf_counter() - t0
    t0 = time.perf_counter()
    info = build_report(tmp / "ws", tmp / "site")
    t_report = time.perf_counter() - t0
    site = tmp / "site"
    model = json.loads((site / "index.html").read_text().split('id="model">', 1)[1].split("</script>", 1)[0])
    key = next(k for k in model["data_files"] if k.startswith("m/"))
    take_bytes = model["data_files"][key]["bytes"]
    # the baseline: the same positions as a JSON array (4 decimals, i.e. 0.1 mm)
    from mocapflow.plugins.report.blobs import decode_positions, read_blob

    _, meta, parts = read_blob(site / model["data_files"][key]["file"])
    pos = decode_positions(parts["root"], parts["rel"], meta["scale"])
    flat = [None if not np.isfinite(v) else round(float(v), 4) for v in pos.reshape(-1)]
    (site / "data" / "baseline.js").write_text("window.__baseline = " + json.dumps(flat, separators=(",", ":")) + ";\n")
    base_bytes = (site / "data" / "baseline.js").stat().st_size
    kib = lambda x: f"{x / 1024:.0f} KiB"  # noqa: E731 - a one-line helper local to this function
    print(
        f"take: {n} frames ({n / 30 / 60:.1f} min at 30 fps), 25 joints; pipeline {t_run:.1f} s, report written in {t_report:.2f} s"
    )
    print(
        f"page weight: {kib(info['bytes'])} in {info['files']} files; index.html {kib((site / 'index.html').stat().st_size)}, "
        f"scripts+css {kib(sum((site / f).stat().st_size for f in ('report.js', 'player.js', 'report.css')))}, "
        f"the take's data script {kib(take_bytes)} (JSON baseline {kib(base_bytes)}, {base_bytes / take_bytes:.1f}x)"
    )
    if not chromium:
        print("no Chromium installed: load times not measured (apt-get install chromium)")
        return

    click = """(async () => {
      const t0 = performance.now();
      document.querySelector('#step-search .play-hit').click();
      while (!(MocapReport.players.length && MocapReport.players[0].frameCount > 0)) await new Promise(r => setTimeout(r, 2));
      return performance.now() - t0; })()"""
    baseline = """(async () => {
      const t0 = performance.now(), s = document.createElement('script');
      await new Promise((ok, bad) => { s.onload = ok; s.onerror = bad; s.src = 'data/baseline.js'; document.head.appendChild(s); });
      const a = Float32Array.from(window.__baseline, v => v === null ? NaN : v);
      return [performance.now() - t0, a.length]; })()"""
    page_s, take_ms, first_ms, base_ms = [], [], [], []
    with Browser() as b:
        for _ in range(rounds):
            page_s.append(b.open((site / "index.html").as_uri()))
            b.wait_for("window.MocapReport !== undefined && MocapReport.ready === true")
            first_ms.append(b.eval(click))
            take_ms.append(b.eval(f"MocapReport.timings[{json.dumps(key)}].ms"))
            ms, count = b.eval(baseline)
            assert count == pos.size
            base_ms.append(ms)
        errors = list(b.errors)
    med = statistics.median
    print(f"page load (navigation -> load event), median of {rounds}: {med(page_s) * 1000:.0f} ms")
    print(
        f"take load (script -> decoded positions), median of {rounds}: {med(take_ms):.0f} ms "
        f"(min {min(take_ms):.0f}, max {max(take_ms):.0f})"
    )
    print(f"click -> first frame drawn, median of {rounds}: {med(first_ms):.0f} ms")
    print(
        f"JSON baseline (script -> Float32Array), median of {rounds}: {med(base_ms):.0f} ms; "
        f"baseline / compact = {med(base_ms) / med(take_ms):.1f}x"
    )
    print(f"console errors: {errors or 'none'}")


def measure_workspace(ws: Path, rounds: int) -> None:
    """Page weight, page load and click-to-first-frame of an existing workspace's report."""
    from mocapflow.plugins.report.browser import Browser
    from mocapflow.plugins.report.plugin import build_report

    site = Path(tempfile.mkdtemp(prefix="report-load-")) / "site"
    info = build_report(ws, site)
    sizes = {sub: sum(p.stat().st_size for p in (site / sub).rglob("*") if p.is_file()) for sub in ("data", "img")}
    click = """(async () => {
      const t0 = performance.now();
      document.querySelector('.play-hit').click();
      while (!(MocapReport.players.length && MocapReport.players[0].frameCount > 0)) await new Promise(r => setTimeout(r, 2));
      return performance.now() - t0; })()"""
    page_s, first_ms = [], []
    with Browser() as b:
        for _ in range(rounds):
            page_s.append(b.open((site / "index.html").as_uri()))
            b.wait_for("window.MocapReport !== undefined && MocapReport.ready === true")
            first_ms.append(b.eval(click))
        errors = list(b.errors)
    print(
        f"{ws}: page weight {info['bytes'] / 1024:.0f} KiB in {info['files']} files; index.html "
        f"{(site / 'index.html').stat().st_size / 1024:.0f} KiB, data {sizes['data'] / 1024:.0f} KiB, "
        f"plots {sizes['img'] / 1024:.0f} KiB"
    )
    print(
        f"page load, median of {rounds}: {statistics.median(page_s) * 1000:.0f} ms "
        f"(min {min(page_s) * 1000:.0f}, max {max(page_s) * 1000:.0f}); first hit click -> first frame "
        f"{statistics.median(first_ms):.0f} ms"
    )
    print(f"console errors: {errors or 'none'}")


if __name__ == "__main__":
    main()
