"""Headless Chromium driven over the Chrome DevTools Protocol (a websocket, no browser download):
the viewer's browser test, its benchmark (`benchmarks/bench_viewer.py`) and its documentation
picture (`tools/make_viewer_figure.py`) use it; `tests/browser.py` finds the browser for the tests.

WebGL in headless mode runs on the software renderer (SwiftShader through ANGLE): the flags are
in :data:`WEBGL_FLAGS`. The system's Chromium is used (`/usr/bin/chromium`, Debian's package,
installed for `make test` by `tools/setup_system.sh --test`); nothing is downloaded.

    with Browser(find_chromium(), 1280, 800) as b:
        page = b.open("http://127.0.0.1:8080")
        page.wait_for("document.querySelector('canvas') !== null")
        png = page.screenshot()                   # PNG bytes
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
WEBGL_FLAGS = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist")


def find_chromium() -> str | None:
    """The path of a Chromium or Chrome executable on PATH (or ``$CHROMIUM``), else None."""
    env = os.environ.get("CHROMIUM")
    if env:
        return env if Path(env).is_file() else shutil.which(env)
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


class Page:
    """One tab, attached through a flattened CDP session of the browser's websocket."""

    def __init__(self, browser: "Browser", session: str) -> None:
        self.browser, self.session = browser, session

    def send(self, method: str, params: dict | None = None, timeout: float = 60.0) -> dict:
        return self.browser.send(method, params, session=self.session, timeout=timeout)

    def eval(self, expression: str, timeout: float = 60.0):
        """The value of a JavaScript expression (a promise is awaited); a JS exception raises."""
        r = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True},
                      timeout=timeout)
        if "exceptionDetails" in r:
            raise RuntimeError(f"JavaScript error in {expression[:80]!r}: {r['exceptionDetails'].get('text')} "
                               f"{r['exceptionDetails'].get('exception', {}).get('description', '')}")
        return r.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float = 60.0, poll: float = 0.05):
        """Polls ``expression`` until it is truthy; returns its value (TimeoutError after ``timeout`` s)."""
        end = time.monotonic() + timeout
        while True:
            value = self.eval(expression)
            if value:
                return value
            if time.monotonic() > end:
                raise TimeoutError(f"{expression[:120]!r} still false after {timeout:g} s")
            time.sleep(poll)

    def screenshot(self) -> bytes:
        """PNG bytes of the page's viewport."""
        return base64.b64decode(self.send("Page.captureScreenshot", {"format": "png"})["data"])


class Browser:
    """A headless Chromium process with a fresh profile, its DevTools websocket on a free loopback
    port; a context manager that ends the process (and removes the profile) however the block ends."""

    def __init__(self, executable: str, width: int = 1280, height: int = 800, startup_timeout: float = 60.0) -> None:
        self.executable, self.width, self.height = executable, width, height
        self.startup_timeout = startup_timeout
        self.proc: subprocess.Popen | None = None
        self.ws = None
        self._ids = itertools.count(1)
        self._profile = None

    def __enter__(self) -> "Browser":
        from websockets.sync.client import connect

        self._profile = tempfile.mkdtemp(prefix="carlaocc-chromium-")
        args = [self.executable, "--headless=new", "--no-sandbox", "--no-first-run", "--no-default-browser-check",
                "--disable-extensions", "--disable-dev-shm-usage", "--hide-scrollbars", "--mute-audio",
                *WEBGL_FLAGS, f"--window-size={self.width},{self.height}", f"--user-data-dir={self._profile}",
                "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0", "about:blank"]
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True)
        try:
            url = self._devtools_url()
            self.ws = connect(url, max_size=None, open_timeout=self.startup_timeout)
        except BaseException:
            self.close()
            raise
        return self

    def _devtools_url(self) -> str:
        # Chromium prints "DevTools listening on ws://127.0.0.1:<port>/devtools/browser/<id>" on stderr
        end = time.monotonic() + self.startup_timeout
        seen = []
        assert self.proc is not None and self.proc.stderr is not None
        while time.monotonic() < end:
            line = self.proc.stderr.readline()
            if not line:
                if self.proc.poll() is not None:
                    break
                continue
            seen.append(line)
            m = re.search(r"DevTools listening on (ws://\S+)", line)
            if m:
                # drain stderr from now on so the browser never blocks on a full pipe
                import threading

                threading.Thread(target=self.proc.stderr.read, daemon=True).start()
                return m.group(1)
        raise RuntimeError(f"{self.executable} did not start its DevTools server: {''.join(seen)[-2000:]}")

    def send(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 60.0) -> dict:
        """One CDP command; returns its result (events arriving meanwhile are dropped)."""
        msg_id = next(self._ids)
        msg = {"id": msg_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        self.ws.send(json.dumps(msg))
        end = time.monotonic() + timeout
        while True:
            left = end - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"CDP {method}: no answer in {timeout:g} s")
            reply = json.loads(self.ws.recv(timeout=left))
            if reply.get("id") == msg_id:
                if "error" in reply:
                    raise RuntimeError(f"CDP {method}: {reply['error']}")
                return reply.get("result", {})

    def open(self, url: str) -> Page:
        """A new tab at ``url`` (the viewport ``width`` x ``height``)."""
        target = self.send("Target.createTarget", {"url": url})
        session = self.send("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})["sessionId"]
        page = Page(self, session)
        page.send("Emulation.setDeviceMetricsOverride", {"width": self.width, "height": self.height,
                                                         "deviceScaleFactor": 1, "mobile": False})
        return page

    def close(self) -> None:
        if self.ws is not None:
            try:
                self.ws.close()
            except Exception:
                pass
            self.ws = None
        if self.proc is not None:
            if self.proc.poll() is None:
                self.proc.terminate()
                try:
                    self.proc.wait(10)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait(10)
            self.proc = None
        if self._profile:
            shutil.rmtree(self._profile, ignore_errors=True)
            self._profile = None

    def __exit__(self, *exc) -> None:
        self.close()
