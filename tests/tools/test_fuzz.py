"""Bad input, end to end: a small run of the fuzz script against the real service (CLI)."""

from __future__ import annotations

from tools.fuzz import run_fuzz
from tools.fuzz_cases import OK


def test_service_survives_2000_malformed_payloads_and_answers_good_frames() -> None:
    report = run_fuzz(2000, seed=1)
    assert report.problems() == []
    frames = report.status["frames"]
    by_reason = report.status["rejected_by_reason"]
    assert report.sent == 2000
    assert frames["received"] == 2002  # + one good raw and one good CDR frame
    assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]
    assert sum(by_reason.values()) == frames["rejected"] > 0
    assert set(by_reason) <= set(report.expected) - {OK}
    for reason, count in by_reason.items():
        assert count <= report.expected[reason]
    assert [(a["source"], a["ok"]) for a in report.good_answers] == [("raw", True), ("cdr", True)]
    assert report.alive
    assert report.tracebacks == 0
    assert report.exit_code == 0
    assert 0 < report.rejected_log_lines < frames["rejected"]  # rate-limited warnings
