"""Error type of the scene generator."""

from __future__ import annotations

from zenoh_perception.errors import PerceptionError


class SceneError(PerceptionError, ValueError):
    """Invalid scene, camera, marker or effect parameters."""
