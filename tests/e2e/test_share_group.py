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
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.helpers import (
    REPO,
    Collector,
    loopback_config,
    loopback_endpoint,
    run_cli,
    running_cli,
    sigterm_exit,
    wait_until,
)
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


# -- peers that are hostile, careless or wedged --------------------------------------------------


def _group_status(session: zenoh.Session) -> dict[str, dict[str, Any]]:
    return {zid: s["group"] for zid, s in _statuses(session).items() if s["group"] is not None}


def test_hostile_announcements_and_bare_members_break_nothing(
    router: tuple[str, zenoh.Session],
) -> None:
    """Wildcard and oversized camera announcements, and bare member tokens (no service
    behind them), once killed the group's thread or black-holed cameras. Each is ignored or
    left out now: the two instances split the four cameras, answer each frame once, and when
    one is killed the other takes everything."""
    endpoint, session = router
    cameras = Cameras(session, CAMERAS)
    records = Collector(session, "cams/*/perception/tags")
    hostile = [
        session.liveliness().declare_token(key)
        for key in (
            "@camera/cams/*/image",
            "@camera/cams/**",
            "@camera/cams/" + "x" * 300 + "/image",
        )
    ]
    with ExitStack() as stack:
        stack.callback(cameras.close)
        for token in hostile:
            stack.callback(token.undeclare)
        first = stack.enter_context(running_cli(*_instance(endpoint)))
        second = stack.enter_context(running_cli(*_instance(endpoint)))
        split = _split(session, 2)
        fingerprint = next(iter(_group_status(session).values()))["fingerprint"]
        for i in range(20):  # bare tokens: a member's key and fingerprint, nothing behind
            key = f"perception/alive/group/{GROUP}/member/abcdef{i:02x}/{fingerprint}"
            stack.callback(session.liveliness().declare_token(key).undeclare)
        stack.callback(session.liveliness().declare_token("@camera/**").undeclare)
        wait_until(
            lambda: all(len(g["silent"]) == 20 for g in _group_status(session).values()),
            what="the bare members seen, and left out",
        )
        assert _split(session, 2) == split
        for group in _group_status(session).values():
            assert group["thread_alive"]
            assert group["ignored"] == {"not_concrete": 3, "too_long": 1}
        for seq in range(2):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}
        second.kill()
        second.wait(timeout=10)
        assert list(_split(session, 1).values()) == [set(cameras.keys.values())]
        for seq in range(2, 4):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}
        assert first.poll() is None


#: A real ``zenoh-perception run`` whose Python can be wedged: a line on its stdin makes a
#: thread call libc's sleep through ctypes.PyDLL, which keeps the GIL. Its Zenoh runtime (Rust
#: threads) lives on, and so does its liveliness token.
_WEDGEABLE = """
import ctypes, sys, threading
from zenoh_perception.cli.main import main

def wedge():
    sys.stdin.readline()
    ctypes.PyDLL(None).sleep(120)

threading.Thread(target=wedge, daemon=True).start()
sys.exit(main(sys.argv[1:]))
"""


def test_a_wedged_instance_loses_its_streams_to_the_others(
    router: tuple[str, zenoh.Session],
) -> None:
    """An instance whose Python is wedged (the GIL held) while its Zenoh runtime lives once
    kept its token and its cameras unanswered. Its heartbeat stops with its workers: the other
    takes its streams, and every frame is answered once."""
    endpoint, session = router
    cameras = Cameras(session, CAMERAS)
    records = Collector(session, "cams/*/perception/tags")
    with ExitStack() as stack:
        stack.callback(cameras.close)
        first = stack.enter_context(running_cli(*_instance(endpoint)))
        wedgeable = subprocess.Popen(
            [sys.executable, "-c", _WEDGEABLE, *_instance(endpoint)],
            cwd=REPO,
            stdin=subprocess.PIPE,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            text=True,
        )
        stack.callback(wedgeable.wait)
        stack.callback(wedgeable.kill)
        _split(session, 2)
        assert wedgeable.stdin is not None
        wedgeable.stdin.write("wedge\n")
        wedgeable.stdin.flush()
        wedged_at = time.monotonic()
        alone = _split(session, 1)
        print(f"wedged instance's streams answered again {time.monotonic() - wedged_at:.1f} s on")
        assert list(alone.values()) == [set(cameras.keys.values())]
        group = next(iter(_group_status(session).values()))
        assert group["silent"] == [z for z in group["silent"]] and len(group["silent"]) == 1
        assert group["evictions"] == 1
        for seq in range(3):
            assert _answer_each_once(cameras, records, seq) == {(name, seq): 1 for name in CAMERAS}
        assert wedgeable.poll() is None  # wedged, not dead
        assert first.poll() is None


def test_an_instance_with_other_settings_refuses_to_join(
    router: tuple[str, zenoh.Session],
) -> None:
    """Two instances with different max_streams once split the cameras and one refused a
    stream the other had room for. The newcomer now exits 2 naming the setting."""
    endpoint, session = router
    cameras = Cameras(session, CAMERAS)
    with ExitStack() as stack:
        stack.callback(cameras.close)
        stack.enter_context(running_cli(*_instance(endpoint)))
        _split(session, 1)
        refused = run_cli(*_instance(endpoint), "--max-streams", "8")
        assert refused.returncode == 2, refused.stderr
        assert "another max_streams" in refused.stderr
        assert list(_split(session, 1).values()) == [set(cameras.keys.values())]


def test_an_input_that_gives_two_cameras_one_name_is_refused_at_start() -> None:
    flags = _instance(loopback_endpoint())
    at = flags.index("--input-key")
    flags[at + 1] = "x/**/cam/**"
    refused = run_cli(*flags)
    assert refused.returncode == 2
    assert "input_key = 'x/**/cam/**' gives two cameras one stream name" in refused.stderr


def _threads_and_rss(pid: int) -> tuple[int, int]:
    fields = dict(
        line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
    )
    return int(fields["Threads"]), int(fields["VmRSS"].split()[0]) // 1024


def test_ten_thousand_announcements_cost_counters_and_sigterm_still_exits(
    router: tuple[str, zenoh.Session],
) -> None:
    """10,000 announced cameras once made a thread per camera (9,928), 372 MB, and a process
    SIGTERM could not stop. Now an instance holds max_streams of them without a thread each,
    keeps at most 1,024, and exits 0 on SIGTERM while announcements come and go."""
    endpoint, session = router
    with running_cli(*_instance(endpoint)) as proc:
        wait_until(lambda: _group_status(session) != {}, what="the instance up")
        threads_before, rss_before = _threads_and_rss(proc.pid)
        tokens = [announce(session, f"cams/f{i}/image") for i in range(10_000)]
        wait_until(
            lambda: (
                [(g["streams"], len(g["held"])) for g in _group_status(session).values()]
                == [(1024, 16)]
            ),
            what="1,024 streams kept, 16 held",
        )
        threads, rss = _threads_and_rss(proc.pid)
        print(f"threads {threads_before} -> {threads}, RSS {rss_before} -> {rss} MB")
        assert threads - threads_before < 16  # no thread per held stream
        stop = threading.Event()

        def churn() -> None:
            i = 0
            while not stop.is_set():
                tokens[i % len(tokens)].undeclare()
                tokens[i % len(tokens)] = announce(session, f"cams/g{i}/image")
                i += 1

        churner = threading.Thread(target=churn, daemon=True)
        churner.start()
        try:
            code, seconds = sigterm_exit(proc, timeout=30.0)
        finally:
            stop.set()
            churner.join()
        print(f"SIGTERM during the churn: exit {code} after {seconds * 1e3:.0f} ms")
        assert code == 0
    for token in tokens:
        token.undeclare()
