"""The bench's side of its service processes: raw frames, the camera, SIGTERM, flags."""

from __future__ import annotations

import signal

import msgpack
import numpy as np
import pytest
import zenoh

from zenoh_perception_bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception_bench.processes import (
    FLOOR,
    Camera,
    frames_of,
    is_idle,
    raw_frame,
    raw_frames,
    services,
    sigterm_exits,
)
from zenoh_perception_bench.scene import CameraModel, SceneGenerator


def test_a_raw_frame_is_the_bgra_payload_and_its_attachment() -> None:
    image = np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4)
    frame = raw_frame(image, 5)
    assert frame.payload == image.tobytes()
    meta = msgpack.unpackb(frame.attachment, raw=False)
    assert (meta["width"], meta["height"], meta["seq"], meta["frame_id"]) == (3, 2, 5, "bench")


def test_raw_frames_number_the_scenes_in_order() -> None:
    generator = SceneGenerator(CameraModel.named("VGA"), seed=4)
    frames = raw_frames(generator.random_scene(1, 0) for _ in range(3))
    assert [msgpack.unpackb(f.attachment, raw=False)["seq"] for f in frames] == [0, 1, 2]


def test_status_counts_and_idleness() -> None:
    # idle: every frame received is accounted for (none waits in the mailbox)
    counts = {"received": 5, "processed": 3, "dropped": 1, "rejected": 1}
    assert frames_of({"frames": counts}) == counts
    assert is_idle({"frames": counts})
    assert not is_idle({"frames": counts | {"received": 6}})


def test_a_camera_without_shared_memory_puts_the_bytes_themselves() -> None:
    camera = Camera(shm=False)
    assert camera.load(b"abc") == b"abc"
    assert camera.summary() == {"shm": False, "put": "bytes (Zenoh copies them on put)"}


def test_sigterm_exits_through_the_finally_blocks_and_restores_the_handler() -> None:
    before = signal.getsignal(signal.SIGTERM)
    cleaned = []
    with pytest.raises(SystemExit) as exited, sigterm_exits():
        try:
            signal.raise_signal(signal.SIGTERM)
        finally:
            cleaned.append(True)
    assert exited.value.code == 128 + signal.SIGTERM
    assert cleaned == [True]
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.timeout(120)
def test_services_run_with_the_flags_given_and_the_floor_without() -> None:
    endpoint = loopback_endpoint()
    with (
        zenoh.open(loopback_config(listen=[endpoint])) as session,
        services(("opencv", FLOOR), endpoint, session, flags=("--no-verify",)) as remotes,
    ):
        assert remotes["opencv"].status()["settings"]["verify"] is False
        floor_command = remotes[FLOOR].service.proc.args
        assert isinstance(floor_command, list) and "--no-verify" not in floor_command
    with (
        zenoh.open(loopback_config(listen=[endpoint])) as session,
        services(("opencv",), endpoint, session) as remotes,
    ):
        assert remotes["opencv"].status()["settings"]["verify"] is True
