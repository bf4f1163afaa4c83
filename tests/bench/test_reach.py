"""The range figure: the furthest distance a tag is found at, and the report of each detector:
OpenCV's default, its best setting, the service."""

from __future__ import annotations

from zenoh_perception_bench.reach import TAG_M, range_report, reach
from zenoh_perception_bench.report import format_report
from zenoh_perception_bench.runners import BEST


def test_the_range_is_the_furthest_distance_reached_with_every_nearer_one() -> None:
    assert reach({2.0: 1.0, 4.0: 0.95, 6.0: 0.9, 8.0: 0.5}) == 6.0
    # a far distance reached by chance after a nearer one missed does not count
    assert reach({2.0: 1.0, 4.0: 0.5, 6.0: 0.95}) == 2.0
    assert reach({2.0: 0.2}) == 0.0


def test_a_near_tag_is_found_by_each_and_a_far_one_by_none() -> None:
    report = range_report(3, 7, distances=(2.0, 60.0))
    assert report["tag_m"] == TAG_M and report["frames_per_distance"] == 3
    assert list(report["found_share"]) == list(report["range_m"]) == ["opencv", BEST, "service"]
    for name in ("opencv", BEST, "service"):
        assert report["found_share"][name] == {"2.0": 1.0, "60.0": 0.0}
        assert report["range_m"][name] == 2.0
    # the text report: a column each, and the range of each on the last row
    text = format_report({"range": report, "sets": {}, "goals": []})
    lines = text.splitlines()
    header = next(line for line in lines if line.startswith("distance"))
    assert header.split() == ["distance", "opencv", BEST, "service"]
    last = next(line for line in lines if line.startswith("range (90 % of frames)"))
    assert last.split()[-6:] == ["2", "m", "2", "m", "2", "m"]
    assert "best = OpenCV's best setting: windows 3-53 step 4, min perimeter 0.02" in text
