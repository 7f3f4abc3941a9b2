"""Headless Chromium for the tests of report.html: Debian's ``chromium`` driven over the DevTools
protocol on a pipe (``--remote-debugging-pipe``), with no driver or package beyond the browser.

:class:`Page` opens one file in a fresh profile and records the page's console messages, uncaught
exceptions, browser log entries and every URL the page requests, so that a test can assert that
nothing failed and nothing left the machine. WebGL runs on SwiftShader (software).
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (apt-get install chromium): the browser check of report.html is skipped"
)
#: Flags for a headless run as root with no network service and no GPU.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--disable-dev-shm-usage")
#: WebGL on the CPU (SwiftShader): newer Chromium refuses its software fallback without the second flag.
WEBGL_FLAGS = ("--use-angle=swiftshader", "--enable-unsafe-swiftshader")


class Page:
    """One page of a headless Chromium, open on ``url``; use as a context manager.

    ``evaluate(expression)`` returns the JavaScript value (promises awaited); ``mouse(kind, x, y)``
    sends a real mouse event; ``screenshot()`` returns PNG bytes; ``problems()`` lists the console
    errors, uncaught exceptions and error log entries so far; ``requests`` the URLs requested."""

    def __init__(self, url: str, profile: Path, size: tuple[int, int] = (1280, 1600), timeout: float = 60.0):
        self.timeout = timeout
        self.requests: list[str] = []
        self.events: list[dict] = []
        self._id, self._buffer = 0, b""
        to_browser, from_browser = os.pipe(), os.pipe()

        def pipes():  # the browser reads commands on fd 3 and writes replies on fd 4
            read_end, write_end = os.dup(to_browser[0]), os.dup(from_browser[1])
            os.dup2(read_end, 3)
            os.dup2(write_end, 4)

        cmd = [CHROMIUM, *FLAGS, *WEBGL_FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
               "--remote-debugging-pipe", "about:blank"]
        self.process = subprocess.Popen(cmd, pass_fds=(3, 4), preexec_fn=pipes, stdin=subprocess.DEVNULL,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_browser[0])
        os.close(from_browser[1])
        self._write, self._read = to_browser[1], from_browser[0]
        target = self._send("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self._send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime", "Log", "Page", "Network"):
            self.send(f"{domain}.enable")
        self.send("Page.navigate", {"url": url})

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        try:
            self._send("Browser.close")
        except (OSError, EOFError, TimeoutError):
            pass
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()
        for fd in (self._write, self._read):
            try:
                os.close(fd)
            except OSError:
                pass

    def send(self, method: str, params: dict | None = None) -> dict:
        """A DevTools command to the page's session; its result."""
        return self._send(method, params, self.session)

    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        self._id += 1
        message = {"id": self._id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._write, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._next(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self._record(reply)

    def _next(self, deadline: float) -> dict:
        import select

        while b"\0" not in self._buffer:
            if not select.select([self._read], [], [], max(deadline - time.monotonic(), 0))[0]:
                raise TimeoutError("no reply from chromium")
            chunk = os.read(self._read, 1 << 20)
            if not chunk:
                raise EOFError("chromium closed its pipe")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def _record(self, event: dict) -> None:
        self.events.append(event)
        if event.get("method") == "Network.requestWillBeSent":
            self.requests.append(event["params"]["request"]["url"])

    def evaluate(self, expression: str):
        result = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True, "awaitPromise": True})
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression[:80]}: {result['exceptionDetails'].get('exception', {}).get('description')}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 30.0):
        """Poll ``expression`` until it is truthy (its value), else TimeoutError."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.05)
        raise TimeoutError(f"{expression} stayed false for {timeout} s")

    def mouse(self, kind: str, x: float, y: float, buttons: int = 0) -> None:
        """A mouse event at page pixel (x, y): 'mouseMoved', 'mousePressed' or 'mouseReleased'
        (left button)."""
        params = {"type": kind, "x": x, "y": y, "buttons": buttons}
        if kind != "mouseMoved":
            params.update(button="left", clickCount=1)
        elif buttons:
            params["button"] = "left"
        self.send("Input.dispatchMouseEvent", params)

    def screenshot(self) -> bytes:
        return base64.b64decode(self.send("Page.captureScreenshot", {"format": "png"})["data"])

    def problems(self) -> list[str]:
        """Console errors, uncaught exceptions and error-level log entries, as text."""
        out = []
        for event in self.events:
            method, params = event.get("method"), event.get("params", {})
            if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                out.append("console: " + " ".join(str(a.get("value", a.get("description"))) for a in params["args"]))
            elif method == "Runtime.exceptionThrown":
                details = params["exceptionDetails"]
                out.append("exception: " + str(details.get("exception", {}).get("description", details.get("text"))))
            elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
                out.append(f"log ({params['entry']['source']}): {params['entry']['text']}")
        return out
