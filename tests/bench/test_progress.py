"""The progress bar: redrawn in place on a terminal, a line per tenth of the work elsewhere."""

from __future__ import annotations

import io

from zenoh_perception_bench.progress import Progress, tick


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_on_a_terminal_the_bar_ends_full_on_one_line() -> None:
    stream = Terminal()
    bar = Progress(3, stream=stream, width=10)
    for _ in range(5):
        bar.step("work")
    bar.close()
    text = stream.getvalue()
    assert text.startswith("\r") and text.endswith("\n")
    assert text.count("\n") == 1
    assert text.rstrip().rsplit("\r", 1)[-1].split() == ["[##########]", "3/3", "work"]
    assert bar.done == bar.total == 3


def test_away_from_a_terminal_a_line_per_tenth_of_the_work() -> None:
    stream = io.StringIO()
    bar = Progress(1000, stream=stream, width=10)
    for index in range(1000):
        bar.step(f"item {index}")
    bar.close()
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue()
    assert len(lines) == 11  # 0 %, 10 %, ..., 100 %
    assert lines[-1].split() == ["[##########]", "1000/1000", "item", "999"]


def test_tick_steps_a_bar_and_ignores_none() -> None:
    stream = io.StringIO()
    bar = Progress(4, stream=stream, width=4)
    tick(bar, "one")
    tick(None, "nothing")
    assert bar.done == 1
    assert "one" in stream.getvalue()
