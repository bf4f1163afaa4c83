"""tools/stage_cpu.py: each stage's CPU time, before and after the tag."""

from __future__ import annotations

import zenoh_perception.pipeline as pipeline_module
from tools.stage_cpu import main


def test_the_stages_are_counted_and_the_package_left_as_it_was() -> None:
    refined = pipeline_module.refined
    found = main(frames=2, passes=1)
    assert found["frames"] == 2
    assert set(found["cpu_ms_per_frame"]) == {"decode", "to tag", "finish", "record"}
    stages = found["stage_cpu_ms_per_frame"]
    assert stages["opencv read"] > 0.0 and "veto" in stages and "corner refinement" in stages
    assert pipeline_module.refined is refined
