"""Headless Chromium driven over the DevTools protocol (CDP, through the ``websocket-client`` package), for the
tests that open ``report.html`` as a person would: the real browser, a real page load, real mouse clicks.

One browser per :class:`Browser`; one page (a target attached in flat-session mode). Every console message,
uncaught exception, log entry and network request of the page is recorded, so that a test can assert that the
page loaded with no error and asked the network for nothing.
"""

from __future__ import annotations

import base64
import contextlib
import json
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Debian's package name and binary
CHROMIUM = "chromium"


def chromium_path() -> str | None:
    """The Chromium binary on this machine, or None."""
    return shutil.which(CHROMIUM) or shutil.which("chromium-browser")


@dataclass
class PageLog:
    """What the page did: console messages (type, text), exceptions (text), log entries (level, text), the URLs
    it requested."""

    console: list[tuple[str, str]] = field(default_factory=list)
    exceptions: list[str] = field(default_factory=list)
    log: list[tuple[str, str]] = field(default_factory=list)
    requests: list[str] = field(default_factory=list)

    def errors(self) -> list[str]:
        """Every console error, uncaught exception and error-level log entry."""
        return (
            [f"console.{k}: {t}" for k, t in self.console if k in ("error", "assert")]
            + [f"exception: {e}" for e in self.exceptions]
            + [f"log {lvl}: {t}" for lvl, t in self.log if lvl == "error"]
        )


class Browser:
    """A headless Chromium with one page. Use as a context manager; :meth:`close` ends the browser process."""

    def __init__(self, binary: str, width: int = 1280, height: int = 900, timeout_s: float = 60.0) -> None:
        import websocket  # websocket-client (test extra)

        self.profile = tempfile.mkdtemp(prefix="slung-chromium-")
        args = [
            binary,
            "--headless=new",
            "--no-sandbox",  # tests run as root in CI
            "--no-first-run",
            "--no-default-browser-check",
            "--disable-extensions",
            "--disable-background-networking",  # the browser's own update / safe-browsing requests
            "--disable-component-update",
            "--disable-sync",
            "--use-angle=swiftshader",  # software WebGL: the 3D view needs WebGL and CI has no GPU
            "--enable-unsafe-swiftshader",
            f"--window-size={width},{height}",
            f"--user-data-dir={self.profile}",
            "--remote-debugging-port=0",
            "about:blank",
        ]
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        url = self._devtools_url(timeout_s)
        self.ws = websocket.create_connection(url, timeout=timeout_s, suppress_origin=True)
        self.timeout_s = timeout_s
        self._id = 0
        self.events: list[dict[str, Any]] = []
        self.page = PageLog()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable", session=True)
        self.call(
            "Emulation.setDeviceMetricsOverride",
            session=True,
            width=width,
            height=height,
            deviceScaleFactor=1,
            mobile=False,
        )

    def _devtools_url(self, timeout_s: float) -> str:
        assert self.proc.stderr is not None
        deadline = time.monotonic() + timeout_s
        lines = []
        while time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            if not line:
                if self.proc.poll() is not None:
                    break
                continue
            lines.append(line)
            m = re.search(r"DevTools listening on (ws://\S+)", line)
            if m:
                return m.group(1)
        raise RuntimeError("chromium did not start: " + "".join(lines[-5:]))

    # ------------------------------------------------------------------------------------------ protocol ---
    def call(self, method: str, session: bool = False, **params: Any) -> dict[str, Any]:
        """Send one CDP command and wait for its answer (recording every event that arrives meanwhile)."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        self.ws.send(json.dumps(msg))
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self._record(reply)
        raise TimeoutError(method)

    def _record(self, ev: dict[str, Any]) -> None:
        method, p = ev.get("method", ""), ev.get("params", {})
        self.events.append(ev)
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            self.page.console.append((p.get("type", ""), text))
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            self.page.exceptions.append(d.get("exception", {}).get("description") or d.get("text", ""))
        elif method == "Log.entryAdded":
            e = p.get("entry", {})
            self.page.log.append((e.get("level", ""), e.get("text", "")))
        elif method == "Network.requestWillBeSent":
            self.page.requests.append(p.get("request", {}).get("url", ""))

    def pump(self, seconds: float) -> None:
        """Let the page run for ``seconds``, recording its events."""
        end = time.monotonic() + seconds
        while True:
            left = end - time.monotonic()
            if left <= 0:
                return
            self.ws.settimeout(left)
            try:
                self._record(json.loads(self.ws.recv()))
            except Exception as exc:  # the socket timed out: the time is up
                if type(exc).__name__ == "WebSocketTimeoutException":
                    return
                raise
            finally:
                self.ws.settimeout(self.timeout_s)

    # ------------------------------------------------------------------------------------------- page ---
    def open(self, path: Path, settle_s: float = 2.0) -> None:
        """Load a local file and wait for its load event, then ``settle_s`` more."""
        self.call("Page.navigate", session=True, url=path.resolve().as_uri())
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            if any(e.get("method") == "Page.loadEventFired" for e in self.events):
                break
            self.pump(0.2)
        else:
            raise TimeoutError(f"{path} did not load")
        self.pump(settle_s)

    def eval(self, expression: str) -> Any:
        """The value of a JavaScript expression in the page (awaited if it is a promise)."""
        r = self.call("Runtime.evaluate", session=True, expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails']}")
        return r.get("result", {}).get("value")

    def click(self, x: float, y: float) -> None:
        """A real left click at page coordinates (CSS px)."""
        for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", session=True, type=kind, x=x, y=y, button="left", clickCount=1)

    def screenshot(self) -> bytes:
        """PNG of the viewport."""
        return base64.b64decode(self.call("Page.captureScreenshot", session=True, format="png")["data"])

    def close(self) -> None:
        """End the browser (the process this object started) and remove its profile."""
        with contextlib.suppress(Exception):  # the browser may already have closed the socket
            self.ws.close()
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
