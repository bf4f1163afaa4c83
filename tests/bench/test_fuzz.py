"""Bad input, end to end: a small run of the fuzz script against the real service (CLI)."""

from __future__ import annotations

from collections import Counter

from zenoh_perception.bench.fuzz import GENERATORS, OK, cases, expected_outcome, run_fuzz

_REASONS = {
    "bad_attachment",
    "bad_cdr",
    "bad_dimensions",
    "bad_stamp",
    "size_mismatch",
    "unsupported_encoding",
}


def test_generators_make_malformed_payloads_of_every_rejection_reason() -> None:
    outcomes: dict[str, Counter[str]] = {}
    for case in cases(seed=7, count=len(GENERATORS) * 60):
        outcomes.setdefault(case.kind, Counter())[expected_outcome(case)] += 1
    assert len(outcomes) == len(GENERATORS)
    for kind, counts in outcomes.items():
        # Mostly rejected (a bit flip in pixel bytes may leave a valid frame).
        assert counts[OK] <= 0.25 * counts.total(), (kind, counts)
    reasons = set().union(*outcomes.values()) - {OK}
    assert reasons == _REASONS


def test_service_survives_2000_malformed_payloads_and_answers_good_frames() -> None:
    report = run_fuzz(2000, seed=1)
    assert report.problems() == []
    frames = report.status["frames"]
    by_reason = report.status["rejected_by_reason"]
    assert report.sent == 2000
    assert frames["received"] == 2002  # + one good raw and one good CDR frame
    assert frames["received"] == frames["processed"] + frames["dropped"] + frames["rejected"]
    assert sum(by_reason.values()) == frames["rejected"] > 0
    assert set(by_reason) <= _REASONS
    for reason, count in by_reason.items():
        assert count <= report.expected[reason]
    assert [(a["source"], a["ok"]) for a in report.good_answers] == [("raw", True), ("cdr", True)]
    assert report.alive
    assert report.tracebacks == 0
    assert report.exit_code == 0
    assert 0 < report.rejected_log_lines < frames["rejected"]  # rate-limited warnings
