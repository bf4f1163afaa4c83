"""The ``zenoh-perception`` command line: parses arguments and calls the matching ``main``."""

from __future__ import annotations

import argparse
import difflib
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn

import zenoh

from zenoh_perception import __version__, demo, echo, replay, service, status
from zenoh_perception.bench import cli as bench_cli
from zenoh_perception.errors import PerceptionError, SettingsError
from zenoh_perception.logs import configure_logging
from zenoh_perception.settings import add_settings_arguments, settings_from_args
from zenoh_perception.signals import stop_on_signals
from zenoh_perception.zenoh_args import add_zenoh_arguments, zenoh_config_from_args

Handler = Callable[[argparse.Namespace], int]


def _cmd_run(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    conf = zenoh_config_from_args(args)
    return service.run(conf, settings, stop_on_signals())


def _cmd_echo(args: argparse.Namespace) -> int:
    return echo.main(
        zenoh_config_from_args(args),
        tag_key=args.tag_key,
        record_key=args.record_key,
        ros_package=args.ros_package,
        records=not args.tags_only,
        as_json=args.json,
        count=args.count,
        timeout=args.timeout,
        stop=stop_on_signals(),
    )


def _cmd_status(args: argparse.Namespace) -> int:
    return status.main(zenoh_config_from_args(args), key=args.status_key, timeout=args.timeout)


def _cmd_demo(args: argparse.Namespace) -> int:
    if args.fps <= 0:
        msg = "--fps must be positive"
        raise SettingsError(msg)
    return demo.main(
        zenoh_config_from_args(args),
        settings_from_args(args),
        resolution=args.resolution,
        fps=args.fps,
        cdr=args.format == "cdr",
        camera_only=args.camera_only,
        limit=args.limit,
        shm=args.shm,
        stop=stop_on_signals(),
    )


def _add_run(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "run",
        help="run the perception service",
        description="Subscribe camera frames, detect ArUco tags, publish tag + record per frame.",
    )
    add_zenoh_arguments(parser)
    add_settings_arguments(parser)
    parser.set_defaults(handler=_cmd_run)


def _add_demo(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser(
        "demo",
        help="synthetic camera + service + echo in one process (no camera needed)",
        description="A rover driving toward synthetic tags, the service, and its output.",
    )
    demo.add_demo_arguments(parser)
    add_zenoh_arguments(parser)
    add_settings_arguments(parser)
    parser.set_defaults(handler=_cmd_demo)


def _add_echo(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("echo", help="print decoded tags and records")
    add_zenoh_arguments(parser)
    parser.add_argument("--tag-key", default="tag", help="tag key (default: tag)")
    parser.add_argument(
        "--record-key", default="perception/tags", help="record key (default: perception/tags)"
    )
    parser.add_argument("--ros-package", default="mrover", help="ROS package of the tag type")
    parser.add_argument("--tags-only", action="store_true", help="do not print records")
    parser.add_argument("--json", action="store_true", help="one JSON object per line")
    parser.add_argument("--count", type=int, default=0, help="exit after N lines (0: never)")
    parser.add_argument("--timeout", type=float, default=None, help="exit after S seconds")
    parser.set_defaults(handler=_cmd_echo)


def _add_status(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = sub.add_parser("status", help="query a running service's status (exit 1: none)")
    add_zenoh_arguments(parser)
    parser.add_argument("--status-key", default="perception/status", help="status key")
    parser.add_argument("--timeout", type=float, default=2.0, help="seconds to wait (default 2)")
    parser.set_defaults(handler=_cmd_status)


# Each entry adds one subcommand whose parser sets ``handler`` (a function of the namespace
# returning the exit code). Commands living in their own module expose ``register(sub)``.
_COMMANDS: tuple[Callable[[argparse._SubParsersAction[argparse.ArgumentParser]], None], ...] = (
    _add_run,
    _add_demo,
    _add_echo,
    _add_status,
    replay.register,
    bench_cli.register,
)


class Parser(argparse.ArgumentParser):
    """argparse that names the closest flag (of any subcommand) when one is mistyped."""

    def error(self, message: str) -> NoReturn:
        prefix = "unrecognized arguments: "
        if message.startswith(prefix):
            known = sorted(_option_strings(self))
            hints = []
            for token in message.removeprefix(prefix).split():
                flag = token.split("=", 1)[0]
                close = difflib.get_close_matches(flag, known, n=1) if flag.startswith("-") else []
                if close:
                    hints.append(f"{flag}: did you mean {close[0]}?")
            if hints:
                message = f"{message} ({'; '.join(hints)})"
        super().error(message)


def _option_strings(parser: argparse.ArgumentParser) -> set[str]:
    """Every flag of ``parser`` and of its subcommands."""
    found: set[str] = set()
    for action in parser._actions:  # argparse offers no public view of them
        found.update(s for s in action.option_strings if s.startswith("--"))
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _option_strings(sub)
    return found


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="zenoh-perception",
        description="ArUco tag perception over Zenoh, ROS 2 compatible on the wire.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=("DEBUG", "INFO", "WARNING", "ERROR"),
        help="log level (default INFO); Zenoh's own log follows RUST_LOG",
    )
    # a mistyped flag of a subcommand is reported by this top-level parser
    sub = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=argparse.ArgumentParser
    )
    for add in _COMMANDS:
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_logging(args.log_level)
    zenoh.init_log_from_env_or("error")
    handler: Handler = args.handler
    try:
        return handler(args)
    except PerceptionError as err:
        print(f"zenoh-perception: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
