"""The veto's read and the corner refinement of this checkout against another revision's, tag
by tag: every number must be the same to the bit.

``python -m tools.read_equivalence --base main [--dataset corpus/manifest.json]
[--frames 24] [--max-video-frames 20] [--timing-rounds 3]``

The revision ``--base`` (``git archive``) and this checkout each run this file in a child
process of their own (the package imported from that tree), over the same tags: OpenCV's
proposals and the second look's on generated frames (HD720 with look-alikes, VGA, in several
dictionaries; drawn look-alikes) and on the manifest's pictures and videos, each tag also with
its corners jittered, shrunk and moved to the image's edge. For each: the verifier's reason,
every measure of :func:`~zenoh_perception.detect.verify.measure`, the reading the second look
uses (quiet zone, levels) and the refined corners. Any difference is printed, exit 1.

Then the CPU per judged tag (``Verifier.check``) and per refined tag (``refine_corners``) on
the generated HD720 frames, each child timing its own, the two alternating ``--timing-rounds``
times (``time.thread_time``: CPU, not wall time, on a busy machine).
"""

from __future__ import annotations

import argparse
import io
import itertools
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Iterator
from dataclasses import astuple
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.detect.cells import stroke_excess
from zenoh_perception.detect.factory import make_detector
from zenoh_perception.detect.types import Detection
from zenoh_perception.detect.verify import Verifier, measure, read_detection
from zenoh_perception.tags.corners import marker_cells, refine_corners
from zenoh_perception_bench.footage import data_folder, frames
from zenoh_perception_bench.manifest import TooLargeError, load_manifest
from zenoh_perception_bench.overhead import frames_at
from zenoh_perception_bench.scene import CameraModel, Effects, SceneGenerator
from zenoh_perception_bench.scene.lookalikes import DRAWN_KINDS, lookalike_frame

Gray = npt.NDArray[np.uint8]
Case = tuple[str, Gray, str]  # name, grey frame, dictionary

#: Dictionaries of the generated frames: each grid size, an AprilTag family, and one whose ids
#: lie one bit apart (no margin rule).
GENERATED = ("DICT_4X4_50", "DICT_5X5_100", "DICT_6X6_250", "DICT_7X7_50", "DICT_APRILTAG_36h11")
ONE_BIT_APART = "DICT_ARUCO_ORIGINAL"


def _gray(image: npt.NDArray[np.uint8]) -> Gray:
    return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY), np.uint8)


def generated(frames: int) -> Iterator[Case]:
    """Generated frames: HD720 with look-alikes (the service's bench), VGA, drawn look-alikes."""
    for index, image in enumerate(frames_at("HD720", frames, 2044, lookalikes=True)):
        yield f"hd720-{index}", _gray(image), "DICT_4X4_50"
    for dictionary in (*GENERATED, ONE_BIT_APART):
        scenes = SceneGenerator(
            CameraModel.named("VGA"), dictionary=dictionary, seed=7, effects=Effects.realistic()
        )
        for index in range(frames // 2):
            scene = scenes.random_scene(1 + index % 5, 2)
            yield f"vga-{dictionary}-{index}", _gray(scene.image), dictionary
    rng = np.random.default_rng(11)
    for kind in DRAWN_KINDS:
        for index in range(max(frames // 8, 1)):
            yield f"{kind}-{index}", _gray(lookalike_frame(kind, "DICT_4X4_50", rng)), "DICT_4X4_50"


def corpus(manifest: Path, max_video_frames: int) -> Iterator[Case]:
    """The manifest's frames, each in its dictionary (a negative in every one it uses)."""
    items = load_manifest(manifest)
    folder = data_folder(manifest, None)
    dictionaries = sorted({i.dictionary for i in items if not i.negative})
    for item in items:
        try:
            for index, image in enumerate(frames(item, folder, max_video_frames)):
                for dictionary in dictionaries if item.negative else [item.dictionary]:
                    yield f"{item.name}-{index}-{dictionary}", _gray(image), dictionary
        except TooLargeError:
            continue


def variants(corners: npt.NDArray[np.float32], shape: tuple[int, ...], seed: int) -> list[Any]:
    """The corners as OpenCV gave them, jittered, shrunk to half about their centre, and moved
    so that the quad touches the image's left or top edge (its quiet zone cut)."""
    rng = np.random.default_rng(seed)
    centre = corners.mean(axis=0)
    shift = -corners.min(axis=0) + rng.uniform(0.0, 3.0, 2)
    shift[rng.integers(0, 2)] = 0.0
    moved = corners + shift.astype(np.float32)
    inside = (moved[:, 0] < shape[1] - 1).all() and (moved[:, 1] < shape[0] - 1).all()
    return [
        corners,
        (corners + rng.uniform(-1.5, 1.5, corners.shape)).astype(np.float32),
        ((corners - centre) * 0.5 + centre).astype(np.float32),
        *([moved] if inside else []),
    ]


def results(cases: Iterator[Case]) -> dict[str, Any]:
    """Every number compared, per tag and variant, keyed by case, detection and variant."""
    found: dict[str, Any] = {}
    for name, gray, dictionary in cases:
        detector = make_detector("opencv", dictionary)
        detections = detector.detect(gray) + detector.look_again()
        verifier = Verifier(dictionary)
        found[name] = [(d.tag_id, d.corners.tobytes()) for d in detections]
        for index, detection in enumerate(detections):
            shapes = variants(detection.corners, gray.shape, index)
            for number, corners in enumerate(shapes):
                tag = Detection(detection.tag_id, corners, dictionary)
                reading = read_detection(gray, tag, dictionary)
                refined, ok = refine_corners(gray, corners, marker_cells(dictionary))
                found[f"{name}/{index}/{number}"] = (
                    verifier.check(gray, tag),
                    astuple(measure(gray, tag, dictionary)),
                    reading.quiet,
                    reading.quiet_local,
                    reading.contrast,
                    reading.border_light,
                    reading.grid_ratio,
                    reading.levels().tobytes(),
                    stroke_excess(reading),
                    refined.tobytes(),
                    ok.tobytes(),
                )
    return found


def timing(frames: int, rounds: int = 3) -> tuple[float, float, int]:
    """Least CPU microseconds per judged tag and per refined tag over ``rounds`` rounds, on the
    generated HD720 frames with look-alikes (all their tags, each once a round), and how many
    tags."""
    tags = []
    for image in frames_at("HD720", frames, 2044, lookalikes=True):
        gray = _gray(image)
        detector = make_detector("opencv", "DICT_4X4_50")
        tags += [(gray, d) for d in detector.detect(gray) + detector.look_again()]
    verifier = Verifier("DICT_4X4_50")
    best = [float("inf"), float("inf")]
    for _ in range(rounds):
        start = time.thread_time()
        for gray, detection in tags:
            verifier.check(gray, detection)
        judged = time.thread_time()
        for gray, detection in tags:
            refine_corners(gray, detection.corners, 6)
        best = [min(best[0], judged - start), min(best[1], time.thread_time() - judged)]
    return best[0] / len(tags) * 1e6, best[1] / len(tags) * 1e6, len(tags)


def _child(tree: Path, argv: list[str]) -> Any:
    """This file run with the package of ``tree``, from outside any checkout; its answer."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "out.pickle"
        env = dict(os.environ, PYTHONPATH=f"{tree}{os.pathsep}{tree / 'bench'}")
        command = [sys.executable, str(Path(__file__).resolve()), *argv, "--out", str(out)]
        subprocess.run(command, check=True, cwd=folder, env=env)
        return pickle.loads(out.read_bytes())  # noqa: S301 (our own child's file)


def compare(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """The keys whose numbers differ (or that one side lacks), printed with both sides."""
    differ = sorted(k for k in old.keys() | new.keys() if old.get(k) != new.get(k))
    tags = sum(1 for k in old if "/" in k)
    print(f"{len(old) - tags} frames, {tags} tag reads: {len(differ)} differ")
    for key in differ[:20]:
        print(f"  {key}:\n    base {old.get(key)}\n    this {new.get(key)}")
    return differ


def main(
    base: str = "main",
    dataset: Path | None = None,
    frames: int = 24,
    max_video_frames: int = 20,
    timing_rounds: int = 3,
) -> int:
    """Exit status 1 when a number differs between ``base`` and this checkout (see the module
    documentation), after the timing rounds."""
    here = Path(__file__).resolve().parents[1]
    with tempfile.TemporaryDirectory() as folder:
        tree = Path(folder)
        archive = subprocess.run(
            ["git", "-C", str(here), "archive", base], check=True, capture_output=True
        ).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(tree, filter="data")
        common = ["--frames", str(frames), "--max-video-frames", str(max_video_frames)]
        if dataset is not None:
            common += ["--dataset", str(dataset.resolve())]
        differ = compare(
            _child(tree, [*common, "--mode", "results"]),
            _child(here, [*common, "--mode", "results"]),
        )
        if timing_rounds:
            print("CPU us per tag (judged, refined), base and this checkout alternating:")
        timed = ["--frames", str(frames), "--mode", "timing"]
        trees = [("base", tree), ("this", here)]
        for round_ in range(timing_rounds):
            for label, root in trees if round_ % 2 == 0 else trees[::-1]:
                judged, refined, tags = _child(root, timed)
                print(f"  {label}: {judged:7.1f} {refined:7.1f}  ({tags} tags)")
    return 1 if differ else 0


def _child_main(args: argparse.Namespace) -> None:
    """A child's work, with the package its PYTHONPATH names: its answer pickled to --out."""
    answer: Any
    if args.mode == "timing":
        answer = timing(args.frames)
    else:
        cases = generated(args.frames)
        if args.dataset is not None:
            cases = itertools.chain(cases, corpus(args.dataset.resolve(), args.max_video_frames))
        answer = results(cases)
    args.out.write_bytes(pickle.dumps(answer))


def _parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m tools.read_equivalence", description=__doc__)
    parser.add_argument("--base", default="main", help="the git revision to compare with")
    parser.add_argument("--dataset", type=Path, help="a manifest whose frames are read too")
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--max-video-frames", type=int, default=20)
    parser.add_argument("--timing-rounds", type=int, default=3)
    parser.add_argument("--mode", choices=("results", "timing"), help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    return parser.parse_args(argv)


if __name__ == "__main__":
    args = _parse(sys.argv[1:])
    if args.mode is not None:
        _child_main(args)
        sys.exit(0)
    sys.exit(main(args.base, args.dataset, args.frames, args.max_video_frames, args.timing_rounds))
