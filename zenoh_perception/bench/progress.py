"""A one-line progress bar on stderr for the long benches."""

from __future__ import annotations

import sys
import time
from typing import Any


class Progress:
    """A one-line progress bar on stderr (``[#####.....]  42/100 label``)."""

    def __init__(self, total: int, stream: Any = None, width: int = 30) -> None:
        self.total = max(total, 1)
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._width = width
        self._last = 0.0
        self._label = ""

    def step(self, label: str | None = None, amount: int = 1) -> None:
        self.done = min(self.done + amount, self.total)
        if label is not None:
            self._label = label
        now = time.monotonic()
        if now - self._last >= 0.1 or self.done == self.total:
            self._last = now
            filled = round(self._width * self.done / self.total)
            bar = "#" * filled + "." * (self._width - filled)
            self._stream.write(f"\r[{bar}] {self.done:4d}/{self.total} {self._label:<40.40}")
            self._stream.flush()

    def close(self) -> None:
        self._stream.write("\n")
        self._stream.flush()


def tick(progress: Progress | None, label: str) -> None:
    """One step of ``progress``, if there is one."""
    if progress is not None:
        progress.step(label)
