"""Named camera resolutions (width, height) of the ZED family: the one table every part uses."""

from __future__ import annotations

from typing import Final

RESOLUTIONS: Final[dict[str, tuple[int, int]]] = {
    "VGA": (640, 480),
    "HD720": (1280, 720),
    "HD1080": (1920, 1080),
    "HD2K": (2208, 1242),
}
