"""Several cameras on one ``zenoh-perception run`` process: a stream per concrete key a
wildcard ``input_key`` matches, answered on its own ``{stream}`` keys, with state of its own.
"""

from __future__ import annotations

import json
import signal
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from tests.helpers import (
    Collector,
    OutputLines,
    log_events,
    open_session,
    query_status,
    run_cli,
    running_cli,
    wait_for_status,
    wait_for_subscriber,
    wait_until,
)
from tools.rig import marker_frame, raw_attachment
from zenoh_perception.wire.records import TagCodec, decode_record

_BLOCK = zenoh.CongestionControl.BLOCK
#: Each camera's outputs under its own name.
STREAM_FLAGS = (
    "--input-key",
    "cams/*/image",
    "--compressed-input-key",
    "",
    "--tag-key",
    "cams/{stream}/tag",
    "--record-key",
    "cams/{stream}/perception/tags",
    "--debug-image-key",
    "cams/{stream}/debug",
    "--detections-key",
    "cams/{stream}/detections",
)


@pytest.fixture
def router(endpoint: str) -> Iterator[zenoh.Session]:
    with open_session(mode="router", listen=[endpoint]) as session:
        yield session


def _service(endpoint: str, *flags: str) -> tuple[str, ...]:
    args = ("run", "-m", "client", "-e", endpoint, "--no-multicast-scouting")
    return (*args, "--stats-interval-s", "0.3", *STREAM_FLAGS, *flags)


class Cameras:
    """A publisher per camera name on ``cams/<name>/image``, and collectors of every
    stream's tag and record."""

    def __init__(self, session: zenoh.Session, names: tuple[str, ...]) -> None:
        self.publishers = {
            name: session.declare_publisher(f"cams/{name}/image", congestion_control=_BLOCK)
            for name in names
        }
        self.tags = Collector(session, "cams/*/tag")
        self.records = Collector(session, "cams/*/perception/tags")
        for publisher in self.publishers.values():
            wait_for_subscriber(publisher)

    def put(self, name: str, tag_id: int, seq: int, origin: tuple[int, int] = (200, 150)) -> None:
        frame = marker_frame(640, 480, tag_id, side=120, origin=origin)
        self.publishers[name].put(frame.payload, attachment=raw_attachment(640, 480, seq=seq))

    def answer(self) -> tuple[str, int, str, dict[str, Any]]:
        """The next tag's key and id, and the next record's key and content."""
        tag = self.tags.get(timeout=20)
        record = self.records.get(timeout=20)
        return (
            tag.key,
            TagCodec().decode(tag.payload).tag_id,
            record.key,
            decode_record(record.payload),
        )


def test_each_camera_is_answered_on_its_own_keys_naming_its_stream(
    router: zenoh.Session, endpoint: str
) -> None:
    with running_cli(*_service(endpoint)) as proc:
        status = wait_for_status(router)
        cameras = Cameras(router, ("front", "rear", "arm"))
        expected = {"front": 3, "rear": 7, "arm": 11}
        for seq, (name, tag_id) in enumerate(expected.items(), start=1):
            cameras.put(name, tag_id, seq)
            tag_key, answered, record_key, record = cameras.answer()
            assert tag_key == f"cams/{name}/tag" and answered == tag_id
            assert record_key == f"cams/{name}/perception/tags"
            assert record["stream"] == f"cams/{name}/image"
            assert record["instance"] == status["zid"]
            assert record["selected"]["tag_id"] == tag_id and record["seq"] == seq
        # per-stream status: each camera counted on its own, the totals all of them
        wait_until(
            lambda: (query_status(router) or {}).get("frames", {}).get("processed") == 3,
            what="three frames counted",
        )
        status = query_status(router) or {}
        streams = {s["stream"]: s for s in status["streams"]}
        assert set(streams) == {f"cams/{n}/image" for n in expected}
        for name in expected:
            stream = streams[f"cams/{name}/image"]
            assert stream["name"] == name and stream["tag_key"] == f"cams/{name}/tag"
            assert stream["frames"]["processed"] == 1 and stream["frames"]["rejected"] == 0
        lines = OutputLines(proc)
        line = lines.wait_for("event=stream_stats", timeout=20)
        assert "stream=cams/" in line


def test_one_cameras_marker_never_confirms_anothers(router: zenoh.Session, endpoint: str) -> None:
    """confirm_frames = 2: marker 7 seen once on 'front', then at the same place on 'rear'
    (that camera's first sight of it) stays held back there; 'rear's own second frame
    confirms it."""
    with running_cli(*_service(endpoint, "--confirm-frames", "2")):
        wait_for_status(router)
        cameras = Cameras(router, ("front", "rear"))
        cameras.put("front", 7, 1)
        assert cameras.answer()[1] == -1  # front: first sight
        cameras.put("rear", 7, 1)
        tag_key, tag_id, _, record = cameras.answer()
        assert (tag_key, tag_id, record["tags"]) == ("cams/rear/tag", -1, [])  # rear: first sight
        cameras.put("rear", 7, 2)
        tag_key, tag_id, _, _ = cameras.answer()
        assert (tag_key, tag_id) == ("cams/rear/tag", 7)
        cameras.put("front", 7, 2)
        assert cameras.answer()[:2] == ("cams/front/tag", 7)


def test_frames_beyond_max_streams_are_refused_and_counted(
    router: zenoh.Session, endpoint: str
) -> None:
    with running_cli(*_service(endpoint, "--max-streams", "2")):
        wait_for_status(router)
        cameras = Cameras(router, ("a", "b", "c"))
        for seq, name in enumerate(("a", "b"), start=1):
            cameras.put(name, 5, seq)
            assert cameras.answer()[0] == f"cams/{name}/tag"
        cameras.put("c", 5, 3)
        wait_until(
            lambda: (
                (query_status(router) or {}).get("rejected_by_reason", {}).get("too_many_streams")
                == 1
            ),
            what="the third camera's frame refused",
        )
        status = query_status(router) or {}
        assert [s["name"] for s in status["streams"]] == ["a", "b"]
        cameras.put("a", 5, 4)  # the streams served go on
        assert cameras.answer()[0] == "cams/a/tag"


def test_an_idle_stream_is_forgotten_and_starts_afresh(
    router: zenoh.Session, endpoint: str
) -> None:
    with running_cli(*_service(endpoint, "--stream-idle-s", "1")) as proc:
        wait_for_status(router)
        cameras = Cameras(router, ("front",))
        cameras.put("front", 4, 1)
        assert cameras.answer()[:2] == ("cams/front/tag", 4)
        wait_until(
            lambda: (query_status(router) or {}).get("streams") == [],
            timeout=20,
            what="the idle stream forgotten",
        )
        status = query_status(router) or {}
        assert status["frames"]["processed"] == 1  # the totals keep its counts
        cameras.put("front", 4, 2)
        assert cameras.answer()[:2] == ("cams/front/tag", 4)
        proc.send_signal(signal.SIGINT)
        output = proc.communicate(timeout=10)[0]
    forgotten = log_events(output, "stream_forgotten")
    assert [(e["name"], e["stream"]) for e in forgotten] == [("front", "cams/front/image")]


@pytest.mark.parametrize("setting", ["tag_key", "record_key", "debug_image_key"])
def test_a_wildcard_input_with_an_output_without_stream_is_refused(setting: str) -> None:
    flags = list(STREAM_FLAGS)
    flags[flags.index("--" + setting.replace("_", "-")) + 1] = "plain/" + setting
    result = run_cli("run", "--no-multicast-scouting", *flags, timeout=60)
    assert result.returncode == 2, result.stderr
    error, named, *fixes = result.stderr.strip().splitlines()
    assert "input_key = 'cams/*/image'" in error and "change 1 key(s)" in error
    assert setting in named and "{stream}" in named, named
    assert f'  {setting} = "cams/{{stream}}/plain/{setting}"' in fixes


def test_echo_follows_every_streams_outputs(router: zenoh.Session, endpoint: str) -> None:
    with running_cli(*_service(endpoint)):
        wait_for_status(router)
        cameras = Cameras(router, ("front", "rear"))
        echo = (
            "echo",
            "-m",
            "client",
            "-e",
            endpoint,
            "--no-multicast-scouting",
            "--tag-key",
            "cams/{stream}/tag",
            "--record-key",
            "cams/{stream}/perception/tags",
            "--json",
            "--count",
            "4",
            "--timeout",
            "60",
        )
        with running_cli(*echo) as proc:
            lines = OutputLines(proc)
            lines.wait_for("listening on")
            # each camera counts its frames from 1: no gap, no restart across streams
            cameras.put("front", 3, 1)
            cameras.answer()
            cameras.put("rear", 7, 1)
            cameras.answer()
            summary = lines.wait_for("records=")
        assert "gaps=0" in summary and "restarts=0" in summary and "streams=2" in summary
        printed = [json.loads(line) for line in lines.seen if line.startswith("{")]
        assert {p["key"] for p in printed} == {
            "cams/front/tag",
            "cams/rear/tag",
            "cams/front/perception/tags",
            "cams/rear/perception/tags",
        }


def _list_flags(*keys: str) -> list[str]:
    """STREAM_FLAGS with a list of cameras (``--input-key`` once per key) for the pattern."""
    flags = list(STREAM_FLAGS)
    at = flags.index("--input-key")
    del flags[at : at + 2]
    for key in keys:
        flags += ["--input-key", key]
    return flags


def test_a_list_of_cameras_is_answered_each_on_its_own_keys(
    router: zenoh.Session, endpoint: str
) -> None:
    """``--input-key`` given twice: two concrete keys, each a stream named by the chunk where
    they differ, answered on its own ``{stream}`` keys; a key of neither is not subscribed."""
    args = ("run", "-m", "client", "-e", endpoint, "--no-multicast-scouting")
    flags = _list_flags("cams/front/image", "cams/rear/image")
    with running_cli(*args, "--stats-interval-s", "0.3", *flags) as proc:
        wait_for_status(router)
        cameras = Cameras(router, ("front", "rear"))
        # a camera in no entry: nobody subscribes it
        side = router.declare_publisher("cams/side/image", congestion_control=_BLOCK)
        cameras.publishers["side"] = side
        expected = {"front": 3, "rear": 7}
        for seq, (name, tag_id) in enumerate(expected.items(), start=1):
            cameras.put("side", 5, seq)  # before, on the same link: never answered
            cameras.put(name, tag_id, seq)
            tag_key, answered, record_key, record = cameras.answer()
            assert (tag_key, answered) == (f"cams/{name}/tag", tag_id)
            assert record_key == f"cams/{name}/perception/tags"
            assert record["stream"] == f"cams/{name}/image"
            assert record["selected"]["tag_id"] == tag_id
        wait_until(
            lambda: (query_status(router) or {}).get("frames", {}).get("processed") == 2,
            what="two frames counted",
        )
        status = query_status(router) or {}
        assert status["frames"]["received"] == 2  # nothing of 'side'
        streams = {s["name"]: s for s in status["streams"]}
        assert set(streams) == set(expected)
        for name in expected:
            assert streams[name]["stream"] == f"cams/{name}/image"
            assert streams[name]["tag_key"] == f"cams/{name}/tag"
            assert streams[name]["frames"]["processed"] == 1
        assert status["settings"]["input_key"] == ["cams/front/image", "cams/rear/image"]
        lines = OutputLines(proc)
        started = lines.wait_for("event=started")
        assert "input=cams/front/image,cams/rear/image" in started
        # a stats line per stream, as with a pattern
        names: set[tuple[str, str]] = set()
        while len(names) < 2:  # each named as the README names it, and by its key
            fields = log_events(lines.wait_for("event=stream_stats"), "stream_stats")[0]
            names.add((fields["name"], fields["stream"]))
        assert names == {("front", "cams/front/image"), ("rear", "cams/rear/image")}


def test_a_list_of_cameras_that_overlap_is_refused_in_one_line() -> None:
    flags = _list_flags("cams/*/image", "cams/front/image")
    result = run_cli("run", "--no-multicast-scouting", *flags, timeout=60)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "input_key" in lines[0] and "overlap" in lines[0], lines
