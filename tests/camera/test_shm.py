""":class:`ShmPutter`: frames from Zenoh shared memory between two in-process peers on loopback
(multicast scouting off), buffers recycled, and the plain-put fallback."""

from __future__ import annotations

import logging
import os
import queue
from dataclasses import dataclass

import pytest
import zenoh

from tests.helpers import WAIT_S, wait_for_subscriber
from zenoh_perception.camera.shm import ShmPutter, ShmUnavailableError

KEY = "shm/test"


@dataclass(frozen=True)
class Got:
    payload: bytes
    shm: bool  # the receiver read it in place from shared memory
    attachment: bytes | None


class Receiver:
    """Queues what arrives; with ``hoard``, also keeps every sample (its buffer stays held)."""

    def __init__(self, session: zenoh.Session, *, hoard: bool = False) -> None:
        self.queue: queue.Queue[Got] = queue.Queue()
        self.hoarded: list[zenoh.Sample] = []
        self._hoard = hoard
        self._subscriber = session.declare_subscriber(KEY, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if self._hoard:
            self.hoarded.append(sample)
        attachment = sample.attachment
        self.queue.put(
            Got(
                sample.payload.to_bytes(),
                sample.payload.as_shm() is not None,
                None if attachment is None else attachment.to_bytes(),
            )
        )

    def get(self) -> Got:
        return self.queue.get(timeout=WAIT_S)


@pytest.fixture
def link(
    peers: tuple[zenoh.Session, zenoh.Session],
) -> tuple[zenoh.Session, zenoh.Publisher]:
    """(the receiving session, a publisher on the other peer matched with nothing yet)."""
    receiving, sending = peers
    publisher = sending.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    return receiving, publisher


def test_the_receiver_reads_identical_bytes_from_shared_memory(
    link: tuple[zenoh.Session, zenoh.Publisher],
) -> None:
    session, publisher = link
    receiver = Receiver(session)
    wait_for_subscriber(publisher)
    putter = ShmPutter()
    payload = os.urandom(1280 * 720 * 4)  # an HD720 BGRA frame
    assert putter.put(publisher, payload, attachment=b"meta")
    got = receiver.get()
    assert got.payload == payload
    assert got.shm
    assert got.attachment == b"meta"
    view = memoryview(bytearray(os.urandom(4096)))
    assert putter.put(publisher, view)
    got = receiver.get()
    assert got.payload == bytes(view)
    assert got.shm
    assert putter.summary() == {
        "shm": True,
        "shm_frames": 2,
        "plain_frames": 0,
        "unavailable": None,
    }


def test_many_puts_recycle_a_small_pool(link: tuple[zenoh.Session, zenoh.Publisher]) -> None:
    session, publisher = link
    receiver = Receiver(session)
    wait_for_subscriber(publisher)
    putter = ShmPutter(slots=2)
    for i in range(60):
        payload = bytes([i]) * 300_000
        assert putter.put(publisher, payload, attachment=bytes([i]))
        got = receiver.get()
        assert got.payload == payload
        assert got.shm
    # 60 frames through 2 slots: every buffer was reused, none was ever refused
    assert (putter.shm_frames, putter.plain_frames) == (60, 0)


def test_a_hoarding_subscriber_gets_plain_frames_then_shm_again(
    link: tuple[zenoh.Session, zenoh.Publisher],
) -> None:
    session, publisher = link
    receiver = Receiver(session, hoard=True)
    wait_for_subscriber(publisher)
    putter = ShmPutter(slots=2)
    sent = []
    for i in range(5):
        payload = bytes([i]) * 100_000
        sent.append(putter.put(publisher, payload))
        assert receiver.get().payload == payload
    # two slots, both held by the receiver: the next frames are plain puts, the pool stays
    assert sent == [True, True, False, False, False]
    assert (putter.shm_frames, putter.plain_frames) == (2, 3)
    assert putter.active  # exhaustion is not unavailability
    receiver.hoarded.clear()  # the receiver lets go: the buffers are collected and reused
    assert putter.put(publisher, b"\x09" * 100_000)
    got = receiver.get()
    assert got.shm
    assert got.payload == b"\x09" * 100_000


def test_a_larger_frame_gets_a_larger_pool(link: tuple[zenoh.Session, zenoh.Publisher]) -> None:
    session, publisher = link
    receiver = Receiver(session)
    wait_for_subscriber(publisher)
    putter = ShmPutter(slots=1)
    for size in (10_000, 2_000_000, 10_000):
        payload = os.urandom(size)
        assert putter.put(publisher, payload)
        got = receiver.get()
        assert (got.payload, got.shm) == (payload, True)


def _no_shm(size: int) -> zenoh.shm.ShmProvider:
    msg = f"Unable to create SHM segment of {size} bytes"
    raise zenoh.ZError(msg)


def test_without_shared_memory_frames_go_as_plain_puts(
    link: tuple[zenoh.Session, zenoh.Publisher], caplog: pytest.LogCaptureFixture
) -> None:
    session, publisher = link
    receiver = Receiver(session)
    wait_for_subscriber(publisher)
    putter = ShmPutter(provider_factory=_no_shm)
    with caplog.at_level(logging.WARNING, logger="zenoh_perception.camera.shm"):
        for i in range(3):
            payload = bytes([i]) * 50_000
            assert not putter.put(publisher, payload, attachment=b"a")
            got = receiver.get()
            assert (got.payload, got.attachment) == (payload, b"a")
    assert not putter.active
    assert putter.unavailable is not None
    assert "Unable to create SHM segment" in putter.unavailable
    assert putter.summary()["shm"] is False
    assert (putter.shm_frames, putter.plain_frames) == (0, 3)
    lines = [r.getMessage() for r in caplog.records if "event=shm_unavailable" in r.getMessage()]
    assert len(lines) == 1  # said once, not per frame


def test_strict_raises_a_typed_error_and_empty_payloads_need_no_buffer() -> None:
    with pytest.raises(ShmUnavailableError, match="shared memory unavailable"):
        ShmPutter(strict=True, provider_factory=_no_shm).load(b"frame")
    putter = ShmPutter(provider_factory=_no_shm)
    assert putter.load(memoryview(b"abc")) == b"abc"
    empty = ShmPutter()
    assert empty.load(b"") == b""
    assert empty.active  # nothing was allocated for an empty payload
    with pytest.raises(ValueError, match="slots"):
        ShmPutter(slots=0)
