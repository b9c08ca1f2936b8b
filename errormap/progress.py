"""Progress on stderr, the one helper the project uses: ``with Progress(n, "label") as p: ... p.update()``.

Backed by `tqdm <https://tqdm.github.io/>`_ with terminal detection: a bar is drawn only when
the stream is a terminal (tqdm's ``disable=None``), so CI logs and redirected output stay clean.
``enabled=False`` turns it off everywhere. The bar is closed (its line finished) when ``total``
is reached, or by :meth:`Progress.close` / leaving a ``with`` block.
"""
from __future__ import annotations

import math
import sys

from tqdm import tqdm

__all__ = ["Progress"]


class Progress:
    """A progress bar of ``total`` steps labelled ``label``, redrawn at most every ``every_s`` seconds.

    ``total`` may be ``None`` or infinite (a counter without a percentage). ``update(k, extra)``
    advances by ``k`` and shows ``extra`` (free text: the current file, the loss) after the bar.
    """

    def __init__(self, total: int | float | None, label: str, every_s: float = 1.0, stream=None,
                 enabled: bool = True):
        self.total = total if total is not None and math.isfinite(total) else None
        self.label = label
        self.done = 0
        self._bar = tqdm(total=self.total, desc=label, file=stream if stream is not None else sys.stderr,
                         mininterval=every_s, disable=None if enabled else True, leave=True,
                         dynamic_ncols=True)

    @property
    def enabled(self) -> bool:
        """Whether anything is drawn (False off a terminal or when turned off)."""
        return not self._bar.disable

    def update(self, k: int = 1, extra: str = "") -> None:
        self.done += k
        if extra:
            self._bar.set_postfix_str(extra, refresh=False)
        self._bar.update(k)
        if self.total is not None and self.done >= self.total:
            self.close()

    def close(self) -> None:
        self._bar.close()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
