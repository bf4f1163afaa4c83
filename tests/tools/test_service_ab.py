"""tools/service_ab.py: two checkouts and the reading peer, paired frame by frame."""

from __future__ import annotations

from pathlib import Path

from tools.service_ab import main

REPO = Path(__file__).resolve().parents[2]


def test_the_same_checkout_twice_is_paired_with_the_peer() -> None:
    found = main(REPO, REPO, frames=2, passes=1, flags=("--no-second-look",))
    assert found["frames"] == 2
    assert set(found["cpu_ms_per_frame"]) == {"peer", "old", "new"}
    for key in ("old_vs_peer_tag_ms", "new_vs_peer_record_ms", "new_minus_old_tag_ms"):
        assert isinstance(found[key], float)
