"""A minimal headless-Chromium driver for the viewer tests: the DevTools protocol over a pipe.

Chromium started with ``--remote-debugging-pipe`` reads protocol commands from its file descriptor 3
and writes replies and events to its descriptor 4, each message JSON ending in a NUL byte. That
needs no WebSocket client and no driver package, and it opens no port. Only the system's Chromium
(Debian package ``chromium``) is used; nothing is downloaded.

    with Browser() as browser:                      # raises BrowserMissing when there is none
        shot = browser.load("file:///.../viewer.html", ready="window.angiohullReady === true")
        shot.png, shot.errors, shot.seconds
"""

from __future__ import annotations

import base64
import json
import os
import queue
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

#: Where Chromium is looked for (``$ANGIOHULL_CHROMIUM`` first).
CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")

#: Flags that work in a container as root without a display: software WebGL (SwiftShader through
#: ANGLE), no sandbox (root), no network activity of the browser's own.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-quic", "--no-first-run", "--no-default-browser-check", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--disable-extensions", "--mute-audio",
         "--hide-scrollbars", "--remote-debugging-pipe")

# The child re-numbers the two pipe ends to 3 (commands in) and 4 (replies out), then becomes Chromium.
_LAUNCHER = ("import os, sys\n"
             "a, b = os.dup(int(sys.argv[1])), os.dup(int(sys.argv[2]))\n"
             "os.dup2(a, 3); os.dup2(b, 4)\n"
             "os.set_inheritable(3, True); os.set_inheritable(4, True)\n"
             "os.execv(sys.argv[3], sys.argv[3:])\n")


class BrowserMissing(RuntimeError):
    """No Chromium executable was found."""


class BrowserError(RuntimeError):
    """The browser failed, answered with an error, or did not answer in time."""


def find_chromium() -> str | None:
    """The path of a Chromium executable, or None."""
    env = os.environ.get("ANGIOHULL_CHROMIUM")
    if env:
        return env if Path(env).is_file() else None
    for name in CANDIDATES:
        found = shutil.which(name)
        if found:
            return found
    return None


@dataclass
class PageShot:
    png: bytes  # the screenshot (PNG)
    errors: list[str] = field(default_factory=list)  # console errors, uncaught exceptions, error log entries
    warnings: list[str] = field(default_factory=list)  # console warnings (not failures)
    seconds: float = 0.0  # from navigation to ready (the page's load and first render)


class Page:
    """An open tab (:meth:`Browser.page`)."""

    def __init__(self, browser: "Browser", target: str, session: str):
        self.browser, self.target, self.session = browser, target, session
        self.seconds = 0.0  # from navigation to ready

    def evaluate(self, expression: str, *, wait: bool = False):
        """The value of a JavaScript expression (``wait``: of the promise it returns)."""
        reply = self.browser.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                       "awaitPromise": wait}, self.session)
        if "exceptionDetails" in reply:
            raise BrowserError(f"{expression}: {reply['exceptionDetails'].get('text')}")
        return reply.get("result", {}).get("value")

    def shot(self, settle_frames: int = 3) -> PageShot:
        """A screenshot after a few animation frames, with the errors and warnings logged so far."""
        frames = ("new Promise(r => { let n = %d; const f = () => (--n > 0 ? requestAnimationFrame(f) : r(true));"
                  " requestAnimationFrame(f); })" % max(1, settle_frames))
        self.evaluate(frames, wait=True)
        png = base64.b64decode(self.browser.send("Page.captureScreenshot", {"format": "png"}, self.session)["data"])
        errors, warnings = self.browser._page_messages(self.session)
        return PageShot(png=png, errors=errors, warnings=warnings, seconds=self.seconds)

    def close(self) -> None:
        self.browser.send("Target.closeTarget", {"targetId": self.target})

    def __enter__(self) -> "Page":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Browser:
    """One headless Chromium process; :meth:`load` opens a page and returns its screenshot."""

    def __init__(self, executable: str | None = None, *, width: int = 1200, height: int = 800,
                 timeout_s: float = 60.0):
        self.executable = executable or find_chromium()
        if self.executable is None:
            raise BrowserMissing("no Chromium found (install the Debian package 'chromium', or set "
                                 "ANGIOHULL_CHROMIUM to its path)")
        self.width, self.height, self.timeout_s = width, height, timeout_s
        self._profile = Path(tempfile.mkdtemp(prefix="angiohull-chromium-"))
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()
        command = [sys.executable, "-c", _LAUNCHER, str(to_child_r), str(from_child_w), self.executable, *FLAGS,
                   f"--user-data-dir={self._profile}", f"--window-size={width},{height}", "about:blank"]
        self._process = subprocess.Popen(command, pass_fds=(to_child_r, from_child_w), stdin=subprocess.DEVNULL,
                                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        os.close(to_child_r)
        os.close(from_child_w)
        self._stderr: list[bytes] = []
        self._messages: queue.Queue = queue.Queue()
        self._next_id = 0
        self._events: list[dict] = []
        self._threads = [threading.Thread(target=self._read, daemon=True),
                         threading.Thread(target=self._drain_stderr, daemon=True)]
        for thread in self._threads:
            thread.start()

    # -- protocol ---------------------------------------------------------------------------------
    def _read(self) -> None:
        buffer = b""
        with os.fdopen(self._from_child, "rb", buffering=0) as stream:
            while True:
                chunk = stream.read(1 << 16)
                if not chunk:
                    self._messages.put(None)
                    return
                buffer += chunk
                *complete, buffer = buffer.split(b"\0")
                for raw in complete:
                    self._messages.put(json.loads(raw))

    def _drain_stderr(self) -> None:
        for line in self._process.stderr:
            self._stderr.append(line)

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Send one command and wait for its reply (events that arrive meanwhile are kept)."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session is not None:
            message["sessionId"] = session
        os.write(self._to_child, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout_s
        while True:
            reply = self._next(deadline, method)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self._events.append(reply)

    def _next(self, deadline: float, waiting_for: str) -> dict:
        try:
            reply = self._messages.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            raise BrowserError(f"no answer to {waiting_for} within {self.timeout_s:g} s") from None
        if reply is None:
            tail = b"".join(self._stderr[-20:]).decode(errors="replace")
            raise BrowserError(f"Chromium closed the pipe while waiting for {waiting_for}; its stderr ends:\n{tail}")
        return reply

    def _wait_event(self, name: str, session: str, deadline: float) -> None:
        for i, event in enumerate(self._events):
            if event.get("method") == name and event.get("sessionId") == session:
                del self._events[i]
                return
        while True:
            event = self._next(deadline, name)
            if event.get("method") == name and event.get("sessionId") == session:
                return
            self._events.append(event)

    # -- pages ------------------------------------------------------------------------------------
    def load(self, url: str, *, ready: str = "document.readyState === 'complete'", settle_frames: int = 3) -> PageShot:
        """Open ``url`` in a new tab, wait until the JavaScript expression ``ready`` is true (then a
        few animation frames more), take a screenshot, close the tab, and return what was seen."""
        with self.page(url, ready=ready) as page:
            return page.shot(settle_frames)

    def page(self, url: str, *, ready: str = "document.readyState === 'complete'") -> "Page":
        """Open ``url`` in a new tab and wait until ``ready`` is true; close it with ``with``."""
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        page = Page(self, target, session)
        try:
            for domain in ("Page", "Runtime", "Log"):
                self.send(f"{domain}.enable", session=session)
            self.send("Emulation.setDeviceMetricsOverride", {"width": self.width, "height": self.height,
                                                              "deviceScaleFactor": 1, "mobile": False}, session)
            start = time.monotonic()
            deadline = start + self.timeout_s
            self.send("Page.navigate", {"url": url}, session)
            self._wait_event("Page.loadEventFired", session, deadline)
            while not page.evaluate(f"Boolean({ready})"):
                if time.monotonic() > deadline:
                    raise BrowserError(f"the page was not ready ({ready}) within {self.timeout_s:g} s")
                time.sleep(0.05)
            page.seconds = time.monotonic() - start
        except BaseException:
            page.close()
            raise
        return page

    def _page_messages(self, session: str) -> tuple[list[str], list[str]]:
        # collect what arrived so far without waiting
        while True:
            try:
                event = self._messages.get_nowait()
            except queue.Empty:
                break
            if event is not None:
                self._events.append(event)
        errors, warnings = [], []
        for event in self._events:
            if event.get("sessionId") != session:
                continue
            method, params = event.get("method"), event.get("params", {})
            if method == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                text = details.get("exception", {}).get("description") or details.get("text", "exception")
                errors.append(f"uncaught: {text}")
            elif method == "Runtime.consoleAPICalled":
                text = " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
                if params.get("type") in ("error", "assert"):
                    errors.append(f"console.{params.get('type')}: {text}")
                elif params.get("type") == "warning":
                    warnings.append(text)
            elif method == "Log.entryAdded":
                entry = params.get("entry", {})
                if entry.get("level") == "error":
                    errors.append(f"log ({entry.get('source')}): {entry.get('text')} {entry.get('url', '')}".rstrip())
                elif entry.get("level") == "warning":
                    warnings.append(entry.get("text", ""))
        return errors, warnings

    # -- lifetime ---------------------------------------------------------------------------------
    def close(self) -> None:
        try:
            if self._process.poll() is None:
                try:
                    self.send("Browser.close")
                except BrowserError:
                    pass
                try:
                    self._process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    self._process.kill()
                    self._process.wait(timeout=10)
        finally:
            try:
                os.close(self._to_child)
            except OSError:
                pass
            for thread in self._threads:  # both end at the pipes' end of file, once Chromium has exited
                thread.join(timeout=10)
            if self._process.stderr is not None:
                self._process.stderr.close()
            shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self) -> "Browser":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
