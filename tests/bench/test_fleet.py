"""bench --fleet's counting of answers, its configurations and its socket readings (the
benchmark itself runs processes for minutes: not a test)."""

from __future__ import annotations

import os
import time

import zenoh

from tests.helpers import open_session, wait_until
from zenoh_perception_bench.fleet import (
    CONFIGS,
    HANDOVER_S,
    Answer,
    Limit,
    _configs,
    _window,
    bytes_received,
    ceiling,
    cpu_seconds,
)

S = 1_000_000_000  # ns


def _answers(stream: str, seqs: list[int], period_ns: int = S // 4) -> list[Answer]:
    return [Answer(stream, seq, seq * period_ns, seq * period_ns + 1) for seq in seqs]


def test_a_window_counts_answers_duplicates_and_holes_per_stream() -> None:
    answers = [*_answers("a", [0, 1, 2, 4, 5]), *_answers("b", [0, 1, 1, 2])]
    window = _window(answers, 0, 10 * S, None)
    assert (window.answered, window.duplicates, window.unanswered) == (8, 1, 1)


def test_after_an_event_the_late_frames_are_counted_apart() -> None:
    event = 2 * S
    late = int(event + HANDOVER_S * S) // (S // 4)  # the first seq stamped after the hand-over
    seqs = [s for s in range(late + 8) if not 9 <= s <= 11 and s != late + 3]
    answers = [*_answers("a", seqs), *_answers("a", [late + 5])]
    window = _window(answers, event, 100 * S, event)
    assert window.unanswered == 4
    assert window.late_unanswered == 1
    assert window.late_duplicates == window.duplicates == 1
    assert window.resumed_s == 1.0  # seq 8 at 2.0 s, seq 12 at 3.0 s


def test_configurations() -> None:
    assert _configs(None) == list(CONFIGS) == [(1, 1), (4, 1), (4, 2), (8, 3)]
    assert _configs("2x1,3x3") == [(2, 1), (3, 3)]


def test_bytes_received_reads_this_process_sockets(endpoint: str) -> None:
    with open_session(listen=[endpoint]) as first, open_session(connect=[endpoint]) as second:
        before = bytes_received([os.getpid()])[os.getpid()]
        got: list[zenoh.Sample] = []
        subscriber = second.declare_subscriber("fleet/x", got.append)
        try:
            wait_until(lambda: bool(first.put("fleet/x", bytes(200_000)) or got), timeout=10)
        finally:
            subscriber.undeclare()
        assert bytes_received([os.getpid()])[os.getpid()] >= before + 200_000


def test_cpu_seconds_counts_this_process_threads_and_0_for_a_process_gone() -> None:
    pid = os.getpid()
    before = cpu_seconds([pid])[pid]
    # work (no sleep) until the kernel has counted 0.05 CPU-s more, or the deadline
    deadline = time.monotonic() + 60
    while cpu_seconds([pid])[pid] < before + 0.05:
        assert time.monotonic() < deadline, "no CPU time counted for a minute of work"
        sum(range(10_000))
    gone = 2**22 + 1  # above the largest pid Linux gives by default
    assert cpu_seconds([gone]) == {gone: 0.0}


def test_the_ceiling_is_opencv_on_the_cores_the_other_processes_left() -> None:
    limit = Limit(fps=400.0, per_cpu_s=250.0)
    share = {"cameras": 0.4, "routers": 0.1, "instances": 1.4, "bench": 0.1}
    # 2 cores less 0.6 taken by the others: 1.4 cores at 250 frames per CPU-second
    assert ceiling(limit, share, 2) == 350.0
    # with cores to spare, never more than OpenCV's loop alone on every core
    assert ceiling(limit, share, 8) == 400.0
    assert ceiling(limit, {"cameras": 3.0, "instances": 0.5}, 2) == 0.0
