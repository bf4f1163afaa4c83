"""Every tool with a command line runs from the repository root, as tools/README.md says."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.helpers import REPO

TOOLS = REPO / "tools"
#: The tools with a command line (a ``__main__`` block).
RUNNABLE = sorted(
    path.stem
    for path in TOOLS.glob("*.py")
    if 'if __name__ == "__main__":' in path.read_text(encoding="utf-8")
)


def test_the_runnable_tools_are_found() -> None:
    assert {"flood", "soak", "fuzz", "stalls"} <= set(RUNNABLE)


@pytest.mark.parametrize("name", RUNNABLE)
def test_the_readme_says_how_to_run_each_tool(name: str) -> None:
    readme = (TOOLS / "README.md").read_text(encoding="utf-8")
    assert f"`{name}.py`" in readme
    assert f"python -m tools.{name}" in readme


@pytest.mark.parametrize("name", RUNNABLE)
def test_each_tool_parses_its_flags_from_the_repository_root(name: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", f"tools.{name}", "--help"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: ")
