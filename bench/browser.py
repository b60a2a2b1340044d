"""Headless Chromium driven over the DevTools protocol through a pipe (no extra package, no port).

Used by ``make screenshot`` (a full-page PNG of the report) and by the report's browser test (open
a page from disk with the network off, then inspect it). Debian: ``apt-get install chromium``.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Self

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_browser() -> str | None:
    """Path of a Chromium-family browser on PATH (``RESTI_BROWSER`` overrides), else None."""
    env = os.environ.get("RESTI_BROWSER")
    if env:
        return env if Path(env).exists() else shutil.which(env)
    for name in CANDIDATES:
        exe = shutil.which(name)
        if exe:
            return exe
    return None


class BrowserError(RuntimeError):
    pass


class Browser:
    """One headless browser with one page. ``with Browser() as b: b.open(path); b.evaluate(js)``.

    The network is off: requests to anything but ``file:`` fail (offline emulation and a dead
    proxy), and every request the page makes is recorded in :attr:`requests` with its outcome.
    """

    def __init__(self, exe: str | None = None, *, width: int = 1280, height: int = 900, timeout: float = 60.0):
        self.exe = exe or find_browser()
        if not self.exe:
            raise BrowserError("no Chromium-family browser on PATH (Debian: apt-get install chromium)")
        self.width, self.height, self.timeout = width, height, timeout
        self._id = 0
        self._buf = b""
        self.events: list[dict] = []
        self.requests: dict[str, dict] = {}

    # -- process and transport
    def __enter__(self) -> Self:
        self._profile = tempfile.mkdtemp(prefix="resti-browser-")
        r_cmd, self._w = os.pipe()
        self._r, w_res = os.pipe()

        def fds():
            os.dup2(r_cmd, 3)
            os.dup2(w_res, 4)

        self.proc = subprocess.Popen(
            [self.exe, "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe",
             "--no-first-run", "--no-default-browser-check", "--disable-extensions", "--disable-sync",
             "--disable-background-networking", "--disable-component-update", "--disable-quic",
             "--proxy-server=127.0.0.1:9", "--proxy-bypass-list=<-loopback>", "--hide-scrollbars",
             f"--user-data-dir={self._profile}", f"--window-size={self.width},{self.height}", "about:blank"],
            pass_fds=(3, 4), preexec_fn=fds,  # noqa: PLW1509 (fds 3 and 4 carry the protocol)
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(r_cmd)
        os.close(w_res)
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Network", "Runtime"):
            self.call(f"{domain}.enable", session=True)
        self.call("Network.emulateNetworkConditions", {"offline": True, "latency": 0, "downloadThroughput": -1,
                                                       "uploadThroughput": -1}, session=True)
        self.call("Emulation.setDeviceMetricsOverride", {"width": self.width, "height": self.height,
                                                         "deviceScaleFactor": 1, "mobile": False}, session=True)
        return self

    def __exit__(self, *exc) -> None:
        try:
            self._send("Browser.close", {})
            self.proc.wait(timeout=10)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        finally:
            for fd in (self._w, self._r):
                try:
                    os.close(fd)
                except OSError:
                    pass
            shutil.rmtree(self._profile, ignore_errors=True)

    def _send(self, method: str, params: dict, session: bool = False) -> int:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        return self._id

    def _recv(self, deadline: float) -> dict:
        import select

        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError("the browser did not answer in time")
            ready, _, _ = select.select([self._r], [], [], left)
            if not ready:
                continue
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise BrowserError("the browser closed the connection")
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\0", 1)
        msg = json.loads(raw)
        if "method" in msg:
            self._event(msg)
        return msg

    def _event(self, msg: dict) -> None:
        self.events.append(msg)
        p = msg.get("params", {})
        m = msg["method"]
        if m == "Network.requestWillBeSent":
            self.requests[p["requestId"]] = {"url": p["request"]["url"], "status": None, "failed": None}
        elif m == "Network.responseReceived" and p["requestId"] in self.requests:
            self.requests[p["requestId"]]["status"] = p["response"].get("status")
        elif m == "Network.loadingFailed" and p["requestId"] in self.requests:
            self.requests[p["requestId"]]["failed"] = p.get("errorText") or "failed"

    def call(self, method: str, params: dict | None = None, *, session: bool = False) -> dict:
        i = self._send(method, params or {}, session)
        deadline = time.monotonic() + self.timeout
        while True:
            msg = self._recv(deadline)
            if msg.get("id") == i:
                if "error" in msg:
                    raise BrowserError(f"{method}: {msg['error'].get('message')}")
                return msg.get("result", {})

    def wait_event(self, method: str, *, since: int = 0) -> dict:
        deadline = time.monotonic() + self.timeout
        while True:
            for e in self.events[since:]:
                if e["method"] == method:
                    return e
            since = len(self.events)
            self._recv(deadline)

    # -- page
    def open(self, path: Path) -> str:
        """Load a local file and wait for its load event and its images; returns the file URL."""
        url = Path(path).resolve().as_uri()
        self.requests.clear()
        mark = len(self.events)
        res = self.call("Page.navigate", {"url": url}, session=True)
        if res.get("errorText"):
            raise BrowserError(f"cannot open {url}: {res['errorText']}")
        self.wait_event("Page.loadEventFired", since=mark)
        # lazy images: scroll through the page so every one is requested, then wait for them
        self.evaluate("""(async () => {
            for (const img of document.images) { img.loading = 'eager'; }
            await Promise.all([...document.images].map(i => i.complete ? null :
                new Promise(r => { i.onload = i.onerror = r; })));
            return true; })()""", await_promise=True)
        return url

    def evaluate(self, expression: str, *, await_promise: bool = False):
        res = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                             "awaitPromise": await_promise}, session=True)
        if res.get("exceptionDetails"):
            raise BrowserError(f"script failed: {res['exceptionDetails'].get('text')}: "
                               f"{res['exceptionDetails'].get('exception', {}).get('description')}")
        return res.get("result", {}).get("value")

    def screenshot(self, png: Path, *, full_page: bool = True) -> Path:
        """PNG of the page; ``full_page``: the whole document, not only the window."""
        params = {"format": "png", "captureBeyondViewport": full_page}
        if full_page:
            m = self.call("Page.getLayoutMetrics", session=True)
            size = m.get("cssContentSize") or m.get("contentSize")
            params["clip"] = {"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1}
        data = self.call("Page.captureScreenshot", params, session=True)["data"]
        png = Path(png)
        png.parent.mkdir(parents=True, exist_ok=True)
        png.write_bytes(base64.b64decode(data))
        return png


# Checks run in the page: images that did not load, elements wider than the page (outside any
# scrolling box), and every link with its resolved URL.
PAGE_CHECKS = r"""(() => {
  const W = document.documentElement.clientWidth;
  const scrolls = el => { for (let a = el.parentElement; a; a = a.parentElement) {
      const o = getComputedStyle(a).overflowX; if (o === 'auto' || o === 'scroll' || o === 'hidden') return true; }
    return false; };
  const over = [];
  for (const el of document.body.querySelectorAll('*')) {
    const r = el.getBoundingClientRect();
    if (r.width === 0 && r.height === 0) continue;
    if (r.right > W + 1 && !scrolls(el)) over.push(el.tagName + (el.id ? '#' + el.id : '') +
        (el.className && typeof el.className === 'string' ? '.' + el.className.split(' ')[0] : '') +
        ' right=' + Math.round(r.right));
  }
  return {
    width: W, scrollWidth: document.documentElement.scrollWidth, title: document.title,
    images: [...document.images].map(i => ({src: i.src, ok: i.complete && i.naturalWidth > 0,
                                            width: i.getBoundingClientRect().width})),
    links: [...document.querySelectorAll('a[href]')].map(a => a.href),
    overflowing: over.slice(0, 20), n_overflowing: over.length,
    text: document.body.innerText,
    ids: [...document.querySelectorAll('[id]')].map(e => e.id),
  };
})()"""
