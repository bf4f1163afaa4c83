"""The range figure: the furthest distance a tag is found at, and the report of both detectors."""

from __future__ import annotations

from zenoh_perception.bench.reach import TAG_M, range_report, reach


def test_the_range_is_the_furthest_distance_reached_with_every_nearer_one() -> None:
    assert reach({2.0: 1.0, 4.0: 0.95, 6.0: 0.9, 8.0: 0.5}) == 6.0
    # a far distance reached by chance after a nearer one missed does not count
    assert reach({2.0: 1.0, 4.0: 0.5, 6.0: 0.95}) == 2.0
    assert reach({2.0: 0.2}) == 0.0


def test_a_near_tag_is_found_by_both_and_a_far_one_by_neither() -> None:
    report = range_report(3, 7, distances=(2.0, 60.0))
    assert report["tag_m"] == TAG_M and report["frames_per_distance"] == 3
    for name in ("opencv", "service"):
        assert report["found_share"][name] == {"2.0": 1.0, "60.0": 0.0}
        assert report["range_m"][name] == 2.0
