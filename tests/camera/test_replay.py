"""Replay: pacing (fake clock), progress, and the publishing loop in process."""

from __future__ import annotations

import io
import queue
import threading

import pytest
import zenoh

from tests.helpers import Collector, loopback_config, open_session
from zenoh_perception.camera.replay import (
    Pacer,
    Pacing,
    ProgressBar,
    ReplayOptions,
    main,
    render_progress,
)
from zenoh_perception.camera.sources import (
    Frames,
    ReplayError,
    SourceFrame,
)


def test_recorded_pacing_keeps_the_recording_spacing() -> None:
    pacer = Pacer(Pacing.RECORDED)
    stamps = [10_000_000_000 + k for k in (0, 100_000_000, 150_000_000, 400_000_000)]
    # The sender is always on time: each frame is asked for when the previous was due.
    now = 50.0
    dues = []
    for stamp in stamps:
        due = pacer.due(stamp, now)
        dues.append(due)
        now = due
    assert dues == pytest.approx([50.0, 50.1, 50.15, 50.4])


def test_recorded_pacing_restarts_one_interval_after_a_loop() -> None:
    pacer = Pacer(Pacing.RECORDED)
    assert pacer.due(0, 10.0) == 10.0
    assert pacer.due(200_000_000, 10.0) == pytest.approx(10.2)
    # The next pass starts over at stamp 0: one interval after the last frame, then as recorded.
    assert pacer.due(0, 10.2) == pytest.approx(10.4)
    assert pacer.due(200_000_000, 10.4) == pytest.approx(10.6)


def test_fixed_rate_pacing_ignores_stamps_and_does_not_drift() -> None:
    pacer = Pacer(Pacing.RATE, 4.0)
    # Asked late each time (processing took 0.1 s): deadlines stay on the 0.25 s grid.
    dues = [pacer.due(stamp, 100.0 + 0.26 * i) for i, stamp in enumerate([9, 3, 7, 1])]
    assert dues == pytest.approx([100.0, 100.25, 100.5, 100.75])


def test_pacing_does_not_burst_after_a_stall() -> None:
    pacer = Pacer(Pacing.RATE, 10.0, max_lag_s=1.0)
    assert pacer.due(0, 0.0) == 0.0
    # Stalled 5 s (e.g. a slow disk): send now and continue from here, not 50 frames at once.
    assert pacer.due(0, 5.0) == 5.0
    assert pacer.due(0, 5.0) == pytest.approx(5.1)


def test_as_fast_as_possible_is_always_due_now() -> None:
    pacer = Pacer(Pacing.ASAP)
    assert [pacer.due(s, t) for s, t in [(5, 1.0), (0, 2.0), (9, 2.5)]] == [1.0, 2.0, 2.5]


def test_fixed_rate_pacing_needs_a_rate() -> None:
    with pytest.raises(ReplayError):
        Pacer(Pacing.RATE, None)
    with pytest.raises(ReplayError):
        Pacer(Pacing.RATE, float("nan"))


def test_render_progress() -> None:
    # Rate: frames after the first over the time since the first.
    assert render_progress(5, 10, 2.0, width=10) == "replay [#####.....]  50% 5/10 frames 2.0 fps"
    assert render_progress(10, 10, 1.5, width=4) == "replay [####] 100% 10/10 frames 6.0 fps"
    assert render_progress(7, None, 0.5) == "replay 7 frames 12.0 fps"
    assert render_progress(1, None, 0.0) == "replay 1 frames 0.0 fps"
    assert render_progress(3, 7, 1.0, width=7) == "replay [###....]  42% 3/7 frames 2.0 fps"


def test_progress_bar_redraws_in_place_and_throttles() -> None:
    stream = io.StringIO()
    bar = ProgressBar(stream, 4, min_interval_s=1.0)
    bar.update(1, 0.5)
    bar.update(2, 0.7)  # within the interval: not drawn
    bar.update(3, 1.6)
    bar.finish(4, 2.0)
    text = stream.getvalue()
    assert text.endswith("\n")
    draws = text.rstrip("\n").split("\r")[1:]
    assert [d.split()[3] for d in draws] == ["1/4", "3/4", "4/4"]


class _ListSource:
    """An in-memory raw source whose payload is the frame number (for counting)."""

    kind = "test"

    def __init__(self, count: int) -> None:
        self._count = count

    @property
    def count(self) -> int | None:
        return self._count

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        for i in range(self._count):
            yield SourceFrame(f"{seq_start + i}".encode(), b"\x80", epoch_ns + i)


def test_main_loops_up_to_the_limit_and_draws_progress(endpoint: str) -> None:
    stream = io.StringIO()
    options = ReplayOptions(
        key="replay/test", pacing=Pacing.ASAP, loop=True, limit=23, progress=True
    )
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "replay/test")
        conf = loopback_config(connect=[endpoint])
        code = main(conf, _ListSource(5), options, threading.Event(), progress_stream=stream)
        got = [frames.get().payload.decode() for _ in range(23)]
    assert code == 0
    # Five frames per pass, numbered on across passes, stopped at 23.
    assert got == [str(i) for i in range(23)]
    assert frames.drain() == []
    assert "23/23 frames" in stream.getvalue().rsplit("\r", 1)[-1]


class _GrowingSource:
    """Frames of 1000, 2000, 3000, ... bytes."""

    kind = "test frames"
    count = 5

    def frames(self, *, epoch_ns: int = 0, seq_start: int = 0) -> Frames:
        for i in range(self.count):
            yield SourceFrame(bytes(1000 * (i + 1)), b"\x80", epoch_ns + i)


def test_main_stops_before_a_frame_over_max_frame_bytes(endpoint: str) -> None:
    options = ReplayOptions(key="replay/test", pacing=Pacing.ASAP, max_frame_bytes=2500)
    with open_session(listen=[endpoint]) as session:
        frames = Collector(session, "replay/test")
        conf = loopback_config(connect=[endpoint])
        with pytest.raises(ReplayError, match=r"frame 3 of the test frames is 3000 bytes"):
            main(conf, _GrowingSource(), options, threading.Event())
        got = [len(frames.get().payload) for _ in range(2)]
        assert got == [1000, 2000]
        assert frames.drain() == []


def test_main_returns_when_stopped_while_waiting_for_a_subscriber() -> None:
    stop = threading.Event()
    stop.set()
    options = ReplayOptions(key="replay/nobody", pacing=Pacing.ASAP)
    assert main(loopback_config(), _ListSource(3), options, stop) == 0


def test_main_times_out_without_a_subscriber() -> None:
    options = ReplayOptions(key="replay/nobody", subscriber_timeout_s=0.2)
    with pytest.raises(ReplayError, match="no subscriber on 'replay/nobody'"):
        main(loopback_config(), _ListSource(3), options, threading.Event())


def test_main_announces_its_key_before_any_subscriber_and_withdraws_it_at_the_end(
    endpoint: str,
) -> None:
    """A service of a share group subscribes to a camera's key only once it sees the
    camera's token: the replay declares it while it still waits for a subscriber."""
    events: queue.Queue[tuple[str, str]] = queue.Queue()

    def on_token(sample: zenoh.Sample) -> None:
        events.put((str(sample.kind), str(sample.key_expr)))

    options = ReplayOptions(key="replay/cams/front", pacing=Pacing.ASAP, limit=3)
    with open_session(listen=[endpoint]) as session:
        watcher = session.liveliness().declare_subscriber("@camera/replay/**", on_token)
        result: list[int] = []
        replay = threading.Thread(
            target=lambda: result.append(
                main(
                    loopback_config(connect=[endpoint]), _ListSource(3), options, threading.Event()
                )
            )
        )
        replay.start()
        try:
            assert events.get(timeout=10) == ("SampleKind.PUT", "@camera/replay/cams/front")
            frames = Collector(session, "replay/cams/front")  # only now a subscriber
            assert [frames.get().payload for _ in range(3)] == [b"0", b"1", b"2"]
            assert events.get(timeout=10) == ("SampleKind.DELETE", "@camera/replay/cams/front")
        finally:
            replay.join(timeout=10)
            watcher.undeclare()
    assert result == [0]
