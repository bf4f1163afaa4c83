"""tools/service_ab.py: two checkouts and the reading peer, paired frame by frame."""

from __future__ import annotations

from pathlib import Path

import pytest

from tools.service_ab import _started, main
from zenoh_perception_bench._loopback import loopback_endpoint

REPO = Path(__file__).resolve().parents[2]


def test_the_same_checkout_twice_is_paired_with_the_peer() -> None:
    found = main(REPO, REPO, frames=2, passes=1, flags=("--no-second-look",))
    assert found["frames"] == 2
    assert set(found["cpu_ms_per_frame"]) == {"peer", "old", "new"}
    for key in ("old_vs_peer_tag_ms", "new_vs_peer_record_ms", "new_minus_old_tag_ms"):
        assert isinstance(found[key], float)


def test_a_version_runs_from_its_own_checkout(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # ``python -m`` imports from the current directory first: the child must start in the
    # checkout it stands for, whatever directory the tool runs from
    monkeypatch.chdir(tmp_path)
    process = _started("new", loopback_endpoint(), REPO, ())
    try:
        assert Path(f"/proc/{process.proc.pid}/cwd").readlink() == REPO
    finally:
        process.stop()
    assert Path.cwd() == tmp_path
