"""``bench --link``: the raw and JPEG payloads of a frame, and both paths timed through one
real service process."""

from __future__ import annotations

import pytest

from zenoh_perception.cli import main as cli
from zenoh_perception.wire.compressed import decode_compressed_cdr
from zenoh_perception.wire.frames import decode_image_cdr
from zenoh_perception_bench import link, overhead


def test_each_frame_is_the_raw_image_and_image_transports_jpeg() -> None:
    (frame,) = link.payloads(overhead.frames_at("HD720", 1, seed=4))
    raw = decode_image_cdr(frame["raw"])
    assert raw.pixels.shape == (720, 1280, 4)
    assert len(frame["raw"]) > 1280 * 720 * 4
    jpeg = decode_compressed_cdr(frame["jpeg"])
    assert jpeg.pixels.shape[:2] == (720, 1280)
    assert len(frame["jpeg"]) < len(frame["raw"]) / 5


def test_the_summary_is_arithmetic_on_the_measured_sizes() -> None:
    frames = [{"raw": bytes(1_000_000), "jpeg": bytes(50_000)}] * 3
    result = link.summary(frames, {"raw": [10.0, 10.0, 10.0], "jpeg": [12.0, 15.0, 20.0]})
    assert result["raw"]["mbit_s"][30] == 240.0
    assert result["raw"]["link_ms"][100] == 80.0
    assert result["jpeg"]["link_ms"][20] == 20.0
    assert result["jpeg_over_raw_median"] == 1.5
    assert result["size_ratio"] == 0.05
    assert "Mbit/s@30" in link.report(result, 3)


def test_link_flag_parses() -> None:
    assert cli.build_parser().parse_args(["bench", "--link"]).link


@pytest.mark.timeout(300)
def test_both_paths_are_answered_by_one_real_service() -> None:
    frames = link.payloads(overhead.frames_at("VGA", 2, seed=5))
    times = link.lockstep(frames)
    assert [len(times[path]) for path in link.PATHS] == [2, 2]
    assert all(t > 0 for path in link.PATHS for t in times[path])
