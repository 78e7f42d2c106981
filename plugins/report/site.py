"""Write the report site: ``index.html``, its script and style, data scripts and images.

Layout of the output directory::

    index.html          the page, with the model inline (JSON)
    report.js player.js report.css
    data/*.js           motion data (see :mod:`.blobs`), loaded when a take is played
    img/<step>/...png   the PNG plots the steps wrote
    .mocapflow-report   marker: the directory may be replaced by the next report

The directory is written next to its destination and renamed into place, so a failed run
leaves the previous report untouched.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from datetime import datetime, timezone
from importlib import resources
from pathlib import Path
from typing import Any

from mocapflow.framework.errors import ConfigError

from .blobs import encode_positions, write_blob
from .model import Model, owned_file

MARKER = ".mocapflow-report"
ASSETS = ("report.js", "player.js", "report.css")


def _asset(name: str) -> str:
    return resources.files("mocapflow.plugins.report").joinpath("assets").joinpath(name).read_text(encoding="utf-8")


def _safe(key: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in key)


def _inline_json(obj: Any) -> str:
    # inside <script type="application/json"> only "</" and "<!--" matter; escape every "<"
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")


def write_data(model: Model, out: Path) -> dict[str, dict[str, Any]]:
    """Write one data script per motion and per cleaned clip; returns ``key -> {file, bytes}``."""
    data = out / "data"
    data.mkdir()
    files = {}
    for key, pos in model.motions.items():
        parts, scale = encode_positions(pos)
        name = f"data/{_safe(key)}.js"
        n = write_blob(
            out / name,
            key,
            {"kind": "motion", "scale": scale, "n_frames": len(pos), "fps": model.fps.get(key, 30.0)},
            parts,
        )
        files[key] = {"file": name, "bytes": n}
    for key, pos in model.markers.items():
        parts, scale = encode_positions(pos)
        name = f"data/{_safe(key)}.js"
        n = write_blob(
            out / name,
            key,
            {"kind": "markers", "scale": scale, "n_frames": len(pos), "fps": model.fps.get(key, 30.0)},
            parts,
        )
        files[key] = {"file": name, "bytes": n}
    for key, c in model.cleaning.items():
        parts, scale = encode_positions(c["positions"])
        name = f"data/{_safe(key)}.js"
        n = write_blob(
            out / name,
            key,
            {
                "kind": "cleaning",
                "scale": scale,
                "n_frames": len(c["positions"]),
                "joints": c["joints"],
                "canonical": c["canonical"],
                "cues": c["cues"],
                "mdm_scale": c["scale"],
            },
            {**parts, "mdm": c["values"], "cue": c["cue"]},
        )
        files[key] = {"file": name, "bytes": n}
    return files


def write_site(model: Model, workspace: Path, dest: Path) -> dict[str, Any]:
    """Write the site for ``model`` (read from ``workspace``, which holds the PNG plots) into
    ``dest`` atomically: an earlier report there is replaced, anything else refused. Returns
    ``index`` (path of index.html), ``files`` and ``bytes`` (page weight of everything)."""
    dest = Path(dest)
    if dest.exists() and not (dest / MARKER).is_file() and (not dest.is_dir() or any(dest.iterdir())):
        raise ConfigError(f"{dest} exists and is not a mocapflow report: choose another --output")
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; a report is meant to be read
    try:
        page = dict(model.page)
        page["data_files"] = write_data(model, tmp)
        page["generated"] = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        page["workspace"] = str(workspace)
        for step in page["steps"]:
            for rel in step["images"]:
                src = workspace / step["id"] / rel
                if not owned_file(workspace / step["id"], src):  # replaced by a link since the model was read
                    continue
                target = tmp / "img" / step["id"] / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, target, follow_symlinks=False)
        for name in ASSETS:
            (tmp / name).write_text(_asset(name), encoding="utf-8")
        html = _asset("index.html").replace("{{title}}", _html_escape(page["title"]))
        html = html.replace("{{model}}", _inline_json(page))
        (tmp / "index.html").write_text(html, encoding="utf-8")
        (tmp / MARKER).write_text(f"written by mocapflow report at {page['generated']}\n")
        files = [p for p in tmp.rglob("*") if p.is_file()]
        total = sum(p.stat().st_size for p in files)
        if dest.exists():
            old = dest.with_name(f".{dest.name}.old-{os.getpid()}-{int(time.time())}")
            dest.rename(old)
            tmp.rename(dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"index": dest / "index.html", "files": len(files), "bytes": total}


def _html_escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")
