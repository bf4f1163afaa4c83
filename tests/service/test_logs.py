"""key=value log lines: safe against whatever text a payload carries."""

from __future__ import annotations

import json
import logging
import re

from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.service.logs import KeyValueFormatter, kv, kv_value

_RAW_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def test_log_values_cannot_break_a_line_or_forge_a_key() -> None:
    line = kv(reason="bad_cdr", detail='say "hi"\nlevel=ERROR', empty="")
    assert line == 'reason=bad_cdr detail="say \\"hi\\"\\nlevel=ERROR" empty=""'
    record = logging.LogRecord(
        "x", logging.WARNING, __file__, 1, "event=rejected %s", (line,), None
    )
    formatted = KeyValueFormatter().format(record)
    assert "\n" not in formatted
    assert formatted.startswith("ts=") and " level=WARNING logger=x event=rejected " in formatted


@given(st.text())
def test_a_value_holds_no_raw_control_character_and_reads_back(text: str) -> None:
    value = kv_value(text)
    assert not _RAW_CONTROL.search(value)
    assert (json.loads(value) if value.startswith('"') else value) == text


def test_the_formatter_escapes_controls_in_a_message_it_did_not_build() -> None:
    record = logging.LogRecord("x", logging.ERROR, __file__, 1, "a\x1b[2J\x00\x07\x7fb", (), None)
    formatted = KeyValueFormatter().format(record)
    assert not _RAW_CONTROL.search(formatted)
    assert formatted.endswith("a\\x1b[2J\\x00\\x07\\x7fb")
