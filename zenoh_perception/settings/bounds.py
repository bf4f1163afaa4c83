"""The values a numeric setting accepts, and the limits every tool shares."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Final

from zenoh_perception.files import MAX_TEXT_FILE_BYTES

#: Largest settings file read, bytes.
MAX_SETTINGS_FILE_BYTES: Final = MAX_TEXT_FILE_BYTES
#: Default largest frame payload: far below Zenoh's default message limit
#: (transport/link/rx/max_message_size, 1 GiB), above any camera frame up to 4K BGRA.
DEFAULT_MAX_FRAME_BYTES: Final = 64 << 20
#: How to let larger frames through, for the messages of every tool that refuses one.
FRAME_LIMITS_HINT: Final = (
    "raise max_frame_bytes (--max-frame-bytes) on the camera side and at the service alike, "
    "and beyond 1 GiB also Zenoh's transport/link/rx/max_message_size on every receiver "
    "(see docs/robustness.md)"
)
#: Most entries of ``tag_sizes``, and the largest id (the tag message's id is an int32).
MAX_TAG_SIZES: Final = 1024
MAX_TAG_ID: Final = 2**31 - 1


@dataclass(frozen=True, slots=True)
class Bound:
    """The values a numeric setting accepts: [``low``, ``high``], and 0 when ``zero`` says
    what 0 means there (``off``, ``unknown``)."""

    low: float
    high: float
    zero: str | None = None
    text: str | None = None  # how the bounds read when ``high`` depends on the machine

    def admits(self, value: float) -> bool:
        # an int is compared as it is: math.isfinite of a 400-digit one overflows
        if isinstance(value, float) and not math.isfinite(value):
            return False
        return (self.zero is not None and value == 0) or self.low <= value <= self.high

    def describe(self) -> str:
        text = self.text or f"[{_number(self.low)}, {_number(self.high)}]"
        return text if self.zero is None else f"{text}, or 0 = {self.zero}"


def _number(value: float) -> str:
    """``value`` as written in the documentation: whole numbers without a decimal point."""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def cpu_count() -> int:
    return os.cpu_count() or 1


#: Sizes in ``tag_sizes``, metres.
TAG_SIZE_BOUND: Final = Bound(0.001, 100)
