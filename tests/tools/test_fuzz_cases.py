"""Malformed payloads by kind, and the outcome the decoders predict for each."""

from __future__ import annotations

from collections import Counter

from tools.fuzz_cases import GENERATORS, OK, cases, expected_outcome

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
