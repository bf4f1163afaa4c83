"""Each subcommand's flags, and a handler that imports the subcommand's module only when it runs.

``import zenoh_perception.cli.main`` stays light (no OpenCV, no scene generator, no bench):
the Docker healthcheck runs ``status`` every few seconds. The benchmark package's commands
(``bench``, ``demo``) are in :mod:`zenoh_perception.cli.bench_commands`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from zenoh_perception.camera.defaults import (
    DEFAULT_COMPRESSED_KEY,
    DEFAULT_FRAME_ID,
    DEFAULT_KEY,
    DEFAULT_RATE_HZ,
)
from zenoh_perception.cli.bench_commands import add_bench, add_demo
from zenoh_perception.cli.numbers import (
    MAX_COUNT,
    MAX_RATE_HZ,
    MAX_WAIT_S,
    MIN_RATE_HZ,
    bounded_float,
    bounded_int,
)
from zenoh_perception.errors import SettingsError
from zenoh_perception.service.signals import stop_on_signals
from zenoh_perception.service.zenoh_args import (
    RMW_ZENOH_SESSION_DEFAULTS,
    SERVICE_SESSION_DEFAULTS,
    add_zenoh_arguments,
    zenoh_config_from_args,
)
from zenoh_perception.settings import (
    RosTransportKind,
    Settings,
    add_settings_arguments,
    check_bound,
    check_key,
    load_settings,
    settings_from_args,
)

if TYPE_CHECKING:
    import zenoh


def _session_defaults(ros_transport: str) -> Mapping[str, object] | None:
    """rmw_zenoh's session defaults on an rmw_zenoh graph, else Zenoh's own."""
    return RMW_ZENOH_SESSION_DEFAULTS if ros_transport == RosTransportKind.RMW_ZENOH else None


def run_config(args: argparse.Namespace, settings: Settings) -> zenoh.Config:
    """The service's session: the transport's defaults and the service's own
    (:data:`~zenoh_perception.service.zenoh_args.SERVICE_SESSION_DEFAULTS`), then the flags."""
    defaults = {**(_session_defaults(settings.ros.ros_transport) or {}), **SERVICE_SESSION_DEFAULTS}
    return zenoh_config_from_args(args, defaults)


def _cmd_run(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    conf = run_config(args, settings)
    from zenoh_perception.service.opencv_pool import quiet_opencv_pool  # noqa: PLC0415

    quiet_opencv_pool()  # before the service's imports load OpenCV
    from zenoh_perception.service import node  # noqa: PLC0415

    return node.run(conf, settings, stop_on_signals())


def _cmd_echo(args: argparse.Namespace) -> int:
    from zenoh_perception.cli import echo  # noqa: PLC0415

    return echo.main(
        zenoh_config_from_args(args, _session_defaults(args.ros_transport)),
        tag_key=check_key("--tag-key", args.tag_key, concrete=False),
        record_key=check_key("--record-key", args.record_key, concrete=False),
        ros_package=args.ros_package,
        ros=echo.RosGraph(
            RosTransportKind(args.ros_transport), args.ros_domain_id, args.ros_namespace
        ),
        records=not args.tags_only,
        as_json=args.json,
        count=args.count,
        timeout=args.timeout,
        stop=stop_on_signals(),
    )


def _cmd_status(args: argparse.Namespace) -> int:
    from zenoh_perception.cli import status  # noqa: PLC0415

    key = check_key("--status-key", args.status_key, concrete=False)
    conf = zenoh_config_from_args(args)
    return status.main(conf, key=key, timeout=args.timeout, lines=args.lines)


def _add_run(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "run",
        help="run the perception service",
        description="Subscribe camera frames, detect ArUco tags, publish tag + record per frame.",
    )
    add_zenoh_arguments(parser)
    add_settings_arguments(parser)
    parser.set_defaults(handler=_cmd_run, leaves_threads=True)


def _add_echo(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("echo", help="print decoded tags and records")
    add_zenoh_arguments(parser)
    parser.add_argument("--tag-key", default="tag", help="tag key (default: tag)")
    parser.add_argument(
        "--record-key", default="perception/tags", help="record key (default: perception/tags)"
    )
    parser.add_argument("--ros-package", default="mrover", help="ROS package of the tag type")
    parser.add_argument(
        "--ros-transport",
        choices=tuple(RosTransportKind),
        default=RosTransportKind.BRIDGE.value,
        help="bridge: the plain tag key; rmw_zenoh: the tag's rmw_zenoh key (default: bridge)",
    )
    parser.add_argument(
        "--ros-domain-id", type=int, default=0, help="rmw_zenoh: ROS_DOMAIN_ID (default 0)"
    )
    parser.add_argument(
        "--ros-namespace", default="", help="rmw_zenoh: the service's namespace (default '')"
    )
    parser.add_argument("--tags-only", action="store_true", help="do not print records")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--count",
        type=bounded_int(0, MAX_COUNT),
        default=0,
        help="exit after N lines (0: never)",
    )
    parser.add_argument(
        "--timeout",
        type=bounded_float(0.001, MAX_WAIT_S),
        default=None,
        help="exit after S seconds",
    )
    parser.set_defaults(handler=_cmd_echo, leaves_threads=True)


def _add_status(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "status",
        help="query running services' status (exit 1: none)",
        description="Prints one JSON array, an object per service that answered; with "
        "--lines, one object per line.",
    )
    add_zenoh_arguments(parser)
    parser.add_argument("--status-key", default="perception/status", help="status key")
    parser.add_argument("--lines", action="store_true", help="one JSON object per line")
    parser.add_argument(
        "--timeout",
        type=bounded_float(0.001, MAX_WAIT_S),
        default=2.0,
        help="seconds to wait (default 2)",
    )
    parser.set_defaults(handler=_cmd_status)


def _cmd_bridge_config(args: argparse.Namespace) -> int:
    from zenoh_perception.cli import bridge_config  # noqa: PLC0415

    settings = settings_from_args(args)
    return bridge_config.main(
        settings,
        source=str(args.settings) if args.settings else "the default settings",
        namespace=args.namespace,
        domain=settings.ros.ros_domain_id if args.domain is None else args.domain,
        output=args.output,
    )


def _add_bridge_config(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "bridge-config",
        help="write the zenoh-bridge-ros2dds config that routes the service's topics",
        description="Write the zenoh-bridge-ros2dds JSON5 that routes exactly the ROS topics "
        "of these settings (camera inputs ROS -> Zenoh, outputs Zenoh -> ROS).",
    )
    add_settings_arguments(parser)
    group = parser.add_argument_group("bridge")
    group.add_argument(
        "--namespace",
        default="/",
        help="the bridge's namespace: every key starts with it ('/rover1': rover1/tag is /tag)",
    )
    group.add_argument(
        "--domain",
        type=bounded_int(0, 232),
        default=None,
        help="the bridge's fallback DDS domain (default: ros_domain_id); ROS_DOMAIN_ID wins",
    )
    group.add_argument(
        "-o", "--output", type=Path, default=None, metavar="FILE", help="write FILE, not stdout"
    )
    parser.set_defaults(handler=_cmd_bridge_config)


def _cmd_view(args: argparse.Namespace) -> int:
    from zenoh_perception.cli import view  # noqa: PLC0415

    template = args.debug_image_key or load_settings(args.settings).outputs.debug_image_key
    check_key("--debug-image-key", template.replace("{stream}", "stream"), concrete=True)
    options = view.ViewOptions(
        key=view.view_key(template, args.stream),
        save=args.save,
        every_s=args.every,
        count=args.count,
        timeout_s=args.timeout,
    )
    return view.main(zenoh_config_from_args(args), options, stop_on_signals())


def _add_view(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "view",
        help="show the annotated debug image (or save it: --save)",
        description="Subscribe to the debug image (which makes the service draw it) and show it "
        "in a window; with --save, also write the latest JPEG to a file every --every seconds. "
        "Without a display (DISPLAY unset, opencv-python-headless) only --save works. "
        "q in the window quits.",
    )
    add_zenoh_arguments(parser)
    default_key = Settings().outputs.debug_image_key
    parser.add_argument(
        "--debug-image-key",
        default=None,
        help=f"debug image key, as run's (may hold {{stream}}) (default: the --settings "
        f"file's, else {default_key})",
    )
    parser.add_argument("-s", "--settings", type=Path, metavar="FILE", help="run's settings")
    parser.add_argument(
        "--stream", metavar="NAME", help="one camera's image (default: every stream's)"
    )
    parser.add_argument(
        "--save", type=Path, default=None, metavar="PATH", help="write the latest JPEG to PATH"
    )
    parser.add_argument(
        "--every",
        type=bounded_float(0.001, MAX_WAIT_S),
        default=1.0,
        metavar="S",
        help="with --save: at most one write every S seconds (default 1)",
    )
    parser.add_argument(
        "--count", type=bounded_int(0, MAX_COUNT), default=0, help="exit after N saves (0: never)"
    )
    parser.add_argument(
        "--timeout",
        type=bounded_float(0.001, MAX_WAIT_S),
        default=None,
        metavar="S",
        help="exit after S seconds",
    )
    parser.set_defaults(handler=_cmd_view, leaves_threads=True)


def _cmd_router(args: argparse.Namespace) -> int:
    from zenoh_perception.cli import router  # noqa: PLC0415

    conf = zenoh_config_from_args(args, {"mode": "router", **router.ROUTER_DEFAULTS})
    conf.insert_json5("mode", '"router"')  # a -c file's mode too: this command is a router
    return router.main(conf, stop_on_signals(), sys.stdout)


def _add_router(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "router",
        help="a Zenoh router (Zenoh's own, as zenohd) for machines without zenohd",
        description="Zenoh's router from zenoh-python: listens on -l (default tcp/[::]:7447), "
        "connects to the routers given with -e, prints its zid and where it listens, runs "
        "until SIGINT/SIGTERM (exit 0). Peers on one machine or one network need none.",
    )
    add_zenoh_arguments(parser, mode=False)
    parser.set_defaults(handler=_cmd_router, leaves_threads=True)


def _max_frame_bytes(text: str) -> int:
    try:
        value = int(text)
        check_bound("max_frame_bytes", value)
    except ValueError as err:
        msg = f"{text!r} is not an integer"
        raise argparse.ArgumentTypeError(msg) from err
    except SettingsError as err:
        raise argparse.ArgumentTypeError(str(err)) from err
    return value


def _cmd_replay(args: argparse.Namespace) -> int:
    from zenoh_perception.camera import replay  # noqa: PLC0415
    from zenoh_perception.camera.sources import open_source  # noqa: PLC0415

    conf = zenoh_config_from_args(args)  # a flag mistake is reported before any file is read
    # what the service would refuse, or a wildcard to publish on, is refused before anything
    if args.key is not None:  # None: the camera's default key for what it sends
        check_key("--key", args.key, concrete=True)
    replay.check_frame_id("--frame-id", args.frame_id)
    source = open_source(
        args.path,
        topic=args.topic,
        image_rate_hz=args.rate if args.rate is not None else DEFAULT_RATE_HZ,
        frame_id=args.frame_id,
        max_frame_bytes=args.max_frame_bytes,
    )
    options = replay.options_from_args(args, stderr_is_tty=sys.stderr.isatty())
    return replay.main(conf, source, options, stop_on_signals())


def _add_replay(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Add the ``replay`` subcommand to the CLI."""
    parser = sub.add_parser(
        "replay",
        help="publish a rosbag2, a video or a folder of images as camera frames",
        description=(
            "Publish frames into Zenoh as a camera would. A rosbag2 (folder, .mcap or .db3) "
            "sends the original sensor_msgs/Image CDR of one topic unchanged (as "
            "zenoh-bridge-ros2dds does); a video or a folder of images (sorted by name) sends "
            "raw BGRA with the msgpack attachment. Waits for a subscriber on the key first."
        ),
    )
    parser.add_argument(
        "path",
        type=Path,
        metavar="PATH",
        help="rosbag2 folder, .mcap / .db3 file, video file, image folder or image file",
    )
    parser.add_argument(
        "--key",
        default=None,
        help=f"key to publish frames on (default: {DEFAULT_KEY}, with --compressed "
        f"{DEFAULT_COMPRESSED_KEY})",
    )
    parser.add_argument(
        "--compressed",
        choices=("jpeg", "png"),
        default=None,
        help="publish sensor_msgs/CompressedImage CDR of this codec, as image_transport's "
        "compressed plugin does (default: uncompressed frames)",
    )
    parser.add_argument(
        "--topic",
        default=None,
        help="bag topic to replay (default: the only sensor_msgs/msg/Image topic, else "
        "/zed/left/image)",
    )
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument(
        "--rate",
        type=bounded_float(MIN_RATE_HZ, MAX_RATE_HZ),
        default=None,
        metavar="HZ",
        help="send at HZ frames per second (default: the recorded rate: bag times, video FPS; "
        f"images {DEFAULT_RATE_HZ:g} Hz)",
    )
    pace.add_argument("--as-fast-as-possible", action="store_true", help="send without pacing")
    parser.add_argument("--loop", action="store_true", help="start over at the end")
    parser.add_argument(
        "--limit",
        type=bounded_int(0, MAX_COUNT),
        default=0,
        metavar="N",
        help="stop after N frames in total (default 0: no limit)",
    )
    parser.add_argument(
        "--frame-id",
        default=DEFAULT_FRAME_ID,
        help=f"frame_id of video / image frames (default: {DEFAULT_FRAME_ID}; bags keep theirs)",
    )
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: only when stderr is a terminal)",
    )
    parser.add_argument(
        "--shm",
        action="store_true",
        help="put frames from a Zenoh shared-memory buffer, as a camera on the service's "
        "machine would (no copy on put; plain puts, with a warning, where shared memory is "
        "unavailable) (default: off)",
    )
    parser.add_argument(
        "--max-frame-bytes",
        type=_max_frame_bytes,
        default=Settings().limits.max_frame_bytes,
        metavar="N",
        help="largest frame payload sent, bytes: a larger frame stops the replay (exit 2); "
        "match the service's max_frame_bytes (default: %(default)s)",
    )
    parser.add_argument(
        "--wait-for-subscriber",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="wait until the key has a subscriber before sending (default: on)",
    )
    parser.add_argument(
        "--subscriber-timeout",
        type=bounded_float(0.001, MAX_WAIT_S),
        default=None,
        metavar="S",
        help="give up (exit 2) when no subscriber appears within S seconds (default: wait)",
    )
    add_zenoh_arguments(parser)
    parser.set_defaults(handler=_cmd_replay, leaves_threads=True)


def _cmd_probe(args: argparse.Namespace) -> int:
    from zenoh_perception.cli import probe  # noqa: PLC0415

    return probe.main(args.paths, max_frames=args.max_frames, topic=args.topic, as_json=args.json)


def _add_probe(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "probe",
        help="which dictionary are these markers? (photos, videos, image folders, bags)",
        description="Read the pictures with every OpenCV dictionary family, as they are and "
        "mirrored, and print per file the families and ids found, how often and how large, and "
        "the run flag to use. Exit code 1 when nothing was found in some file.",
    )
    parser.add_argument(
        "paths",
        type=Path,
        nargs="+",
        metavar="PATH",
        help="photo, video, folder of images, rosbag2 folder or .mcap/.db3 file",
    )
    parser.add_argument(
        "--max-frames",
        type=bounded_int(1, 100_000),
        default=300,
        metavar="N",
        help="frames read per file at most, spread over a longer one (default 300)",
    )
    parser.add_argument("--topic", default=None, help="bag topic (default: its Image topic)")
    parser.add_argument("--json", action="store_true", help="one JSON object per file")
    parser.set_defaults(handler=_cmd_probe)


#: Each entry adds one subcommand whose parser sets ``handler`` (a function of the namespace
#: returning the exit code), and ``leaves_threads`` when the command may return while threads
#: of its process are still inside OpenCV or Zenoh (cli/main.py then ends the process through
#: service/signals.py's ``leave``).
COMMANDS: tuple[Callable[[argparse._SubParsersAction[argparse.ArgumentParser]], None], ...] = (
    _add_run,
    add_demo,
    _add_echo,
    _add_status,
    _add_replay,
    _add_probe,
    add_bench,
    _add_view,
    _add_bridge_config,
    _add_router,
)
