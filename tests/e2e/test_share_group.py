"""Instances of one share group divide the streams: real ``zenoh-perception run`` processes.

Four cameras (in-process publishers on ``cams/<name>/image`` that announce their key as
``replay`` does) and instances started with ``--share-group`` meet at an in-process Zenoh
router. Two instances hold two streams each; killing one (SIGKILL) hands its streams to the
other within 3 s; a third joining takes its share. After each hand-over every frame is
answered exactly once, and an instance receives only the frames of the streams it holds.
"""

from __future__ import annotations

import json
import queue
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import ExitStack
from typing import Any

import pytest
import zenoh

from tests.helpers import Collector, loopback_config, loopback_endpoint, running_cli, wait_until
from tools.rig import marker_frame
from zenoh_perception.camera.shm import announce
from zenoh_perception.wire.frames import RawFrameMeta
from zenoh_perception.wire.records import decode_record

CAMERAS = ("front", "rear", "left", "right")
GROUP = "rover"
WIDTH, HEIGHT = 320, 240
HANDOVER_S = 3.0


@pytest.fixture
def router() -> Iterator[tuple[str, zenoh.Session]]:
    endpoint = loopback_endpoint()
    session = zenoh.open(loopback_config(mode="router", listen=[endpoint]))
    try:
        yield endpoint, session
    finally:
        session.close()


class Cameras:
    """One publisher and one announcement per camera, on the router's session."""

    def __init__(self, session: zenoh.Session, names: tuple[str, ...]) -> None:
        self.keys = {name: f"cams/{name}/image" for name in names}
        self._frame = marker_frame(WIDTH, HEIGHT, 3, side=80, origin=(60, 50)).payload
        self._publishers = {
            name: session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            for name, key in self.keys.items()
        }
        self._tokens = [announce(session, key) for key in self.keys.values()]

    def put(self, name: str, seq: int) -> None:
        meta = RawFrameMeta(WIDTH, HEIGHT, stamp_ns=time.time_ns(), frame_id=name, seq=seq)
        self._publishers[name].put(self._frame, attachment=meta.to_msgpack())

    def close(self) -> None:
        for token in self._tokens:
            token.undeclare()
        for publisher in self._publishers.values():
            publisher.undeclare()


def _instance(endpoint: str) -> list[str]:
    return [
        "run",
        "-m",
        "client",
        "-e",
        endpoint,
        "--no-multicast-scouting",
        "--share-group",
        GROUP,
        "--input-key",
        "cams/*/image",
        "--compressed-input-key",
        "",
        "--tag-key",
        "cams/{stream}/tag",
        "--record-key",
        "cams/{stream}/perception/tags",
        "--debug-image-key",
        "cams/{stream}/perception/debug",
        "--detections-key",
        "cams/{stream}/perception/detections",
        "--stats-interval-s",
        "0",
    ]


def _statuses(session: zenoh.Session) -> dict[str, dict[str, Any]]:
    """Every instance's status that answered within 1 s, by Zenoh id."""
    found: dict[str, dict[str, Any]] = {}
    replies = session.get(
        "perception/status",
        target=zenoh.QueryTarget.ALL,
        consolidation=zenoh.ConsolidationMode.NONE,
        timeout=1.0,
    )
    for reply in replies:
        if reply.ok is not None:
            status = json.loads(reply.ok.payload.to_string())
            found[status["zid"]] = status
    return found


def _split(session: zenoh.Session, instances: int) -> dict[str, set[str]]:
    """The streams each of ``instances`` instances holds, once they hold every stream between
    them, each floor or ceil of the share, and agree on the members."""
    result: dict[str, set[str]] = {}

    def settled() -> bool:
        statuses = _statuses(session)
        groups = [s["group"] for s in statuses.values()]
        if None in groups:  # an instance still starting
            return False
        held = [set(g["held"]) for g in groups]
        if len(statuses) != instances or any(len(g["members"]) != instances for g in groups):
            return False
        every = set().union(*held)
        low = len(CAMERAS) // instances
        if sum(map(len, held)) != len(CAMERAS) or len(every) != len(CAMERAS):
            return False
        if any(not low <= len(h) <= -(-len(CAMERAS) // instances) for h in held):
            return False
        result.clear()
        result.update({zid: set(s["group"]["held"]) for zid, s in statuses.items()})
        return True

    wait_until(settled, timeout=60.0, what=f"{len(CAMERAS)} streams split over {instances}")
    return result


def _answer_each_once(cameras: Cameras, records: Collector, seq: int) -> Counter[tuple[str, int]]:
    """Put frame ``seq`` of every camera, one at a time (each answered before the next is
    put), and count the records of each (camera, seq) until 2 s pass without one."""
    answered: Counter[tuple[str, int]] = Counter()
    for name in CAMERAS:
        cameras.put(name, seq)
        deadline = time.monotonic() + 20.0
        while (name, seq) not in answered and time.monotonic() < deadline:
            try:
                record = decode_record(records.get(timeout=1.0).payload)
            except queue.Empty:
                continue
            answered[(record["frame_id"], record["seq"])] += 1
    # a second answer to any of them would come now
    while True:
        try:
            record = decode_record(records.get(timeout=2.0).payload)
        except queue.Empty:
            return answered
        answered[(record["frame_id"], record["seq"])] += 1


def _received(session: zenoh.Session) -> dict[str, int]:
    return {zid: s["frames"]["received"] for zid, s in _statuses(session).items()}


def test_instances_split_the_streams_hand_them_over_and_answer_each_frame_once(
    router: tuple[str, zenoh.Session],
) -> None:
    endpoint, session = router
    cameras = Cameras(session, CAMERAS)
    records = Collector(session, "cams/*/perception/tags")
    with ExitStack() as stack:
        stack.callback(cameras.close)
        first = stack.enter_context(running_cli(*_instance(endpoint)))
        second = stack.enter_context(running_cli(*_instance(endpoint)))
        split = _split(session, 2)
        assert sorted(len(held) for held in split.values()) == [2, 2]

        # every frame answered once; each instance receives only its own streams' frames
        rounds = 3
        for seq in range(rounds):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}
        assert _received(session) == {zid: rounds * len(held) for zid, held in split.items()}

        # SIGKILL one: the other holds every stream within HANDOVER_S
        second.kill()
        killed_at = time.monotonic()
        second.wait(timeout=10)
        alone = _split(session, 1)
        handed_over_s = time.monotonic() - killed_at
        assert handed_over_s <= HANDOVER_S + 1.0  # the status query itself takes up to 1 s
        assert list(alone.values()) == [set(cameras.keys.values())]
        for seq in range(rounds, 2 * rounds):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}

        # a third joins: it takes its share, and every frame is still answered once
        stack.enter_context(running_cli(*_instance(endpoint)))
        split = _split(session, 2)
        assert sorted(len(held) for held in split.values()) == [2, 2]
        before = _received(session)
        for seq in range(2 * rounds, 3 * rounds):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}
        after = _received(session)
        assert {zid: after[zid] - before[zid] for zid in after} == {
            zid: rounds * len(held) for zid, held in split.items()
        }
        assert first.poll() is None


def test_a_list_of_cameras_is_split_as_a_pattern_is(router: tuple[str, zenoh.Session]) -> None:
    """``--input-key`` once per camera: the group learns the listed cameras' streams from
    their announcements, and only theirs (another camera announced beside them is no
    stream); each instance holds its share and every frame is answered once."""
    endpoint, session = router
    cameras = Cameras(session, (*CAMERAS, "side"))
    records = Collector(session, "cams/*/perception/tags")
    flags = _instance(endpoint)
    at = flags.index("--input-key")
    flags[at : at + 2] = [f for name in CAMERAS for f in ("--input-key", f"cams/{name}/image")]
    with ExitStack() as stack:
        stack.callback(cameras.close)
        for _ in range(2):
            stack.enter_context(running_cli(*flags))
        split = _split(session, 2)  # the four listed cameras, not "side"
        assert sorted(len(held) for held in split.values()) == [2, 2]
        assert set().union(*split.values()) == {f"cams/{name}/image" for name in CAMERAS}
        for seq in range(2):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}
        assert _received(session) == {zid: 2 * len(held) for zid, held in split.items()}
        statuses = _statuses(session).values()
        streams = {s["name"]: s["tag_key"] for status in statuses for s in status["streams"]}
        assert streams == {name: f"cams/{name}/tag" for name in CAMERAS}
