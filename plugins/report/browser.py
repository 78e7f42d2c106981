"""Drive a headless Chromium over the DevTools protocol, for the report's tests and benchmark.

The protocol runs over ``--remote-debugging-pipe`` (JSON messages separated by NUL bytes
on file descriptors 3 and 4), so no websocket library and no network port are needed.
Only what the tests use is here: open a page, evaluate JavaScript, collect console errors
and uncaught exceptions, take a screenshot.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import queue
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, cast

from mocapflow.framework.errors import MocapflowError

FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--remote-debugging-pipe",
)


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable (``MOCAPFLOW_CHROMIUM`` first), or None."""
    env = os.environ.get("MOCAPFLOW_CHROMIUM")
    if env:
        return env if Path(env).is_file() else shutil.which(env)
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


class BrowserError(MocapflowError):
    """The browser failed, timed out, or a page raised."""


class Browser:
    """One headless Chromium with a fresh profile and one page.

    Use as a context manager; :attr:`errors` collects console errors, uncaught exceptions and
    error log entries (network failures) of the page, as strings.
    """

    def __init__(
        self, executable: str | None = None, width: int = 1280, height: int = 1600, timeout: float = 60.0
    ) -> None:
        found = executable or find_chromium()
        if not found:
            raise BrowserError("no Chromium found (apt-get install chromium, or set MOCAPFLOW_CHROMIUM)")
        self.executable: str = found
        self.size, self.timeout = (width, height), timeout
        self.errors: list[str] = []
        self.events: list[dict[str, Any]] = []
        self._id = 0
        self._replies: dict[int, queue.Queue[Any]] = {}
        self._lock = threading.Lock()

    # --- process and transport ------------------------------------------------------------
    def __enter__(self) -> Browser:
        self._profile = tempfile.mkdtemp(prefix="mocapflow-chromium-")
        to_browser_r, self._to_browser = os.pipe()
        self._from_browser, from_browser_w = os.pipe()

        def fds() -> None:  # child: the protocol pipes on fds 3 and 4
            a, b = os.dup(to_browser_r), os.dup(from_browser_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = [
            self.executable,
            *FLAGS,
            f"--user-data-dir={self._profile}",
            f"--window-size={self.size[0]},{self.size[1]}",
            "about:blank",
        ]
        # a file, not a pipe: nobody reads Chromium's chatter, and a full pipe would block it
        self._log = open(Path(self._profile) / "stderr.log", "wb")
        self.proc = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=self._log,
            pass_fds=(3, 4, to_browser_r, from_browser_w),
            preexec_fn=fds,
        )
        os.close(to_browser_r)
        os.close(from_browser_w)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()
        try:
            target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        except BrowserError as exc:
            self._log.flush()
            tail = (Path(self._profile) / "stderr.log").read_text(errors="replace")[-600:].strip()
            self.__exit__()
            raise BrowserError(
                f"{self.executable} did not start: {exc}" + (f"; it said: {tail}" if tail else "")
            ) from None
        self.session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Page"):
            self.send(f"{domain}.enable", session=self.session)
        self.send(
            "Emulation.setDeviceMetricsOverride",
            {"width": self.size[0], "height": self.size[1], "deviceScaleFactor": 1, "mobile": False},
            session=self.session,
        )
        return self

    def __exit__(self, *exc: object) -> None:
        with contextlib.suppress(BrowserError, OSError):  # already gone
            self.send("Browser.close", timeout=10)
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._to_browser)
        self._log.close()
        shutil.rmtree(self._profile, ignore_errors=True)

    def _read(self) -> None:
        buf = b""
        while True:
            try:
                chunk = os.read(self._from_browser, 1 << 16)
            except OSError:
                chunk = b""
            if not chunk:
                break
            buf += chunk
            while b"\0" in buf:
                raw, buf = buf.split(b"\0", 1)
                msg = json.loads(raw)
                if "id" in msg:
                    with self._lock:
                        q = self._replies.get(msg["id"])
                    if q is not None:
                        q.put(msg)
                else:
                    self._event(msg)
        os.close(self._from_browser)

    def _event(self, msg: dict[str, Any]) -> None:
        self.events.append(msg)
        method, p = msg.get("method"), msg.get("params", {})
        if method == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
            self.errors.append(
                "console."
                + p["type"]
                + ": "
                + " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            )
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            self.errors.append("exception: " + str(d.get("exception", {}).get("description") or d.get("text")))
        elif method == "Log.entryAdded" and p.get("entry", {}).get("level") == "error":
            e = p["entry"]
            self.errors.append(f"log: {e.get('text')} {e.get('url', '')}".strip())

    def send(
        self,
        method: str,
        params: dict[str, Any] | None = None,
        session: str | None = None,
        timeout: float | None = None,
    ) -> dict[str, Any]:
        """Send one protocol command and wait for its result."""
        with self._lock:
            self._id += 1
            mid = self._id
            q: queue.Queue[Any] = queue.Queue()
            self._replies[mid] = q
        msg = {"id": mid, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        try:
            os.write(self._to_browser, json.dumps(msg).encode() + b"\0")
        except OSError as exc:
            raise BrowserError(f"{method}: the browser is gone ({exc})") from None
        try:
            reply = q.get(timeout=timeout or self.timeout)
        except queue.Empty:
            raise BrowserError(f"{method}: no reply within {timeout or self.timeout} s") from None
        finally:
            with self._lock:
                self._replies.pop(mid, None)
        if "error" in reply:
            raise BrowserError(f"{method}: {reply['error'].get('message')}")
        return cast("dict[str, Any]", reply.get("result", {}))

    # --- page -------------------------------------------------------------------------------
    def open(self, url: str) -> float:
        """Navigate and wait for the load event; returns the seconds it took."""
        n = len(self.events)
        t0 = time.perf_counter()
        self.send("Page.navigate", {"url": url}, session=self.session)
        while time.perf_counter() - t0 < self.timeout:
            if any(e.get("method") == "Page.loadEventFired" for e in self.events[n:]):
                return time.perf_counter() - t0
            time.sleep(0.02)
        raise BrowserError(f"{url}: no load event within {self.timeout} s")

    def eval(self, expression: str, await_promise: bool = True) -> Any:
        """Value of a JavaScript expression (promises awaited); a thrown error raises."""
        r = self.send(
            "Runtime.evaluate",
            {"expression": expression, "awaitPromise": await_promise, "returnByValue": True},
            session=self.session,
        )
        if "exceptionDetails" in r:
            d = r["exceptionDetails"]
            raise BrowserError(f"{expression[:60]}: {d.get('exception', {}).get('description') or d.get('text')}")
        return r.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float = 20.0) -> Any:
        """Poll until the expression is truthy; returns its value."""
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < timeout:
            v = self.eval(expression)
            if v:
                return v
            time.sleep(0.05)
        raise BrowserError(f"timed out waiting for {expression!r}")

    def screenshot(self, clip: dict[str, float] | None = None) -> bytes:
        """PNG bytes of the page (or of ``clip``: x, y, width, height in CSS pixels)."""
        params: dict[str, Any] = {"format": "png"}
        if clip:
            params["clip"] = {**clip, "scale": 1}
        return base64.b64decode(self.send("Page.captureScreenshot", params, session=self.session)["data"])
