"""key=value log lines: safe against whatever text a payload carries."""

from __future__ import annotations


def test_log_values_cannot_break_a_line_or_forge_a_key() -> None:
    import logging

    from zenoh_perception.service.logs import KeyValueFormatter, kv

    line = kv(reason="bad_cdr", detail='say "hi"\nlevel=ERROR', empty="")
    assert line == 'reason=bad_cdr detail="say \\"hi\\"\\nlevel=ERROR" empty=""'
    record = logging.LogRecord(
        "x", logging.WARNING, __file__, 1, "event=rejected %s", (line,), None
    )
    formatted = KeyValueFormatter().format(record)
    assert "\n" not in formatted
    assert formatted.startswith("ts=") and " level=WARNING logger=x event=rejected " in formatted
