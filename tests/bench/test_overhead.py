"""``bench --overhead``: the rows and the report from measured times, and the flags."""

from __future__ import annotations

import pytest

from zenoh_perception.cli import main as cli
from zenoh_perception_bench import overhead
from zenoh_perception_bench.runners import DICTIONARY, Baseline


def _times(
    bare: float, floor: float, tag: float, record: float, peer: float | None = None
) -> dict[str, list[float]]:
    """Times of every path; the peer (floor and OpenCV in one process) at floor + bare unless
    given."""
    times = {"opencv bare": [bare, bare + 2.0, bare - 2.0]}
    peer = floor + bare if peer is None else peer
    for camera in overhead.CAMERAS:
        times[f"floor/tag {camera}"] = [floor] * 3
        times[f"opencv-peer/tag {camera}"] = [peer] * 3
        times[f"opencv-peer/record {camera}"] = [peer + 0.05] * 3
        times[f"opencv/tag {camera}"] = [tag] * 3
        times[f"opencv/record {camera}"] = [record] * 3
    return times


def test_rows_give_the_excess_over_bare_in_ms_per_size_and_camera() -> None:
    rows = overhead.overhead_rows({"HD720": _times(4.0, 1.0, 5.5, 5.75)})
    assert [(r["resolution"], r["camera"]) for r in rows] == [("HD720", "shm"), ("HD720", "bytes")]
    row = rows[0]
    assert row["bare_ms"] == pytest.approx(4.0)  # the median, not the mean of the spread
    assert row["tag_over_bare_ms"] == pytest.approx(1.5)
    assert row["record_over_bare_ms"] == pytest.approx(1.75)
    assert row["tag_ratio"] == pytest.approx(1.38)
    assert row["own_ms"] == pytest.approx(0.5)  # tag - floor - bare
    assert row["own_record_ms"] == pytest.approx(0.75)  # record - floor - bare
    assert row["vs_peer_ms"] == pytest.approx(0.5)  # tag - the peer's tag
    assert row["vs_peer_record_ms"] == pytest.approx(0.7)  # record - the peer's record


def test_the_goals_judge_the_service_against_the_peer_idle_as_it_is() -> None:
    # bare OpenCV read hot in the bench's process: 4 ms; the peer, idle between frames as the
    # service is, 6.5 ms: the service's 6.7 ms is 0.2 ms over it, not 1.7 over floor + bare
    rows = overhead.overhead_rows({"HD720": _times(4.0, 1.0, 6.7, 6.8, peer=6.5)})
    assert rows[0]["own_ms"] == pytest.approx(1.7)
    assert rows[0]["vs_peer_ms"] == pytest.approx(0.2)
    lines = overhead.report(rows, None, 0.0).splitlines()
    assert all(line.endswith("met") for line in lines if line.startswith("HD720 "))


def test_report_holds_hd720_frames_of_both_kinds_to_the_goals() -> None:
    rows = overhead.overhead_rows(
        {"HD720": _times(4.0, 1.0, 5.2, 5.4), overhead.LOOKALIKES: _times(4.0, 1.0, 5.2, 5.6)}
    )
    lines = overhead.report(rows, None, 0.0).splitlines()
    plain = [line for line in lines if line.startswith("HD720 ") and "look-alikes" not in line]
    alike = [line for line in lines if line.startswith(overhead.LOOKALIKES)]
    assert len(plain) == len(alike) == len(overhead.CAMERAS)
    assert all(line.endswith("met") for line in plain)  # own 0.2 / 0.4 ms
    assert all(line.endswith("MISSED") for line in alike)  # own to the record 0.6 ms


def test_report_names_every_size_and_the_paced_run() -> None:
    rows = overhead.overhead_rows({"VGA": _times(2, 0.5, 3, 3), "HD1080": _times(9, 1, 11, 11)})
    rate = {
        "opencv": {
            "put": 120,
            "answered": 90,
            "answered_hz": 45.0,
            "detect_median_ms": 20.0,
            "frame_median_ms": 22.0,
            "max_hz_from_frame_ms": 45.5,
        }
    }
    text = overhead.report(rows, rate, 60.0)
    assert "VGA" in text and "HD1080" in text
    assert "answered 90/120" in text
    assert "HD1080 at 60 Hz" in text


def test_frames_have_the_named_size() -> None:
    frames = overhead.frames_at("VGA", 2, seed=3)
    assert [f.shape for f in frames] == [(480, 640, 4)] * 2


def test_lookalike_frames_give_the_veto_more_to_read() -> None:
    """Frames with look-alikes hold more candidates for OpenCV than the plain ones."""
    baseline = Baseline(DICTIONARY)
    plain = overhead.frames_at("VGA", 6, seed=3)
    alike = overhead.frames_at("VGA", 6, seed=3, lookalikes=True)
    count = lambda frames: sum(len(baseline.run(f)[0]) for f in frames)  # noqa: E731
    assert count(alike) > count(plain)


def test_overhead_flags_parse() -> None:
    args = cli.build_parser().parse_args(["bench", "--overhead", "--rate", "60"])
    assert args.overhead and args.rate == 60.0
    assert not cli.build_parser().parse_args(["bench"]).overhead


@pytest.mark.timeout(300)
def test_lockstep_sizes_times_every_path_through_real_services() -> None:
    frames = {"VGA": overhead.frames_at("VGA", 2, seed=5)}
    times = overhead.lockstep_sizes(frames, None)["VGA"]
    for camera in overhead.CAMERAS:
        for path in ("floor/tag", "opencv-peer/tag", "opencv/tag", "opencv/record"):
            assert len(times[f"{path} {camera}"]) == 2, path
        # the record is put after the tag, by the same service, for the same frame
        tags, records = times[f"opencv/tag {camera}"], times[f"opencv/record {camera}"]
        assert all(r > 0 and t > 0 for t, r in zip(tags, records, strict=True))
    assert len(times["opencv bare"]) == 2
