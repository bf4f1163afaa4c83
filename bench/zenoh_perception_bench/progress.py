"""A progress bar on stderr for the long benches."""

from __future__ import annotations

import sys
import time
from typing import Any

#: Away from a terminal (a log file, CI), a line is written each time one of this many equal
#: parts of the work is done, instead of a bar redrawn in place.
LOG_PARTS = 10


class Progress:
    """On a terminal, a one-line bar redrawn in place (``[#####.....]  42/100 label``);
    elsewhere, one such line per tenth of the work."""

    def __init__(self, total: int, stream: Any = None, width: int = 30) -> None:
        self.total = max(total, 1)
        self.done = 0
        self._stream = stream if stream is not None else sys.stderr
        self._terminal = bool(getattr(self._stream, "isatty", lambda: False)())
        self._width = width
        self._last = 0.0
        self._logged = -1  # parts of the work written so far (away from a terminal)
        self._label = ""

    def step(self, label: str | None = None, amount: int = 1) -> None:
        self.done = min(self.done + amount, self.total)
        if label is not None:
            self._label = label
        if self._terminal:
            now = time.monotonic()
            if now - self._last >= 0.1 or self.done == self.total:
                self._last = now
                self._stream.write(f"\r{self._line()}")
                self._stream.flush()
            return
        parts = self.done * LOG_PARTS // self.total
        if parts > self._logged:
            self._logged = parts
            self._stream.write(f"{self._line().rstrip()}\n")
            self._stream.flush()

    def _line(self) -> str:
        filled = round(self._width * self.done / self.total)
        bar = "#" * filled + "." * (self._width - filled)
        return f"[{bar}] {self.done:4d}/{self.total} {self._label:<40.40}"

    def close(self) -> None:
        if self._terminal:
            self._stream.write("\n")
            self._stream.flush()


def tick(progress: Progress | None, label: str) -> None:
    """One step of ``progress``, if there is one."""
    if progress is not None:
        progress.step(label)
