"""tools/exit_stress.py, short: two runs of the real service beside a CPU-burning process and one
of the demo, each signalled while busy; a run over the deadline fails the tool."""

from __future__ import annotations

import io
import re

import pytest

from tools import exit_stress


# one burner for the service's runs only: the rest of the suite runs beside them
@pytest.mark.parametrize(("command", "runs", "burners"), [("run", 2, 1), ("demo", 1, 0)])
def test_every_run_exits_0_within_the_deadline(command: str, runs: int, burners: int) -> None:
    out = io.StringIO()
    code = exit_stress.main(runs=runs, burner_count=burners, command=command, out=out)
    lines = out.getvalue().splitlines()
    assert code == 0, "\n".join(lines)
    results = [line for line in lines if line.startswith("run ")]
    # SIGTERM then SIGINT, each answered by exit 0
    assert [re.findall(r"signal=(\w+) .* code=(\S+)", line)[0] for line in results] == [
        ("SIGTERM", "0"),
        ("SIGINT", "0"),
    ][:runs]
    assert lines[-1].startswith(f"runs={runs} exit_codes={{'0': {runs}}} ")
    assert lines[-1].endswith(" over_2s=0")


def test_an_exit_over_the_deadline_fails_the_tool() -> None:
    out = io.StringIO()
    assert exit_stress.main(runs=1, burner_count=0, deadline_s=1e-6, out=out) == 1
    (result,) = [line for line in out.getvalue().splitlines() if line.startswith("run ")]
    assert " code=0 " in result and result.endswith(" FAIL")


def test_the_summary_counts_crashes_hangs_and_slow_exits() -> None:
    runs = [
        exit_stress.Run(1, "SIGTERM", 0, 0.1, 3, ""),
        exit_stress.Run(2, "SIGINT", -6, 0.1, 3, "FATAL: exception not rethrown"),
        exit_stress.Run(3, "SIGTERM", None, 20.0, 3, ""),
    ]
    assert exit_stress.summary(runs, 2.0) == (
        "runs=3 exit_codes={'-6': 1, '0': 1, 'hung': 1} exit_s_median=0.10 exit_s_max=20.00 "
        "over_2s=1"
    )
