"""A headless Chromium driven over the DevTools protocol, to check and photograph results pages.

Chromium is started with ``--remote-debugging-pipe``: it reads protocol messages (JSON, each ending
in a NUL byte) on its file descriptor 3 and writes on 4, so no port and no websocket library are
needed. WebGL runs on SwiftShader (software), so the 3D views render on machines without a GPU.
Used by the slow tests and by scripts/page_screenshot.py.
"""
from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import cv2
import numpy as np

from recon.errors import ReconError

EXECUTABLES = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome", "chrome")


def find_chromium() -> str | None:
    """A Chromium on PATH ($RECON_CHROMIUM first), or None."""
    for name in (os.environ.get("RECON_CHROMIUM"), *EXECUTABLES):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


class Chromium:
    """One headless browser with one tab. ``console``: the page's console messages and uncaught
    exceptions as (level, text), in order."""

    def __init__(self, executable: str | None = None, size: tuple[int, int] = (1280, 900), timeout: float = 60.0):
        exe = executable or find_chromium()
        if exe is None:
            raise ReconError("no Chromium found (Debian: apt-get install chromium-headless-shell)")
        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="recon-chromium-")
        to_child, self._w = os.pipe()
        self._r, from_child = os.pipe()

        def fds():  # the child's protocol descriptors: 3 to read, 4 to write
            os.dup2(to_child, 3)
            os.dup2(from_child, 4)
        args = [exe, "--headless", "--remote-debugging-pipe", f"--user-data-dir={self.profile}",
                f"--window-size={size[0]},{size[1]}", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                "--no-first-run", "--no-default-browser-check", "--hide-scrollbars", "--mute-audio"]
        if hasattr(os, "geteuid") and os.geteuid() == 0:
            args.append("--no-sandbox")  # Chromium refuses to run its sandbox as root
        self.proc = subprocess.Popen(args + ["about:blank"], preexec_fn=fds, pass_fds=(3, 4),
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_child)
        os.close(from_child)
        self._next, self._replies, self.console = 0, {}, []
        self._cond = threading.Condition()
        threading.Thread(target=self._read, daemon=True).start()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride", width=size[0], height=size[1], deviceScaleFactor=1,
                  mobile=False, session=True)
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", session=True)

    def _read(self):
        buf = b""
        while True:
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                break
            buf += chunk
            *messages, buf = buf.split(b"\0")
            for m in messages:
                msg = json.loads(m)
                with self._cond:
                    if "id" in msg:
                        self._replies[msg["id"]] = msg
                    else:
                        self._event(msg)
                    self._cond.notify_all()
        with self._cond:
            self._replies[-1] = {"error": {"message": "Chromium exited"}}
            self._cond.notify_all()

    def _event(self, msg: dict):
        p = msg.get("params", {})
        if msg.get("method") == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            self.console.append((p.get("type", "log"), text))
        elif msg.get("method") == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            self.console.append(("exception", d.get("exception", {}).get("description", d.get("text", ""))))
        elif msg.get("method") == "Log.entryAdded":
            e = p.get("entry", {})
            self.console.append((e.get("level", "info"), f"{e.get('source')}: {e.get('text')} {e.get('url', '')}"))

    def call(self, method: str, session: bool = False, **params) -> dict:
        with self._cond:
            self._next += 1
            n = self._next
        msg = {"id": n, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        with self._cond:
            while n not in self._replies and -1 not in self._replies:
                if not self._cond.wait(max(deadline - time.monotonic(), 0)) and time.monotonic() > deadline:
                    raise TimeoutError(f"Chromium did not answer {method} within {self.timeout:.0f} s")
            reply = self._replies.pop(n, None) or self._replies[-1]
        if "error" in reply:
            raise RuntimeError(f"{method}: {reply['error'].get('message')}")
        return reply.get("result", {})

    def open(self, url: str | Path) -> None:
        """Load a page (a path becomes a file:// URL) and wait for its load event."""
        url = Path(url).resolve().as_uri() if isinstance(url, Path) or "://" not in str(url) else str(url)
        self.call("Page.navigate", url=url, session=True)
        self.wait_for("document.readyState === 'complete'")

    def eval(self, expression: str):
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True, session=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails'].get('text')}")
        return r.get("result", {}).get("value")

    def wait_for(self, expression: str, timeout: float | None = None, every: float = 0.1):
        """Poll ``expression`` until it is truthy; its value."""
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            value = self.eval(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"waited {timeout or self.timeout:.0f} s for {expression}")
            time.sleep(every)

    def screenshot(self) -> np.ndarray:
        """The tab's viewport, RGB (H, W, 3) uint8."""
        png = base64.b64decode(self.call("Page.captureScreenshot", format="png", session=True)["data"])
        return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        for fd in (self._w, self._r):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
