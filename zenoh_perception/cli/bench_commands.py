"""The commands of the benchmark package (``bench``, ``demo``): their flags, and handlers that
import the package only when they run, saying how to install it when it is missing.

The service does not ship that package (``bench/`` in this repository is a second one).
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

from zenoh_perception.cli.numbers import (
    DEMO_MAX_FPS,
    DEMO_MIN_FPS,
    MAX_COUNT,
    bounded_float,
    bounded_int,
)
from zenoh_perception.errors import MissingPackageError
from zenoh_perception.resolutions import RESOLUTIONS
from zenoh_perception.service.signals import stop_on_signals
from zenoh_perception.service.zenoh_args import add_zenoh_arguments, zenoh_config_from_args
from zenoh_perception.settings import add_settings_arguments, load_settings, settings_from_args

#: The second package of this repository (``bench/``): benchmarks, scene generator, demo camera.
BENCH_PACKAGE = "zenoh_perception_bench"


def _need_bench_package(command: str) -> None:
    """Refuse ``command`` (exit 2, saying how to install it) when the benchmark package,
    which the service does not ship, is missing."""
    if importlib.util.find_spec(BENCH_PACKAGE) is None:
        raise MissingPackageError(command)


def _cmd_demo(args: argparse.Namespace) -> int:
    _need_bench_package("demo")
    from zenoh_perception_bench import demo  # noqa: PLC0415

    return demo.main(
        zenoh_config_from_args(args),
        settings_from_args(args),
        resolution=args.resolution,
        fps=args.fps,
        cdr=args.format == "cdr",
        camera_only=args.camera_only,
        limit=args.limit,
        shm=args.shm,
        adversaries=args.adversaries,
        stop=stop_on_signals(),
    )


def add_demo(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "demo",
        help="synthetic camera + service + echo in one process (no camera needed)",
        description="A rover driving toward synthetic tags, the service, and its output.",
    )
    _add_demo_arguments(parser)
    add_zenoh_arguments(parser)
    add_settings_arguments(parser)
    parser.set_defaults(handler=_cmd_demo, leaves_threads=True)


def _add_demo_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("demo camera")
    group.add_argument(
        "--resolution", choices=tuple(RESOLUTIONS), default="VGA", help="camera resolution"
    )
    group.add_argument(
        "--fps",
        type=bounded_float(DEMO_MIN_FPS, DEMO_MAX_FPS),
        default=15.0,
        help=f"frames per second, [{DEMO_MIN_FPS:g}, {DEMO_MAX_FPS:g}] (default 15)",
    )
    group.add_argument(
        "--format", choices=("raw", "cdr"), default="raw", help="raw+attachment or Image CDR"
    )
    group.add_argument(
        "--camera-only", action="store_true", help="only publish frames (feed a separate run)"
    )
    group.add_argument(
        "--limit",
        type=bounded_int(0, MAX_COUNT),
        default=0,
        help="stop after N frames (0: never)",
    )
    group.add_argument(
        "--shm",
        action="store_true",
        help="put frames from a Zenoh shared-memory buffer, as a camera on the service's machine "
        "would (no copy on put; plain puts, with a warning, where unavailable) (default: off)",
    )
    group.add_argument(
        "--adversaries",
        action="store_true",
        help="drive past synthetic adversaries instead of what a rover meets: an exact valid "
        "code hidden in a blob, a glyph or a bare code, which no real camera shows (default: "
        "keyboards, text, tiles, other families' markers)",
    )


def _cmd_bench(args: argparse.Namespace) -> int:
    _need_bench_package("bench")
    if args.poses:
        from zenoh_perception_bench import poses  # noqa: PLC0415

        return poses.main(args)
    if args.fleet:
        from zenoh_perception_bench import fleet  # noqa: PLC0415

        return fleet.main(args)
    if args.overhead:
        from zenoh_perception_bench import overhead  # noqa: PLC0415

        return overhead.main(args)
    if args.link:
        from zenoh_perception_bench import link  # noqa: PLC0415

        return link.main(args)
    if args.streams:
        from zenoh_perception_bench import streams  # noqa: PLC0415

        return streams.main(args)
    if args.peer is not None:
        from zenoh_perception_bench import peer  # noqa: PLC0415

        return peer.main(args)
    if args.dataset is not None or args.init is not None:
        from zenoh_perception_bench import dataset  # noqa: PLC0415

        return dataset.main(args, load_settings(args.settings))
    from zenoh_perception_bench import generated  # noqa: PLC0415

    return generated.main(args)


def add_bench(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "bench",
        help="the service's detector against OpenCV's default, side by side",
        description="Generated frame sets by default; --dataset MANIFEST for labelled real "
        "pictures and videos (see corpus/README.md). OpenCV's best setting measured runs "
        "beside them, shown but not judged. Exit code 1 when a goal fails.",
    )
    parser.add_argument("--quick", action="store_true", help="few frames (well under a minute)")
    parser.add_argument("--json", type=Path, metavar="PATH", help="write the report as JSON")
    parser.add_argument(
        "--plot",
        type=Path,
        metavar="PATH",
        help="write a PNG of latency vs resolution (--dataset: found and false ids per item "
        "and per marker size)",
    )
    parser.add_argument(
        "--frames", type=bounded_int(1, 100_000), help="independent frames per resolution"
    )
    parser.add_argument(
        "--video-frames", type=bounded_int(2, 100_000), help="frames of the video drive"
    )
    parser.add_argument("--seed", type=bounded_int(0, 2**32 - 1), help="scene seed")
    parser.add_argument(
        "--passes",
        type=bounded_int(1, 1000),
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
    group = parser.add_argument_group("against a peer")
    group.add_argument(
        "--peer",
        choices=["ros2"],
        help="ros2: a ros2_aruco-style rclpy node over Fast DDS, reliable then best effort, "
        "beside this service, OpenCV bare and the transport floor (HD720; needs the ros2 extra)",
    )
    group.add_argument(
        "--ros-python",
        metavar="PYTHON",
        help="the Python with the ros2 extra (default: this one)",
    )
    group.add_argument(
        "--overhead",
        action="store_true",
        help="what the service adds to OpenCV in ms, per frame size, to tag and to record, "
        "shared-memory and plain-bytes camera",
    )
    group.add_argument(
        "--streams",
        action="store_true",
        help="three VGA cameras at 15 Hz into one service, alone and beside an HD2K one",
    )
    group.add_argument(
        "--link",
        action="store_true",
        help="HD720 as raw Image CDR and as image_transport's JPEG: bytes a frame puts on a "
        "link, and put -> tag through the service, in lockstep",
    )
    group.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="with --overhead: also HD1080 at HZ, frames answered per detector",
    )
    group.add_argument(
        "--poses",
        action="store_true",
        help="tag poses against exact ground truth (rendered HD720 and VGA frames, 1-10 m): "
        "rotation and distance errors of the service and of OpenCV's corner refinements, "
        "flipped poses marked ambiguous, cost a tag",
    )
    group = parser.add_argument_group("several instances")
    group.add_argument(
        "--fleet",
        action="store_true",
        help="cameras, two Zenoh routers and instances of a share group as processes: "
        "frames answered, duplicates and gaps around a kill and a join, bytes read per "
        "instance, latency, and HD720 capacity against bare OpenCV's",
    )
    group.add_argument(
        "--fleet-configs",
        metavar="NxM,...",
        help="cameras x instances to run (default 1x1,4x1,4x2,8x3)",
    )
    group.add_argument(
        "--fleet-rate",
        type=bounded_float(0.5, 60.0),
        default=4.0,
        metavar="HZ",
        help="with --fleet: each camera's VGA rate around the kill and the join (default 4)",
    )
    group.add_argument(
        "--fleet-window",
        type=bounded_float(1.0, 600.0),
        default=4.0,
        metavar="S",
        help="with --fleet: seconds of each measured window (capacity: twice that)",
    )
    group.add_argument(
        "--fleet-shm",
        action="store_true",
        help="with --fleet: shared memory on in every process (frames pass by reference on "
        "this machine): the instances' own capacity",
    )
    group = parser.add_argument_group("labelled dataset")
    group.add_argument(
        "--dataset",
        nargs="?",
        const="",  # --dataset --init FOLDER: no manifest (the bench makes it a Path)
        metavar="MANIFEST",
        help="bench a labelled manifest instead (docs/dataset.md)",
    )
    group.add_argument(
        "--init",
        type=Path,
        metavar="FOLDER",
        help="with --dataset: write FOLDER/manifest.json listing its pictures and videos, "
        "to fill in",
    )
    group.add_argument(
        "--data", type=Path, metavar="DIR", help="its files (default: data/ beside it)"
    )
    group.add_argument(
        "--settings",
        type=Path,
        metavar="FILE",
        help="the service settings to bench (default: the defaults); also given to the "
        "service processes of --e2e and --overhead",
    )
    group.add_argument(
        "--e2e", action="store_true", help="also run each video through service processes"
    )
    group.add_argument(
        "--max-video-frames",
        type=bounded_int(1, 1_000_000),
        default=600,
        metavar="N",
        help="frames read from each video (default 600)",
    )
    parser.set_defaults(handler=_cmd_bench)
