"""``bench --streams``: the report and goals from measured figures, the flag, one short run."""

from __future__ import annotations

from typing import Any

import pytest

from zenoh_perception.cli import main as cli
from zenoh_perception_bench import streams


def _row(answered: int, median: float) -> dict[str, Any]:
    return {
        "put": 100,
        "answered": answered,
        "answered_share": answered / 100,
        "latency_median_ms": median,
        "latency_p95_ms": median * 2,
        "detect_median_ms": 3.0,
    }


def _result(beside_answered: int, beside_median: float) -> dict[str, Any]:
    return {
        "opencv_bare_ms": {"VGA": 3.0, "HD2K": 30.0},
        "rate_hz": 15.0,
        "alone": {name: _row(100, 8.0) for name in streams.SMALL},
        "beside": {
            **{name: _row(beside_answered, beside_median) for name in streams.SMALL},
            streams.LARGE: _row(90, 40.0),
        },
    }


def test_goals_hold_the_small_cameras_to_their_share_and_latency() -> None:
    assert all(met for _, met in streams.goals(_result(96, 17.9)))
    missed = [text for text, met in streams.goals(_result(94, 18.1)) if not met]
    assert len(missed) == 2 * len(streams.SMALL)


def test_report_shows_every_camera_of_both_phases_beside_opencv() -> None:
    text = streams.report(_result(96, 12.0))
    assert "VGA 3.0 ms, HD2K 30.0 ms" in text
    assert sum(line.startswith("beside") for line in text.splitlines()) == len(streams.RESOLUTION)
    assert sum(line.startswith("alone") for line in text.splitlines()) == len(streams.SMALL)


def test_the_flag_parses() -> None:
    assert cli.build_parser().parse_args(["bench", "--streams"]).streams
    assert not cli.build_parser().parse_args(["bench"]).streams


@pytest.mark.timeout(300)
def test_a_short_run_answers_every_camera_through_one_real_service() -> None:
    result = streams.measure(1.0, seed=3)
    for phase in ("alone", "beside"):
        for name, row in result[phase].items():
            assert row["put"] == 15 and row["answered"] > 0, (phase, name)
    assert set(result["beside"]) == set(streams.RESOLUTION)
