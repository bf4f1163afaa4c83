"""The ``bench`` subcommand: the generator's frame sets, or a labelled dataset (``--dataset``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from zenoh_perception.bench import dataset, detectors
from zenoh_perception.settings import load_settings


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``bench`` subcommand."""
    parser = sub.add_parser(
        "bench",
        help="the service's detector against OpenCV's default, side by side",
        description="Generated frame sets by default; --dataset MANIFEST for labelled real "
        "pictures and videos (see corpus/README.md). Exit code 1 when a goal fails.",
    )
    parser.add_argument("--quick", action="store_true", help="few frames (well under a minute)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the report as JSON")
    parser.add_argument(
        "--plot", type=Path, metavar="PATH", help="write a PNG of latency vs resolution"
    )
    parser.add_argument("--frames", type=int, help="independent frames per resolution")
    parser.add_argument("--video-frames", type=int, help="frames of the video drive")
    parser.add_argument("--seed", type=int, help="scene seed")
    parser.add_argument(
        "--passes",
        type=int,
        help="end to end: lockstep passes over each frame set, pooled (full: 3)",
    )
    parser.add_argument(
        "--no-e2e", action="store_true", help="skip the service (Zenoh) measurements"
    )
    parser.add_argument(
        "--no-shm",
        action="store_true",
        help="end to end: the camera puts plain bytes (Zenoh copies them on put) instead of "
        "frames from a shared-memory buffer",
    )
    group = parser.add_argument_group("labelled dataset")
    group.add_argument(
        "--dataset", type=Path, metavar="MANIFEST", help="bench a labelled manifest instead"
    )
    group.add_argument(
        "--data", type=Path, metavar="DIR", help="its files (default: data/ beside it)"
    )
    group.add_argument(
        "--settings",
        type=Path,
        metavar="FILE",
        help="the service settings to bench (default: the defaults)",
    )
    group.add_argument(
        "--e2e", action="store_true", help="also run each video through service processes"
    )
    group.add_argument(
        "--max-video-frames",
        type=int,
        default=600,
        metavar="N",
        help="frames read from each video (default 600)",
    )
    parser.set_defaults(handler=main)


def main(args: argparse.Namespace) -> int:
    if args.dataset is not None:
        return dataset.main(args, load_settings(args.settings))
    return detectors.main(args)
