"""Soak: a short run of ``python -m tools.soak`` against the real service (CLI subprocess)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.helpers import REPO


def test_short_soak_measures_the_real_service_and_passes(tmp_path: Path) -> None:
    out = tmp_path / "soak.json"
    # Seconds, not minutes: this checks the tool's mechanics and catches a gross leak (a kept
    # HD720 frame a frame is 160 MiB a second, several times the service's whole RSS). Under
    # a loaded machine, frames Zenoh buffers while the worker waits for a core grew RSS by up
    # to a third over a second of warm-up, so the growth allowed here is wider than the
    # tool's default, which judges a run of minutes (docs/robustness.md).
    argv = ["--duration", "6", "--rate", "60", "--resolution", "HD720", "--warmup", "2"]
    argv += ["--max-rss-growth-pct", "60"]
    # from the repository root, as tools/README.md says to run it
    done = subprocess.run(
        [sys.executable, "-m", "tools.soak", *argv, "--json", str(out), "--quiet"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert out.exists(), done.stderr
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
    assert done.returncode == 0, done.stderr
    assert done.stdout.rstrip().endswith("PASS")
