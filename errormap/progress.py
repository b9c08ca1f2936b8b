"""Minimal progress reporting to stderr (no dependency): ``for i in progress(range(n), "label")``."""
from __future__ import annotations

import sys
import time


class Progress:
    """Prints ``label: k/n (pct) elapsed`` to stderr at most every ``every_s`` seconds."""

    def __init__(self, total: int, label: str, every_s: float = 1.0, stream=None, enabled: bool = True):
        self.total = total
        self.label = label
        self.every_s = every_s
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self._last = -1e9
        self.done = 0

    def update(self, k: int = 1, extra: str = "") -> None:
        self.done += k
        now = time.perf_counter()
        if self.enabled and (now - self._last >= self.every_s or self.done >= self.total):
            self._last = now
            pct = 100.0 * self.done / self.total if self.total else 100.0
            msg = f"\r{self.label}: {self.done}/{self.total} ({pct:5.1f}%) {now - self.t0:7.1f} s {extra}"
            self.stream.write(msg)
            if self.done >= self.total:
                self.stream.write("\n")
            self.stream.flush()


def progress(iterable, label: str, total: int | None = None, enabled: bool = True):
    total = len(iterable) if total is None else total
    p = Progress(total, label, enabled=enabled)
    for item in iterable:
        yield item
        p.update()
