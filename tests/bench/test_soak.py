"""Soak: a short run of the real service (CLI subprocess) against a steady camera."""

from __future__ import annotations

import json
from pathlib import Path

from zenoh_perception.bench import soak


def test_short_soak_measures_the_real_service_and_passes(tmp_path: Path) -> None:
    out = tmp_path / "soak.json"
    argv = ["--duration", "5", "--rate", "60", "--resolution", "HD720", "--warmup", "1"]
    code = soak.main([*argv, "--json", str(out), "--quiet"])
    report = json.loads(out.read_text(encoding="utf-8"))
    frames = report["service"]["frames"]
    assert report["failures"] == []
    assert report["frames_sent"] > 0
    assert frames["received"] == report["frames_sent"]
    assert frames["processed"] > 0
    assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]
    assert report["answered"] > 0
    assert 0 < report["e2e_latency_ms"]["p50"] <= report["e2e_latency_ms"]["p99"]
    assert report["baseline"]["rss_kib"] > 0 and report["end"]["threads"] > 0
    assert report["end"]["fds"] > 0
    assert report["exit_code"] == 0
    assert report["problems"] == []
    assert code == 0
