"""The progress bar: one line, redrawn in place, full at the end."""

from __future__ import annotations

import io

from zenoh_perception.bench.progress import Progress, tick


def test_progress_bar_ends_full_on_one_line() -> None:
    stream = io.StringIO()
    bar = Progress(3, stream=stream, width=10)
    for _ in range(5):
        bar.step("work")
    bar.close()
    text = stream.getvalue()
    assert text.endswith("\n")
    assert text.count("\n") == 1
    assert "[##########]    3/3 work" in text
    assert bar.done == bar.total == 3


def test_tick_steps_a_bar_and_ignores_none() -> None:
    stream = io.StringIO()
    bar = Progress(4, stream=stream, width=4)
    tick(bar, "one")
    tick(None, "nothing")
    assert bar.done == 1
    assert "one" in stream.getvalue()
