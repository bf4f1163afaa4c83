"""``echo``: what it listens to, and gap counting (records lost show as gaps in ``seq``)."""

from __future__ import annotations

import io
import json

from zenoh_perception.bench._loopback import loopback_config, loopback_endpoint
from zenoh_perception.cli import echo
from zenoh_perception.cli.echo import Gap, SeqGaps


def test_consecutive_seqs_have_no_gap() -> None:
    gaps = SeqGaps()
    assert [gaps.observe(seq) for seq in range(5)] == [None] * 5
    assert gaps.summary() == "records=5 gaps=0 missing=0 restarts=0"


def test_missing_seqs_are_gaps_with_their_count() -> None:
    gaps = SeqGaps()
    seen = [gaps.observe(seq) for seq in (1, 2, 5, 6, 10)]
    assert seen == [None, None, Gap(2, 5), None, Gap(6, 10)]
    assert [g.missing for g in seen if g is not None] == [2, 3]
    assert (gaps.records, gaps.gaps, gaps.missing) == (5, 2, 5)


def test_a_seq_going_back_is_a_restart_not_a_gap() -> None:
    gaps = SeqGaps()
    for seq in (7, 8, 0, 1, 1):
        assert gaps.observe(seq) is None
    assert (gaps.gaps, gaps.missing, gaps.restarts) == (0, 0, 2)


def test_seqs_that_are_not_integers_are_ignored() -> None:
    gaps = SeqGaps()
    for seq in (1, "2", True, None, 2.0, 2):
        assert gaps.observe(seq) is None
    assert gaps.records == 2 and gaps.gaps == 0


def test_gap_lines_in_text_and_json() -> None:
    gap = Gap(2, 5)
    assert gap.format("perception/tags", as_json=False) == (
        "[perception/tags] gap: 2 record(s) missing between seq 2 and 5"
    )
    assert json.loads(gap.format("perception/tags", as_json=True)) == {
        "key": "perception/tags",
        "gap": {"after": 2, "next": 5, "missing": 2},
    }


def test_echo_says_what_it_listens_to_before_anything_arrives() -> None:
    out, err = io.StringIO(), io.StringIO()
    conf = loopback_config(listen=[loopback_endpoint()])
    code = echo.main(conf, tag_key="rover/tag", count=1, timeout=0.2, out=out, err=err)
    assert code == 1  # nothing arrived
    assert out.getvalue() == ""
    assert "listening on 'rover/tag' and 'perception/tags'" in err.getvalue()
