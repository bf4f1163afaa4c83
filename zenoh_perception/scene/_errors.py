"""Error type of the scene generator."""

from __future__ import annotations


class SceneError(ValueError):
    """Invalid scene, camera, marker or effect parameters."""
