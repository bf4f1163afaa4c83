"""The benches' runs shared by the tests of their modules: ``bench --quick`` through the CLI
(end to end through real service processes, shared memory and plain bytes), and a small
labelled corpus (made-up items: the real corpus is not in CI).

Each bench run happens once per test session, however many pytest-xdist workers ask for it:
``--dist loadgroup`` sends its tests to one worker where it can (with pytest 9.2 it cannot,
pytest-xdist issue 1386), and a lock in the session's temporary folder makes the workers that
ask meanwhile wait for that run and read its report instead of running it again.
"""

from __future__ import annotations

import fcntl
import json
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pytest

from zenoh_perception.cli import main as cli
from zenoh_perception_bench.framesets import Plan
from zenoh_perception_bench.scene import render_markers

W, H = 640, 480
#: The plan of the ``quick`` run: ``--quick`` with fewer frames, to keep the suite short.
QUICK_PLAN = replace(Plan.quick(), frames=3, video_frames=8)


@dataclass(frozen=True)
class BenchRun:
    """What one ``zenoh-perception bench`` run left: its exit code, JSON report and plot."""

    code: int
    report: dict[str, Any]
    plot: Path


def _bench(factory: pytest.TempPathFactory, name: str, *argv: str) -> BenchRun:
    """``bench *argv``, run by the first worker of the session that asks for ``name``."""
    root = factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the session's folder, above each worker's own
    folder = root / f"bench-{name}"
    path, plot, exit_code = folder / "bench.json", folder / "bench.png", folder / "exit-code"
    with (root / f"bench-{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file is closed
        if not exit_code.exists():
            folder.mkdir(exist_ok=True)
            code = cli.main(["bench", *argv, "--json", str(path), "--plot", str(plot)])
            exit_code.write_text(str(code), encoding="ascii")
    report: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return BenchRun(int(exit_code.read_text(encoding="ascii")), report, plot)


#: The time a test of a bench run may take: one run can take minutes on a loaded 2-core
#: machine, and a test may wait for one run and then do the other.
BENCH_RUN_TIMEOUT_S = 1200


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The tests of the bench runs go to one pytest-xdist worker (see the module's doc), and
    their setup may take a run or two.

    First among the hooks: pytest-xdist reads the ``xdist_group`` marks in its own
    ``pytest_collection_modifyitems``, which would otherwise run before this one and see none.
    """
    for item in items:
        if {"quick", "quick_no_shm"} & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.xdist_group("bench-run"))
            item.add_marker(pytest.mark.timeout(BENCH_RUN_TIMEOUT_S))


@pytest.fixture(scope="session")
def quick(tmp_path_factory: pytest.TempPathFactory) -> BenchRun:
    """``bench --quick``: every frame set, end to end and throughput, shared memory."""
    plan = QUICK_PLAN
    argv = ("--quick", "--frames", str(plan.frames), "--video-frames", str(plan.video_frames))
    return _bench(tmp_path_factory, "quick", *argv)


@pytest.fixture(scope="session")
def quick_no_shm(tmp_path_factory: pytest.TempPathFactory) -> BenchRun:
    """A smaller quick run, one pass, whose camera puts plain bytes."""
    argv = ("--quick", "--no-shm", "--frames", "2", "--video-frames", "4", "--passes", "1")
    return _bench(tmp_path_factory, "quick-no-shm", *argv)


def square(x0: float, y0: float, side: float) -> npt.NDArray[np.float64]:
    return np.array([[x0, y0], [x0 + side, y0], [x0 + side, y0 + side], [x0, y0 + side]])


def _bgr(image: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2BGR), dtype=np.uint8)


def labelled(name: str, kind: str, markers: dict[str, int], **extra: Any) -> dict[str, Any]:
    """One manifest item (DICT_4X4_50 unless ``extra`` says otherwise)."""
    return {"name": name, "kind": kind, "dictionary": "DICT_4X4_50", "markers": markers, **extra}


@pytest.fixture(scope="session")
def corpus(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A manifest and its data folder: stills, a negative, a sequence and a video."""
    root = tmp_path_factory.mktemp("corpus")
    data = root / "data"
    data.mkdir()
    two = render_markers(W, H, [(3, square(60, 60, 100)), (7, square(400, 200, 30))])
    cv2.imwrite(str(data / "two.png"), _bgr(two))
    # id 9 is labelled, id 12 is a marker the labeller could not read
    one_known = render_markers(W, H, [(9, square(100, 100, 60)), (12, square(300, 300, 60))])
    cv2.imwrite(str(data / "unknown.png"), _bgr(one_known))
    five = render_markers(W, H, [(4, square(200, 150, 120))], dictionary="DICT_5X5_100")
    cv2.imwrite(str(data / "five.jpg"), _bgr(five))
    # a negative that holds a DICT_4X4_50 marker nobody labelled: a false id by definition
    cv2.imwrite(str(data / "n-empty.png"), _bgr(render_markers(W, H, [(1, square(50, 50, 80))])))
    sequence = data / "walk"
    sequence.mkdir()
    for k in range(6):
        frame = render_markers(W, H, [(5, square(80 + 10 * k, 120, 90))])
        cv2.imwrite(str(sequence / f"{k:06d}.png"), _bgr(frame))
    writer = cv2.VideoWriter(str(data / "clip.avi"), cv2.VideoWriter.fourcc(*"MJPG"), 10, (W, H))
    assert writer.isOpened()
    for k in range(8):
        writer.write(_bgr(render_markers(W, H, [(2, square(300 - 8 * k, 200, 100))])))
    writer.release()
    manifest = {
        "format": 1,
        "items": [
            labelled("two", "image", {"3": 1, "7": 1}, camera="webcam"),
            labelled("unknown", "image", {"9": 1}, unknown_markers=1),
            {**labelled("five", "image", {"4": 1}), "dictionary": "DICT_5X5_100"},
            labelled("n-empty", "image", {}),
            labelled("walk", "sequence", {"5": 1}),
            labelled("clip", "video", {"2": 1}),
        ],
    }
    (root / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    return root
