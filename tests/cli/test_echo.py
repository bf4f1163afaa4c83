"""``echo``: what it listens to, and gap counting (records lost show as gaps in ``seq``)."""

from __future__ import annotations

import io
import json
import threading
from typing import Any

import pytest
import zenoh

from tests.helpers import (
    loopback_config,
    loopback_endpoint,
    open_session,
    parse_pairs,
    wait_for_subscriber,
    wait_until,
)
from zenoh_perception.cli import echo
from zenoh_perception.cli.echo import Gap, SeqGaps, StreamGaps, listen_key
from zenoh_perception.errors import SettingsError
from zenoh_perception.settings import RosTransportKind
from zenoh_perception.tags.selection import TagMessage, TagObservation
from zenoh_perception.wire.input_kinds import InputKind
from zenoh_perception.wire.records import FrameRecord, TagCodec, decode_record


def test_consecutive_seqs_have_no_gap() -> None:
    gaps = SeqGaps()
    assert [gaps.observe(seq) for seq in range(5)] == [None] * 5
    assert gaps.summary() == "records=5 gaps=0 missing=0 restarts=0"


def test_missing_seqs_are_gaps_with_their_count() -> None:
    gaps = SeqGaps()
    seen = [gaps.observe(seq) for seq in (1, 2, 5, 6, 10)]
    assert seen == [None, None, Gap(2, 5), None, Gap(6, 10)]
    assert [g.missing for g in seen if g is not None] == [2, 3]
    assert (gaps.records, gaps.gaps, gaps.missing) == (5, 2, 5)


def test_a_seq_going_back_is_a_restart_not_a_gap() -> None:
    gaps = SeqGaps()
    for seq in (7, 8, 0, 1, 1):
        assert gaps.observe(seq) is None
    assert (gaps.gaps, gaps.missing, gaps.restarts) == (0, 0, 2)


def test_seqs_that_are_not_integers_are_ignored() -> None:
    gaps = SeqGaps()
    for seq in (1, "2", True, None, 2.0, 2):
        assert gaps.observe(seq) is None
    assert gaps.records == 2 and gaps.gaps == 0


def test_gap_lines_in_text_and_json() -> None:
    gap = Gap(2, 5)
    assert gap.format("perception/tags", as_json=False) == (
        "[perception/tags] gap: 2 record(s) missing between seq 2 and 5"
    )
    assert json.loads(gap.format("perception/tags", as_json=True)) == {
        "key": "perception/tags",
        "gap": {"after": 2, "next": 5, "missing": 2},
    }


def test_echo_says_what_it_listens_to_before_anything_arrives() -> None:
    out, err = io.StringIO(), io.StringIO()
    conf = loopback_config(listen=[loopback_endpoint()])
    code = echo.main(conf, tag_key="rover/tag", count=1, timeout=0.2, out=out, err=err)
    assert code == 1  # nothing arrived
    assert out.getvalue() == ""
    assert "listening on 'rover/tag' and 'perception/tags'" in err.getvalue()


def test_echo_with_a_timeout_and_nothing_received_says_so_and_exits_1() -> None:
    out, err = io.StringIO(), io.StringIO()
    conf = loopback_config(listen=[loopback_endpoint()])
    code = echo.main(conf, tag_key="rover/tag", timeout=0.2, out=out, err=err)
    assert code == 1
    assert "echo: nothing received on 'rover/tag' and 'perception/tags' within 0.2 s" in (
        err.getvalue()
    )


class _Echo:
    """``echo.main`` on a thread, listening on ``endpoint``; always stopped on exit."""

    def __init__(self, endpoint: str, **options: Any) -> None:
        self.out, self.err = io.StringIO(), io.StringIO()
        self.codes: list[int] = []
        self._stop = threading.Event()
        conf = loopback_config(listen=[endpoint])
        self._thread = threading.Thread(
            target=lambda: self.codes.append(
                echo.main(conf, out=self.out, err=self.err, stop=self._stop, **options)
            )
        )

    def __enter__(self) -> _Echo:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=30.0)

    def publisher(self, session: zenoh.Session, key: str) -> zenoh.Publisher:
        publisher = session.declare_publisher(key)
        wait_for_subscriber(publisher)
        return publisher

    def finish(self) -> int:
        """Its exit code, once it has printed its ``count`` lines and returned by itself."""
        self._thread.join(timeout=60.0)
        assert not self._thread.is_alive()
        (code,) = self.codes
        return code


def _record(seq: int) -> bytes:
    tag = TagObservation(4, 50.0, 60.0, 0.5, ((45, 55), (55, 55), (55, 65), (45, 65)), 100.0)
    return FrameRecord(
        seq, "cam", seq, 64, 48, tag.message(), (tag,), {"latency_ms": 1.0}, InputKind.RAW
    ).to_msgpack()


def test_echo_prints_each_tag_and_record_as_json(endpoint: str) -> None:
    with (
        _Echo(endpoint, as_json=True, count=2) as running,
        open_session(connect=[endpoint]) as service,
    ):
        tags = running.publisher(service, "tag")
        records = running.publisher(service, "perception/tags")
        tags.put(bytes(TagCodec().encode(TagMessage(4, 50.0, 60.0, 0.5))))
        wait_until(lambda: len(running.out.getvalue().splitlines()) == 1, what="the tag")
        records.put(_record(7))
        assert running.finish() == 0
    tag_line, record_line = (json.loads(line) for line in running.out.getvalue().splitlines())
    assert tag_line == {
        "key": "tag",
        "tag_id": 4,
        "x_tag_center_pixel": 50.0,
        "y_tag_center_pixel": 60.0,
        "closeness_metric": 0.5,
    }
    assert record_line.pop("key") == "perception/tags"
    assert record_line == decode_record(_record(7))
    summary = running.err.getvalue().splitlines()[-1]
    assert parse_pairs(summary) == {"records": "1", "gaps": "0", "missing": "0", "restarts": "0"}


def test_tags_only_follows_no_records(endpoint: str) -> None:
    with (
        _Echo(endpoint, as_json=True, count=1, records=False, tag_key="rover/tag") as running,
        open_session(connect=[endpoint]) as service,
    ):
        tags = running.publisher(service, "rover/tag")
        tags.put(bytes(TagCodec().encode(TagMessage(2, 1.0, 2.0, 0.25))))
        assert running.finish() == 0
    (line,) = running.out.getvalue().splitlines()
    assert json.loads(line)["tag_id"] == 2
    assert "records=" not in running.err.getvalue()  # no gap totals without records


def test_an_undecodable_tag_is_a_line_too(endpoint: str) -> None:
    with (
        _Echo(endpoint, count=1, records=False) as running,
        open_session(connect=[endpoint]) as service,
    ):
        running.publisher(service, "tag").put(b"\x00\x01\x00\x00short")
        assert running.finish() == 0
    (line,) = running.out.getvalue().splitlines()
    assert line.startswith("[tag] undecodable")


def test_stop_ends_an_endless_echo_with_0(endpoint: str) -> None:
    with _Echo(endpoint) as running:
        wait_until(lambda: "listening" in running.err.getvalue(), what="echo listening")
    assert running.codes == [0]


def test_an_invalid_ros_package_is_refused_before_any_session() -> None:
    with pytest.raises(SettingsError, match="ros_package"):
        echo.main(loopback_config(), ros_package="Not-A-Package")


def test_echo_reads_the_tag_where_the_ros_transport_puts_it() -> None:
    assert echo.RosGraph().tag_key("tag", "mrover") == "tag"
    rmw = echo.RosGraph(RosTransportKind.RMW_ZENOH, 3, "/rover")
    assert rmw.tag_key("tag", "rover_msgs") == (
        "3/rover/tag/rover_msgs::msg::dds_::StarterProjectTag_/*"
    )
    for bad in (
        echo.RosGraph(RosTransportKind.RMW_ZENOH, 233),
        echo.RosGraph(RosTransportKind.RMW_ZENOH, 0, "rover"),
    ):
        with pytest.raises(SettingsError):
            bad.tag_key("tag", "mrover")
    with pytest.raises(SettingsError):
        rmw.tag_key("t*", "mrover")


def test_each_stream_has_its_own_seq_and_the_summary_adds_them_up() -> None:
    gaps = StreamGaps()
    # two cameras counting frames each from 1, interleaved: no gap, no restart
    for seq in (1, 2, 3):
        assert gaps.observe("cams/front/image", seq) is None
        assert gaps.observe("cams/rear/image", seq) is None
    gap = gaps.observe("cams/rear/image", 6)
    assert gap is not None and gap.missing == 2
    assert parse_pairs(gaps.summary()) == {
        "records": "7",
        "gaps": "1",
        "missing": "2",
        "restarts": "0",
        "streams": "2",
    }


def test_an_output_key_with_stream_listens_to_every_streams() -> None:
    assert listen_key("cams/{stream}/tag") == "cams/**/tag"
    assert listen_key("tag_{stream}") == "tag_$*"
    assert listen_key("tag") == "tag"
