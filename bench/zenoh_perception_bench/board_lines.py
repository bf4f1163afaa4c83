"""Refined against OpenCV's corners on real photos of ChArUco boards: how straight the rows are.

``python -m zenoh_perception_bench.board_lines [corpus/manifest.json]``

The corpus's photos come without intrinsics or a calibration, so the corners cannot be
reprojected from a pose; but a ChArUco board is flat and its markers sit in rows (an 8x8
board: four markers a row, ids row by row), and a straight line stays straight in a picture
(lens distortion aside). Through the top corners (0 and 1) of a row's markers one line is
fitted (total least squares), through their bottom corners (3 and 2) another; each corner's
residual is its distance from its line. The same for OpenCV's default corners and for the
service's refined ones (:func:`~zenoh_perception.tags.corners.refine_corners`), on the same
markers. A bias common to every corner of a row (OpenCV's corners sit about a pixel out)
moves the line with them, so the residuals show the corners' scatter, not their offset.

Then every photo of the corpus goes through the service's pipeline with and without the
refinement: the ids found must be the same (the refinement runs on markers already decided).
"""

from __future__ import annotations

import json
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import numpy.typing as npt

from zenoh_perception.pipeline import Pipeline
from zenoh_perception.settings import Settings
from zenoh_perception.tags.corners import marker_cells, refine_corners
from zenoh_perception.tags.geometry import mean_side
from zenoh_perception.wire.frames import Frame
from zenoh_perception_bench.runners import BGRA8

#: The corpus's photos of PhotonVision's 8x8 ChArUco board (ids 0-31, four markers a row).
BOARD_PREFIXES: Final = ("pv-charuco-screen-", "photonvision-lifecam480-charuco-")
MARKERS_A_ROW: Final = 4
#: A row's line is fitted through at least this many markers' corners.
MIN_MARKERS: Final = 3


@dataclass(frozen=True, slots=True)
class Board:
    """One photo's residuals (pixels) of OpenCV's and of the refined corners."""

    name: str
    size: tuple[int, int]
    markers: int
    side_px: float
    opencv: list[float]
    refined: list[float]

    @staticmethod
    def rms(residuals: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(residuals)))) if residuals else float("nan")


def line_residuals(points: npt.NDArray[np.float64]) -> list[float]:
    """Each point's distance from the total-least-squares line through ``points`` (n, 2)."""
    centred = points - points.mean(axis=0)
    _, _, axes = np.linalg.svd(centred)
    residuals: list[float] = np.abs(centred @ axes[1]).tolist()
    return residuals


def row_residuals(corners: dict[int, npt.NDArray[np.float64]]) -> list[float]:
    """The residuals of the corners (id -> (4, 2)) of a board's markers from their rows'
    top and bottom lines."""
    out: list[float] = []
    for row in {tag // MARKERS_A_ROW for tag in corners}:
        members = sorted(tag for tag in corners if tag // MARKERS_A_ROW == row)
        if len(members) < MIN_MARKERS:
            continue
        for edge in ((0, 1), (3, 2)):
            points = np.array([corners[tag][k] for tag in members for k in edge], np.float64)
            out += line_residuals(points)
    return out


def board(name: str, path: Path, dictionary: str) -> Board:
    read = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if read is None:
        msg = f"cannot read {path}"
        raise OSError(msg)
    grey = np.asarray(read, np.uint8)
    detector = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    )
    found, ids, _ = detector.detectMarkers(grey)
    opencv = {
        int(tag): np.asarray(quad, np.float64).reshape(4, 2)
        for quad, tag in zip(found, [] if ids is None else ids.reshape(-1), strict=True)
    }
    cells = marker_cells(dictionary)
    refined = {tag: refine_corners(grey, quad, cells)[0] for tag, quad in opencv.items()}
    sides = [mean_side(quad) for quad in opencv.values()]
    return Board(
        name,
        (grey.shape[1], grey.shape[0]),
        len(opencv),
        statistics.median(sides) if sides else 0.0,
        row_residuals(opencv),
        row_residuals(refined),
    )


def _file(data: Path, name: str) -> Path | None:
    found = sorted(p for p in data.iterdir() if p.stem == name and p.is_file())
    return found[0] if found else None


def ids_found(pipeline: Pipeline, path: Path) -> list[int]:
    """The ids the pipeline keeps on the photo at ``path``."""
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        return []
    bgra = np.ascontiguousarray(cv2.cvtColor(image, cv2.COLOR_BGR2BGRA), np.uint8)
    return sorted(t.tag_id for t in pipeline.process(Frame(bgra, BGRA8, None, "bench", None)).tags)


def same_markers(items: list[dict[str, Any]], data: Path) -> tuple[int, int, list[str]]:
    """Photos compared, markers found with the refinement, and the photos where the ids
    found differ with it and without it."""
    photos = markers = 0
    differ = []
    for item in items:
        path = _file(data, item["name"])
        if item.get("kind") != "image" or path is None:
            continue
        found = []
        for refine in (True, False):
            settings = Settings.from_flat(dictionary=item["dictionary"], refine_corners=refine)
            found.append(ids_found(Pipeline(settings.detection, settings.selection), path))
        photos += 1
        markers += len(found[0])
        if found[0] != found[1]:
            differ.append(item["name"])
    return photos, markers, differ


def main(argv: list[str]) -> int:
    manifest = Path(argv[0] if argv else "corpus/manifest.json")
    data = manifest.parent / "data"
    items: list[dict[str, Any]] = json.loads(manifest.read_text(encoding="utf-8"))["items"]
    print("| photo | size | markers | side px | residual RMS, OpenCV's | refined | corners |")
    print("|---|---|---|---|---|---|---|")
    pooled: dict[str, list[float]] = {"opencv": [], "refined": []}
    for item in items:
        path = _file(data, item["name"])
        if path is None or not item["name"].startswith(BOARD_PREFIXES):
            continue
        b = board(item["name"], path, item["dictionary"])
        pooled["opencv"] += b.opencv
        pooled["refined"] += b.refined
        print(
            f"| {b.name} | {b.size[0]}x{b.size[1]} | {b.markers} | {b.side_px:.0f} | "
            f"{Board.rms(b.opencv):.3f} | {Board.rms(b.refined):.3f} | {len(b.opencv)} |"
        )
    print(
        f"| all | | | | {Board.rms(pooled['opencv']):.3f} | {Board.rms(pooled['refined']):.3f} "
        f"| {len(pooled['opencv'])} |"
    )
    photos, markers, differ = same_markers(items, data)
    print(
        f"\nEvery photo with and without the refinement: {photos} photos, {markers} markers "
        f"kept with it; ids differ on: {', '.join(differ) or 'none'}"
    )
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
