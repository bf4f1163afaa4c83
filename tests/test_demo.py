"""``demo``: how each answer compares with the truth of the frame it answers."""

from __future__ import annotations

from typing import Any

from zenoh_perception.camera.demo import agreement
from zenoh_perception.scene import CameraModel, Effects, MarkerPose, SceneGenerator


def _tag(tag_id: int, x: float, y: float) -> dict[str, Any]:
    return {
        "tag_id": tag_id,
        "x_tag_center_pixel": x,
        "y_tag_center_pixel": y,
        "closeness_metric": 0.9,
    }


def test_agreement_lists_found_missed_and_false_ids() -> None:
    scene = SceneGenerator(
        CameraModel.named("VGA"), seed=1, effects=Effects.clean()
    ).scene_from_poses([MarkerPose(3, 0.2, (-0.3, 0.0, 1.5)), MarkerPose(9, 0.2, (0.3, 0.0, 1.5))])
    three = scene.markers[0].corner_mean
    record = {"tags": [_tag(3, three[0] + 0.25, three[1]), _tag(7, 10.0, 10.0)]}
    line = agreement(record, scene.markers)
    assert "2 visible" in line
    assert f"found 3@({three[0] + 0.25:.1f},{three[1]:.1f}) c=0.900" in line
    assert "centre error <= 0.25 px" in line
    assert "missed [9]" in line
    assert "false ids [7]" in line


def test_agreement_of_an_empty_answer() -> None:
    scene = SceneGenerator(
        CameraModel.named("VGA"), seed=2, effects=Effects.clean()
    ).scene_from_poses([MarkerPose(5, 0.2, (0.0, 0.0, 1.5))])
    line = agreement({"tags": []}, scene.markers)
    assert "found -" in line and "missed [5]" in line and "false ids -" in line
