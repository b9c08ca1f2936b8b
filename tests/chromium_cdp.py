"""Headless Chromium driven over the DevTools protocol on a pipe (no extra package): load a page from
disk, collect its console errors, failed loads and network requests, and read every ``<img>``'s state.

Used by tests/test_report_pages.py. ``--remote-debugging-pipe`` makes Chromium read commands from fd 3
and write replies/events to fd 4, each JSON message ended by a NUL byte.
"""
from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

CHROMIUM = Path("/usr/bin/chromium")
LOAD_TIMEOUT_S = 60.0      # one page on a loaded 2-core machine loads in well under a second; this is a hang guard
SETTLE_S = 0.3             # time after the load event for late console messages to arrive

PROBE = """JSON.stringify({
  title: document.title,
  images: Array.from(document.images).map(i => ({alt: i.alt, complete: i.complete, width: i.naturalWidth})),
  styled: getComputedStyle(document.documentElement).getPropertyValue('--ink').trim() !== '',
  h1: (document.querySelector('h1') || {}).textContent || ''
})"""


@dataclass
class PageCheck:
    """What Chromium saw on one page: the ``<img>`` states, console/log errors, the URLs requested."""

    url: str
    title: str
    images: list
    styled: bool
    h1: str
    errors: list = field(default_factory=list)
    requests: list = field(default_factory=list)

    @property
    def broken_images(self) -> list:
        return [i for i in self.images if not (i["complete"] and i["width"] > 0)]


class Browser:
    """One headless Chromium for several pages; a context manager."""

    def __init__(self, chromium: Path = CHROMIUM):
        self._profile = tempfile.mkdtemp(prefix="volcomp-chromium-")
        cmd_r, cmd_w = os.pipe()     # we write commands -> Chromium's fd 3
        out_r, out_w = os.pipe()     # Chromium's fd 4 -> we read

        def child_fds():             # runs in the child before exec: put the pipe ends on fds 3 and 4, inheritable
            a, b = os.dup(cmd_r), os.dup(out_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        cmd = [str(chromium), "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", "--disable-extensions", "--mute-audio", f"--user-data-dir={self._profile}",
               "about:blank"]
        self.proc = subprocess.Popen(cmd, preexec_fn=child_fds, close_fds=False, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(cmd_r)
        os.close(out_w)
        self._w, self._r = cmd_w, out_r
        self._buf = b""
        self._id = 0
        self._events: list = []

    # -- protocol ---------------------------------------------------------------------------
    def _send(self, method, params=None, session=None) -> int:
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        return self._id

    def _recv(self, until, timeout_s: float):
        """Read messages, keeping events, until ``until(msg)``; None when ``timeout_s`` passes first."""
        end = time.monotonic() + timeout_s
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                msg = json.loads(raw)
                if until(msg):
                    return msg
                if "method" in msg:
                    self._events.append(msg)
            left = end - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self._r], [], [], left)
            if ready:
                chunk = os.read(self._r, 1 << 20)
                if not chunk:
                    raise RuntimeError(f"Chromium closed the DevTools pipe (exit code {self.proc.poll()})")
                self._buf += chunk

    def call(self, method, params=None, session=None, timeout_s: float = LOAD_TIMEOUT_S) -> dict:
        i = self._send(method, params, session)
        msg = self._recv(lambda m: m.get("id") == i, timeout_s)
        if msg is None:
            raise TimeoutError(f"Chromium did not answer {method} in {timeout_s:g} s")
        if "error" in msg:
            raise RuntimeError(f"{method}: {msg['error']}")
        return msg["result"]

    # -- pages ------------------------------------------------------------------------------
    def check(self, page: Path) -> PageCheck:
        """Load ``page`` from disk in a fresh tab; report what :class:`PageCheck` holds."""
        url = Path(page).resolve().as_uri()
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        sid = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        try:
            for domain in ("Page", "Runtime", "Log", "Network"):
                self.call(f"{domain}.enable", None, sid)
            self._events.clear()
            self.call("Page.navigate", {"url": url}, sid)
            loaded = self._recv(lambda m: m.get("method") == "Page.loadEventFired" and m.get("sessionId") == sid,
                                LOAD_TIMEOUT_S)
            if loaded is None:
                raise TimeoutError(f"{url} did not finish loading in {LOAD_TIMEOUT_S:g} s")
            res = self.call("Runtime.evaluate", {"expression": PROBE, "returnByValue": True}, sid)
            self._recv(lambda m: False, SETTLE_S)
            probe = json.loads(res["result"]["value"])
            out = PageCheck(url, probe["title"], probe["images"], probe["styled"], probe["h1"])
            for e in (e for e in self._events if e.get("sessionId") == sid):
                m, p = e["method"], e.get("params", {})
                if m == "Log.entryAdded" and p["entry"]["level"] == "error":
                    out.errors.append(f"{p['entry'].get('url', '')}: {p['entry']['text']}")
                elif m == "Runtime.consoleAPICalled" and p["type"] in ("error", "assert"):
                    out.errors.append("console: " + " ".join(str(a.get("value", a.get("description", "")))
                                                             for a in p.get("args", [])))
                elif m == "Runtime.exceptionThrown":
                    out.errors.append("exception: " + p["exceptionDetails"].get("text", ""))
                elif m == "Network.requestWillBeSent":
                    out.requests.append(p["request"]["url"])
            return out
        finally:
            self.call("Target.closeTarget", {"targetId": target})

    def close(self):
        try:
            if self.proc.poll() is None:
                self.call("Browser.close", timeout_s=10)
                self.proc.wait(10)
        except (OSError, RuntimeError, TimeoutError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait(10)
        finally:
            os.close(self._w)
            os.close(self._r)
            shutil.rmtree(self._profile, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
