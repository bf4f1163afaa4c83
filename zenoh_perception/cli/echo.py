"""``zenoh-perception echo``: print what the service publishes (``ros2 topic echo /tag`` here).

Keys may hold ``{stream}`` as the service's output keys do (``--tag-key 'cams/{stream}/tag'``):
echo then listens to every stream's, each line naming its key. Lost records show: echo follows
each stream's ``seq`` (the record names its stream) and prints a ``gap`` line whenever
numbers are missing (a ``seq`` lower than the last one is a restart, not a gap), and on exit
prints the totals to stderr. The ``seq`` is the camera's frame counter when the camera sends
one (then frames the service dropped or rejected are missing too), else the service's count of
answered frames (then only records lost on the way are).
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, NamedTuple, TextIO

import zenoh

from zenoh_perception.errors import MessageDecodeError, SettingsError
from zenoh_perception.service.skips import Skipped
from zenoh_perception.service.zenoh_args import open_zenoh
from zenoh_perception.settings import RosTransportKind, check_bound, check_ros_package
from zenoh_perception.wire.records import TagCodec, decode_record
from zenoh_perception.wire.rmw_zenoh import (
    ANY_HASH,
    fully_qualified,
    is_namespace,
    is_relative_topic,
    topic_key,
)
from zenoh_perception.wire.ros_topics import ros_topic
from zenoh_perception.wire.stream_keys import STREAM, output_key
from zenoh_perception.wire.text import format_decoded_record, format_tag


@dataclass(frozen=True, slots=True)
class Gap:
    """Records missing between two consecutive ``seq`` values seen."""

    after: int
    next: int

    @property
    def missing(self) -> int:
        return self.next - self.after - 1

    def format(self, key: str, *, as_json: bool) -> str:
        if as_json:
            gap = {"after": self.after, "next": self.next, "missing": self.missing}
            return json.dumps({"key": key, "gap": gap})
        return (
            f"[{key}] gap: {self.missing} record(s) missing between seq {self.after} "
            f"and {self.next}"
        )


class SeqGaps:
    """Follows a stream's ``seq`` numbers and counts the gaps in it. Pure, not thread-safe."""

    def __init__(self) -> None:
        self.records = 0
        self.gaps = 0
        self.missing = 0
        self.restarts = 0
        self._last: int | None = None

    def observe(self, seq: object) -> Gap | None:
        """The gap before ``seq``, if any (a seq that is not an integer is ignored)."""
        if isinstance(seq, bool) or not isinstance(seq, int):
            return None
        self.records += 1
        last, self._last = self._last, seq
        if last is None:
            return None
        if seq <= last:  # the camera or the service started over
            self.restarts += 1
            return None
        if seq == last + 1:
            return None
        gap = Gap(last, seq)
        self.gaps += 1
        self.missing += gap.missing
        return gap

    def summary(self) -> str:
        return (
            f"records={self.records} gaps={self.gaps} missing={self.missing} "
            f"restarts={self.restarts}"
        )


class StreamGaps:
    """A :class:`SeqGaps` per stream (at most :data:`MAX_STREAMS`; past that the oldest is
    forgotten, its counts kept in the totals). Pure, not thread-safe."""

    def __init__(self) -> None:
        self._streams: OrderedDict[str, SeqGaps] = OrderedDict()
        self._forgotten = SeqGaps()

    def observe(self, stream: str, seq: object) -> Gap | None:
        gaps = self._streams.get(stream)
        if gaps is None:
            gaps = self._streams[stream] = SeqGaps()
            while len(self._streams) > MAX_STREAMS:
                _, old = self._streams.popitem(last=False)
                for name in ("records", "gaps", "missing", "restarts"):
                    setattr(
                        self._forgotten, name, getattr(self._forgotten, name) + getattr(old, name)
                    )
        self._streams.move_to_end(stream)
        return gaps.observe(seq)

    def summary(self) -> str:
        every = [self._forgotten, *self._streams.values()]
        total = SeqGaps()
        for name in ("records", "gaps", "missing", "restarts"):
            setattr(total, name, sum(getattr(g, name) for g in every))
        streams = len(self._streams)
        return total.summary() + (f" streams={streams}" if streams > 1 else "")


#: Streams whose ``seq`` echo follows at once.
MAX_STREAMS = 4096


def listen_key(key: str) -> str:
    """The key echo subscribes for an output key: ``{stream}`` matches every stream's."""
    return "/".join("**" if c == STREAM else c.replace(STREAM, "$*") for c in key.split("/"))


@dataclass(frozen=True, slots=True)
class RosGraph:
    """How the service meets ROS 2 (its ``ros_transport``, ``ros_domain_id``, ``ros_namespace``)."""

    transport: RosTransportKind = RosTransportKind.BRIDGE
    domain_id: int = 0
    namespace: str = ""

    def tag_key(self, tag_key: str, ros_package: str) -> str:
        """The key the tag arrives on: ``tag_key`` itself through the bridge; on an rmw_zenoh
        graph the tag topic's rmw_zenoh key, any type hash.

        Raises:
            SettingsError: a domain id, namespace or tag topic rmw_zenoh cannot have.

        """
        if self.transport is not RosTransportKind.RMW_ZENOH:
            return listen_key(tag_key)
        check_bound("ros_domain_id", self.domain_id)
        if not is_namespace(self.namespace) or not is_relative_topic(output_key(tag_key, "stream")):
            msg = f"--ros-namespace {self.namespace!r} / --tag-key {tag_key!r}: not ROS names"
            raise SettingsError(msg)
        ros_type = ros_topic("tag").type_name(ros_package)
        return topic_key(
            self.domain_id,
            fully_qualified(self.namespace, listen_key(tag_key)),
            ros_type,
            ANY_HASH,
        )


class _Line(NamedTuple):
    text: str
    counted: bool  # counts toward --count (gap lines do not)


def main(
    conf: zenoh.Config,
    *,
    tag_key: str = "tag",
    record_key: str = "perception/tags",
    ros_package: str = "mrover",
    ros: RosGraph | None = None,
    records: bool = True,
    as_json: bool = False,
    count: int = 0,
    timeout: float | None = None,
    stop: threading.Event | None = None,
    out: TextIO = sys.stdout,
    err: TextIO = sys.stderr,
) -> int:
    """Print decoded tags (and records, with gaps in their ``seq``) until ``count`` lines,
    ``timeout`` or ``stop``; then the gap totals on ``err`` when records were followed, and
    how many samples were skipped as undecodable, by key and reason. A skipped sample is a
    line too (one per key and reason every :data:`SKIP_LINE_INTERVAL_S`).

    Returns 0, or 1 when ``count`` lines did not arrive before ``timeout``, or nothing at all
    did (said on ``err``).

    ``ros`` says where the tag comes (default: the bridge's plain key).

    Raises:
        SettingsError: ``ros_package`` is not a ROS package name, or ``ros`` holds no ROS names.
        SessionError: the Zenoh session cannot be opened.

    """
    codec = TagCodec(check_ros_package(ros_package))
    tag_key = (ros or RosGraph()).tag_key(tag_key, ros_package)
    lines: queue.Queue[_Line] = queue.Queue()
    stop = stop or threading.Event()
    gaps = StreamGaps()
    gaps_lock = threading.Lock()
    skipped = Skipped()

    def skip(key: str, error: MessageDecodeError) -> None:
        line = skipped.skip(key, error, as_json=as_json)
        if line is not None:
            lines.put(_Line(line, True))

    def on_tag(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            lines.put(
                _Line(format_tag(key, sample.payload.to_bytes(), codec, as_json=as_json), True)
            )
        except MessageDecodeError as error:
            skip(key, error)

    def on_record(sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        try:
            record = decode_record(sample.payload.to_bytes())
        except MessageDecodeError as error:
            skip(key, error)
            return
        with gaps_lock:
            gap = gaps.observe(str(record.get("stream", key)), record["seq"])
            if gap is not None:
                lines.put(_Line(gap.format(key, as_json=as_json), False))
            lines.put(_Line(format_decoded_record(key, record, as_json=as_json), True))

    with open_zenoh(conf) as session:
        subscribers: list[Any] = [session.declare_subscriber(tag_key, on_tag)]
        if records:
            subscribers.append(session.declare_subscriber(listen_key(record_key), on_record))
        keys = [tag_key, record_key] if records else [tag_key]
        listening = " and ".join(repr(k) for k in keys)
        print(f"echo: listening on {listening} (Ctrl-C to stop)", file=err, flush=True)
        printed = _print_lines(lines, stop, out, timeout=timeout, count=count)
    code = 1 if (count and printed < count) or (timeout is not None and printed == 0) else 0
    if printed == 0 and timeout is not None and not stop.is_set():
        print(
            f"echo: nothing received on {listening} within {timeout:g} s: is the service "
            "running on these keys, and do both sides meet (-e/-l, multicast scouting)?",
            file=err,
            flush=True,
        )
    print(f"echo: {skipped.summary()}", file=err, flush=True)
    if records:
        with gaps_lock:
            print(f"echo: {gaps.summary()}", file=err, flush=True)
    return code


def _print_lines(
    lines: queue.Queue[_Line],
    stop: threading.Event,
    out: TextIO,
    *,
    count: int,
    timeout: float | None,
) -> int:
    """Print queued lines until ``count`` counted ones, ``timeout`` or ``stop``; how many
    counted lines were printed."""
    deadline = None if timeout is None else time.monotonic() + timeout
    printed = 0
    while not stop.is_set():
        wait = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
        if wait <= 0:
            break
        try:
            line = lines.get(timeout=wait)
        except queue.Empty:
            continue
        print(line.text, file=out, flush=True)
        if line.counted:
            printed += 1
        if count and printed >= count:
            break
    return printed
