"""The quickstart's report in a real browser: headless Chromium (the Debian package) opens it
from ``file://``, the player advances frames, the canvas is not blank, no console error; a
marker workspace's report plays its markers, and its reconstruction beside them.

Driven over the DevTools protocol on a pipe (:mod:`mocapflow.plugins.report.browser`);
skipped when no Chromium is installed. Load times are recorded (``record_property``),
not asserted: benchmarks/report.py measures them.
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from report_workspaces import markers_workspace, quickstart_workspace  # noqa: F401 (fixtures)

from mocapflow.plugins.report.browser import Browser, find_chromium

pytestmark = pytest.mark.skipif(
    find_chromium() is None,
    reason="no Chromium installed (apt-get install chromium, or set MOCAPFLOW_CHROMIUM to a Chrome/Chromium binary)",
)

RECT = "(() => {const r = %s.getBoundingClientRect(); return {x: r.x + scrollX, y: r.y + scrollY, width: r.width, height: r.height};})()"


@pytest.fixture(scope="module")
def page(quickstart_workspace, tmp_path_factory):
    from mocapflow.plugins.report.plugin import build_report

    info = build_report(quickstart_workspace, tmp_path_factory.mktemp("browser") / "report")
    with Browser() as b:
        b.load_s = b.open(info["index"].resolve().as_uri())
        b.wait_for("window.MocapReport !== undefined && MocapReport.ready === true")
        yield b


def canvas_pixels(browser: Browser, selector: str) -> np.ndarray:
    from PIL import Image

    browser.eval(f"{selector}.scrollIntoView({{block: 'center'}})")
    png = browser.screenshot(browser.eval(RECT % selector))
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)


def test_page_loads_from_file_url_without_console_errors(page, record_property):
    record_property("index_load_s", round(page.load_s, 3))
    assert page.eval("document.querySelectorAll('section.step').length") == 10
    assert page.eval("document.querySelector('#clips tbody').rows.length") == 8
    assert page.errors == []


def test_search_hit_plays_query_and_hit_side_by_side(page, record_property):
    page.eval("document.querySelector('#step-search .play-hit').click()")
    page.wait_for("MocapReport.players.length > 0 && MocapReport.players[0].playing")
    player = "MocapReport.players[0]"
    assert page.eval(f"{player}.tracks.length") == 2 and page.eval(f"{player}.steps") == 30
    seen, drawn = set(), page.eval(f"{player}.frameCount")
    for _ in range(12):
        seen.add(page.eval(f"{player}.step"))
        time.sleep(0.1)
    assert len(seen) > 3 and page.eval(f"{player}.frameCount") > drawn + 3
    # the query (blue) and the hit (red) are drawn on the light background
    px = canvas_pixels(page, f"{player}.canvas")
    bg = np.array([0xF7, 0xF7, 0xF4])
    assert (np.abs(px - bg).sum(-1) > 60).mean() > 0.005
    blue = (px[..., 2] - px[..., 0] > 60).sum()
    red = (px[..., 0] - px[..., 2] > 60).sum()
    assert blue > 100 and red > 100, (blue, red)
    # pausing stops the steps; the scrubber seeks
    page.eval(f"{player}.pause(); {player}.seek(7)")
    assert page.eval(f"{player}.step") == 7 and page.eval(f"{player}.slider.value") == "7"
    # speed, orbit (drag) and zoom (wheel) change the view
    page.eval(f"{player}.speedSel.value = '2'; {player}.speedSel.dispatchEvent(new Event('change'))")
    assert page.eval(f"{player}.speed") == 2
    yaw, dist = page.eval(f"{player}.yaw"), page.eval(f"{player}.dist")
    page.eval(f"""(() => {{ const c = {player}.canvas, r = c.getBoundingClientRect(), x = r.x + 100, y = r.y + 100;
        c.dispatchEvent(new PointerEvent('pointerdown', {{clientX: x, clientY: y, pointerId: 7, bubbles: true}}));
        c.dispatchEvent(new PointerEvent('pointermove', {{clientX: x + 80, clientY: y + 10, pointerId: 7, bubbles: true}}));
        c.dispatchEvent(new PointerEvent('pointerup', {{clientX: x + 80, clientY: y + 10, pointerId: 7, bubbles: true}}));
        c.dispatchEvent(new WheelEvent('wheel', {{deltaY: 300, bubbles: true, cancelable: true}})); }})()""")
    assert page.eval(f"{player}.yaw") != yaw and page.eval(f"{player}.dist") > dist
    record_property("timings", page.eval("JSON.stringify(MocapReport.timings)"))
    assert page.errors == []


@pytest.mark.parametrize("step", ["nearest", "hits"])
def test_other_retrievals_play(page, step):
    n = page.eval("MocapReport.players.length")
    page.eval(f"document.querySelector('#step-{step} .play-hit').click()")
    page.wait_for(f"MocapReport.players.length > {n} && MocapReport.players[{n}].playing")
    assert page.eval(f"MocapReport.players[{n}].tracks.length") == 2
    assert page.errors == []


def test_digression_map_hover_and_click_play_around_the_cell(page):
    page.eval("document.querySelector('#step-clean .pick-clip').click()")
    page.wait_for("!!document.querySelector('#step-clean .heat-canvas')")
    heat = "document.querySelector('#step-clean .heat-canvas')"
    r = page.eval(RECT.replace("+ scrollX", "").replace("+ scrollY", "") % heat)
    # a cell in the middle of the map, a third of the way down (inside the plot, right of the joint names)
    x, y = r["x"] + 0.5 * r["width"], r["y"] + 0.3 * (r["height"] - 24)
    for kind in ("mousemove", "click"):
        page.eval(f"{heat}.dispatchEvent(new MouseEvent('{kind}', {{clientX: {x}, clientY: {y}, bubbles: true}}))")
    tip = page.eval("document.getElementById('tooltip').textContent")
    assert (
        tip.startswith("joint ") and "frame" in tip and "MDM" in tip and ("flagged by" in tip or "not flagged" in tip)
    )
    player = "MocapReport.players[MocapReport.players.length - 1]"
    page.wait_for(f"{player}.playing")
    assert page.eval(f"{player}.tracks.map(t => t.label.split(' ')[0]).join()") == "original,cleaned"
    assert page.eval(f"{player}.tracks[0].highlight") >= 0
    px = canvas_pixels(page, f"{player}.canvas")
    assert (np.abs(px - np.array([0xF7, 0xF7, 0xF4])).sum(-1) > 60).mean() > 0.005
    heat_px = canvas_pixels(page, heat)
    assert len(np.unique(heat_px.reshape(-1, 3) // 32, axis=0)) > 8  # a colour map, not a flat fill
    assert page.errors == []


def test_a_take_longer_than_the_map_is_wide_is_shown_by_its_largest_values(page):
    # 02_04 has 121 frames; a 200 px map has 110 px of plot: bins of one or two frames
    page.eval("document.querySelector('#step-clean .heatmap').style.width = '150px'")
    page.eval(
        "[...document.querySelectorAll('#step-clean .pick-clip')].find(b => b.textContent.startsWith('02_04')).click()"
    )
    page.wait_for("document.querySelector('#step-clean .heatmap h3').textContent.startsWith('02_04')")
    heat = "document.querySelector('#step-clean .heat-canvas')"
    assert page.eval(f"{heat}.width") == 200
    r = page.eval(RECT.replace("+ scrollX", "").replace("+ scrollY", "") % heat)
    page.eval(
        f"{heat}.dispatchEvent(new MouseEvent('mousemove', {{clientX: {r['x'] + 0.7 * r['width']}, "
        f"clientY: {r['y'] + 5}, bubbles: true}}))"
    )
    tip = page.eval("document.getElementById('tooltip').textContent")
    assert "largest at" in tip and tip.startswith("joint root")
    page.eval("document.querySelector('#step-clean .heatmap').style.width = ''")
    assert page.errors == []


@pytest.fixture(scope="module")
def markers_page(markers_workspace, tmp_path_factory):
    from mocapflow.plugins.report.plugin import build_report

    info = build_report(markers_workspace, tmp_path_factory.mktemp("browser-markers") / "report")
    with Browser() as b:
        b.open(info["index"].resolve().as_uri())
        b.wait_for("window.MocapReport !== undefined && MocapReport.ready === true")
        yield b


def test_marker_takes_play_their_markers(markers_page):
    page = markers_page
    page.eval("document.querySelector('#step-markers .play-markers').click()")
    page.wait_for("MocapReport.players.length > 0 && MocapReport.players[0].playing")
    player = "MocapReport.players[0]"
    assert page.eval(f"{player}.tracks.length") == 1
    assert page.eval(f"{player}.tracks[0].nJ") == 15 and page.eval(f"{player}.tracks[0].bones.length") == 0
    assert page.eval(f"{player}.steps") == 120
    seen = set()
    for _ in range(10):
        seen.add(page.eval(f"{player}.step"))
        time.sleep(0.1)
    assert len(seen) > 3
    # y up in the page: the head markers above the ankle markers (the file is z up)
    heights = page.eval(
        f"(() => {{ const p = {player}, t = p.tracks[0]; "
        "return [...Array(t.nJ).keys()].map(j => p.joint(t, p.step, j)[1]); })()"
    )
    labels = page.eval("MocapReport.model.steps.find(s => s.id === 'markers').views[0].clips[0].labels")
    y = dict(zip([lb.split(":")[-1] for lb in labels], heights, strict=True))
    assert y["LFHD"] > y["LFWT"] > y["LANK"]
    px = canvas_pixels(page, f"{player}.canvas")
    blue = (px[..., 2] - px[..., 0] > 60).sum()
    assert blue > 100, blue  # the markers are drawn
    assert page.errors == []


def test_a_reconstruction_plays_beside_its_input_markers(markers_page):
    page = markers_page
    n = page.eval("MocapReport.players.length")
    page.eval("document.querySelector('#step-recon .play-derived').click()")
    page.wait_for(f"MocapReport.players.length > {n} && MocapReport.players[{n}].playing")
    player = f"MocapReport.players[{n}]"
    labels = page.eval(f"{player}.tracks.map(t => t.label)")
    assert labels[0].startswith("input markers") and labels[1].startswith("recon")
    assert page.eval(f"{player}.tracks[0].bones.length") == 0 and page.eval(f"{player}.tracks[0].nJ") == 15
    # the markers sit on the skeleton: the pelvis markers' mean within 15 cm of the root
    gap = page.eval(
        f"""(() => {{ const p = {player}, s = 10, mk = p.tracks[0], sk = p.tracks[1];
        const root = p.joint(sk, s, 0), pts = [0, 1, 2, 3].map(j => p.joint(mk, s, j));
        const c = [0, 1, 2].map(i => pts.reduce((a, q) => a + q[i], 0) / 4);
        return Math.hypot(c[0] - root[0], c[2] - root[2]); }})()"""
    )
    assert gap < 0.15, gap
    px = canvas_pixels(page, f"{player}.canvas")
    blue = (px[..., 2] - px[..., 0] > 60).sum()
    red = (px[..., 0] - px[..., 2] > 60).sum()
    assert blue > 100 and red > 50, (blue, red)
    assert page.errors == []
