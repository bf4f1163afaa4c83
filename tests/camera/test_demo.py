"""``demo``: the synthetic camera, the whole demo in process, and how each answer compares with
the truth of the frame it answers."""

from __future__ import annotations

import io
import itertools
import re
import threading
from typing import Any

import numpy as np
import pytest

from tests.helpers import STREAMS, Collector, loopback_config, open_session, parse_pairs, wait_until
from zenoh_perception.errors import SettingsError
from zenoh_perception.settings import Settings
from zenoh_perception.wire.frames import decode_image_cdr, decode_raw_frame
from zenoh_perception_bench import demo
from zenoh_perception_bench.demo import (
    MIN_READABLE_SIDE_PX,
    Summary,
    agreement,
    check_frame_bytes,
    format_agreement,
    publish_camera,
)
from zenoh_perception_bench.scene import CameraModel, Effects, MarkerPose, Scene, SceneGenerator


def _tag(tag_id: int, x: float, y: float) -> dict[str, Any]:
    return {
        "tag_id": tag_id,
        "x_tag_center_pixel": x,
        "y_tag_center_pixel": y,
        "closeness_metric": 0.9,
    }


def test_agreement_lists_read_not_read_and_false_ids() -> None:
    scene = SceneGenerator(
        CameraModel.named("VGA"), seed=1, effects=Effects.clean()
    ).scene_from_poses([MarkerPose(3, 0.2, (-0.3, 0.0, 1.5)), MarkerPose(9, 0.2, (0.3, 0.0, 1.5))])
    three = scene.markers[0].corner_mean
    record = {"tags": [_tag(3, three[0] + 0.25, three[1]), _tag(7, 10.0, 10.0)]}
    result = agreement(record, scene.markers)
    assert result.in_view == 2
    assert [(tag_id, round(error, 2)) for tag_id, error in result.read] == [(3, 0.25)]
    assert result.not_read == ((9, "other"),)
    assert result.false_ids == (7,) and result.on_lookalikes == ()
    line = format_agreement(result, scene.markers)
    assert line.startswith("  truth: 2 tags in view; read 3 (0.25 px off); not read 9 (")
    assert "not read (blur, angle or light)" in line
    assert line.endswith("reported where no such tag is: [7]")


def test_a_tag_not_read_says_why() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=2, effects=Effects.clean())
    far = generator.scene_from_poses([MarkerPose(5, 0.1, (0.0, 0.0, 9.0))])
    (marker,) = far.markers
    assert marker.visible and marker.side_px < MIN_READABLE_SIDE_PX
    result = agreement({"tags": []}, far.markers)
    assert result.read == () and result.not_read == ((5, "too far"),)
    line = format_agreement(result, far.markers)
    assert "read none" in line and "too far: under 10 px a side" in line and "no false id" in line


def test_a_false_id_on_a_look_alike_is_named_and_the_summary_adds_up() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=3, effects=Effects.clean())
    scene = next(iter(generator.drive(1, n_tags=1, n_distractors=2)))
    code = next(d for d in scene.distractors if d.mimic_id is not None)
    x, y = code.corners.mean(axis=0)
    result = agreement({"tags": [_tag(int(code.mimic_id or 0), x, y)]}, [], scene.distractors)
    assert result.false_ids == result.on_lookalikes == (code.mimic_id,)
    assert "(1 on the scene's look-alikes)" in format_agreement(result, [])
    summary = Summary()
    summary.add(result)
    summary.add(agreement({"tags": []}, scene.markers))
    text = summary.format(sent=3)
    assert text.startswith("demo: 2 of 3 frames answered")
    assert "1 false ids (1 on the scene's look-alikes" in text


def test_a_selected_false_id_is_counted_as_what_a_rover_would_steer_by() -> None:
    scene = SceneGenerator(
        CameraModel.named("VGA"), seed=1, effects=Effects.clean()
    ).scene_from_poses([MarkerPose(3, 0.2, (-0.3, 0.0, 1.5))])
    three = scene.markers[0].corner_mean
    true_tag, false_tag = _tag(3, three[0], three[1]), _tag(7, 10.0, 10.0)
    steered_right = agreement({"tags": [true_tag, false_tag], "selected": true_tag}, scene.markers)
    steered_wrong = agreement({"tags": [true_tag, false_tag], "selected": false_tag}, scene.markers)
    none = agreement({"tags": [], "selected": {**false_tag, "tag_id": -1}}, scene.markers)
    assert (steered_right.selected_false, steered_wrong.selected_false) == (False, True)
    assert not none.selected_false
    summary = Summary(opencv=Summary())
    summary.add(steered_right)
    assert summary.opencv is not None
    summary.opencv.add(steered_wrong)
    text = summary.format(sent=1)
    assert "0 selected (the tag a rover steers by) where no such tag is" in text
    assert text.splitlines()[1] == (
        "demo: OpenCV's default detector on the same 1 frames: 1 read, 1 false ids, "
        "1 selected where no such tag is (what the service's checks veto)"
    )


def test_the_default_drive_passes_what_a_rover_meets_and_adversaries_need_a_flag() -> None:
    everyday = list(itertools.islice(demo.drive_forever("VGA", 15.0, "DICT_4X4_50"), 3))
    assert all(scene.distractors == () for scene in everyday)
    # the lower band is the surroundings' layer, not the generator's ground
    plain = next(iter(SceneGenerator(CameraModel.named("VGA"), dictionary="DICT_4X4_50").drive(1)))
    assert not np.array_equal(everyday[0].image[-50:], plain.image[-50:])
    adversaries = demo.drive_forever("VGA", 15.0, "DICT_4X4_50", adversaries=True)
    assert any(scene.distractors for scene in itertools.islice(adversaries, 3))


def test_opencv_default_reads_what_the_service_would_be_compared_with() -> None:
    scene = SceneGenerator(
        CameraModel.named("VGA"), seed=1, effects=Effects.clean()
    ).scene_from_poses([MarkerPose(3, 0.2, (-0.3, 0.0, 1.5)), MarkerPose(9, 0.1, (0.3, 0.0, 2.0))])
    record = demo.OpenCvDefault(
        Settings().detection.dictionary, Settings().selection.policy
    ).record(scene.image)
    assert sorted(t["tag_id"] for t in record["tags"]) == [3, 9]
    assert record["selected"]["tag_id"] == 3  # the largest: the closest
    result = agreement(record, scene.markers)
    assert sorted(tag_id for tag_id, _ in result.read) == [3, 9]
    assert not result.selected_false


def _answers(printed: io.StringIO) -> list[tuple[dict[str, str], str]]:
    """Each record line the demo printed with the truth line printed under it."""
    lines = printed.getvalue().splitlines()
    return [
        (parse_pairs(line), lines[i + 1])
        for i, line in enumerate(lines[:-1])
        if line.startswith("[perception/tags] ") and lines[i + 1].startswith("  truth:")
    ]


def _found_ids(truth: str) -> list[int]:
    found = truth.split("; read ", 1)[1].split(";", 1)[0]
    return [int(tag_id) for tag_id in re.findall(r"(\d+) \(", found)]


def test_demo_answers_its_frames_and_compares_each_answer_with_the_truth() -> None:
    printed = io.StringIO()  # written from a Zenoh thread, read here (each call atomic)
    stop = threading.Event()
    codes: list[int] = []
    settings = Settings.from_flat(stats_interval_s=0.0)

    def run() -> None:
        codes.append(demo.main(loopback_config(), settings, fps=30.0, stop=stop, out=printed))

    thread = threading.Thread(target=run)
    thread.start()
    try:
        # however many frames the worker skips on a busy machine, answers keep coming
        wait_until(
            lambda: (
                len(_answers(printed)) >= 3
                and any(fields["selected"] != "-1" for fields, _ in _answers(printed))
            ),
            timeout=120.0,
            what="three answers, one with a tag",
        )
    finally:
        stop.set()
        thread.join(timeout=30.0)
    assert codes == [0]
    answers = _answers(printed)
    seqs = [int(fields["seq"]) for fields, _ in answers]
    assert seqs == sorted(set(seqs))  # frames in order, skipped ones missing
    with_tag = [(fields, truth) for fields, truth in answers if fields["selected"] != "-1"]
    # the selected tag is a real one of that frame: found where the truth puts it
    assert any(int(fields["selected"]) in _found_ids(truth) for fields, truth in with_tag)
    # and the run ends with its summary
    assert printed.getvalue().splitlines()[-1].startswith("demo: ")


def test_camera_publishes_numbered_raw_frames_of_the_scenes(endpoint: str) -> None:
    scenes = list(SceneGenerator(CameraModel.named("VGA"), seed=3).drive(3, n_tags=2))
    seen: list[tuple[int, Scene]] = []
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "demo/image")  # same session: delivered as it is put
        sent = publish_camera(
            session,
            "demo/image",
            iter(scenes),
            fps=1000.0,
            cdr=False,
            stop=threading.Event(),
            limit=2,
            on_frame=lambda stamp, scene: seen.append((stamp, scene)),
        )
        got = [frames.get() for _ in range(sent)]
        assert frames.drain() == []
    assert sent == 2
    assert [id(scene) for _, scene in seen] == [id(scene) for scene in scenes[:2]]
    for seq, (sample, (stamp, scene)) in enumerate(zip(got, seen, strict=True)):
        frame = decode_raw_frame(sample.payload, sample.attachment)
        assert (frame.seq, frame.stamp_ns, frame.frame_id) == (seq, stamp, "demo")
        np.testing.assert_array_equal(frame.pixels, scene.image)


def test_camera_publishes_cdr_frames_when_asked(endpoint: str) -> None:
    scenes = SceneGenerator(CameraModel.named("VGA"), seed=4).drive(1, n_tags=1)
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "demo/image")
        stop = threading.Event()
        assert publish_camera(session, "demo/image", scenes, fps=1000.0, cdr=True, stop=stop) == 1
        sample = frames.get()
    assert sample.attachment is None
    frame = decode_image_cdr(sample.payload)
    assert (frame.width, frame.height, frame.frame_id) == (640, 480, "demo")


def test_a_frame_over_max_frame_bytes_is_refused_before_anything_starts() -> None:
    check_frame_bytes(1000, 1000, "a frame")
    with pytest.raises(SettingsError, match="max_frame_bytes = 999"):
        check_frame_bytes(1000, 999, "a frame")
    small = Settings.from_flat(max_frame_bytes=640 * 480 * 4 - 1)
    with pytest.raises(SettingsError, match=f"is {640 * 480 * 4} bytes"):
        demo.main(loopback_config(), small, resolution="VGA", limit=1)


@pytest.mark.parametrize("camera_only", [True, False])
def test_a_wildcard_input_key_is_refused_the_camera_publishes_on_it(camera_only: bool) -> None:
    with pytest.raises(SettingsError, match="input_key = 'cams/\\*/image'"):
        demo.main(loopback_config(), STREAMS, camera_only=camera_only, limit=1)


def test_a_list_of_input_keys_is_refused_the_camera_publishes_on_one_key() -> None:
    cameras = STREAMS.with_flat(input_key=("cams/front/image", "cams/rear/image"))
    with pytest.raises(SettingsError, match=r"input_key = \['cams/front/image', 'cams/rear"):
        demo.main(loopback_config(), cameras, limit=1)


def test_camera_announces_its_key_while_it_publishes(endpoint: str) -> None:
    scenes = SceneGenerator(CameraModel.named("VGA"), seed=5).drive(2, n_tags=1)
    tokens: list[tuple[str, str]] = []
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "demo/cams/left")

        def on_frame(_stamp: int, _scene: Scene) -> None:
            # the token is there while frames are put
            tokens.extend(
                (str(r.ok.kind), str(r.ok.key_expr))
                for r in session.liveliness().get("@camera/**", timeout=5)
                if r.ok is not None
            )

        stop = threading.Event()
        sent = publish_camera(
            session,
            "demo/cams/left",
            scenes,
            fps=1000.0,
            cdr=True,
            stop=stop,
            limit=1,
            on_frame=on_frame,
        )
        assert sent == 1
        frames.get()
        after = list(session.liveliness().get("@camera/**", timeout=5))
    assert tokens == [("SampleKind.PUT", "@camera/demo/cams/left")]
    assert [r for r in after if r.ok is not None] == []  # withdrawn once the camera stops
