"""The ``zenoh-perception`` command line: parses arguments and calls the matching ``main``."""

from __future__ import annotations

import argparse
import difflib
import os
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn

import zenoh

from zenoh_perception import __version__
from zenoh_perception.cli.commands import COMMANDS
from zenoh_perception.errors import PerceptionError
from zenoh_perception.service.logs import configure_logging
from zenoh_perception.service.signals import leave

Handler = Callable[[argparse.Namespace], int]


class Parser(argparse.ArgumentParser):
    """argparse that names the closest flag when one is mistyped, and shows the usage of the
    subcommand the flag was given to."""

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:
            # argparse hands a subcommand's unknown flags up to the top-level parser, which
            # would print its own usage: the subcommand's is the one that helps
            command = getattr(parsed, "command", None)
            target = _subcommands(self).get(command, self) if command else self
            target.error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed

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
                # the suggestion is what helps: said first, without the usage dump before it
                self.exit(2, f"{self.prog}: error: {'; '.join(hints)} ({message}; see --help)\n")
        super().error(message)


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse offers no public view of them
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


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
    sub: argparse._SubParsersAction[argparse.ArgumentParser] = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=Parser
    )
    for add in COMMANDS:
        add(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line ``argv``; its exit code.

    Without ``argv`` (the installed ``zenoh-perception``, ``python -m zenoh_perception``) the
    process's own command line runs, and a command that may leave threads inside OpenCV or
    Zenoh when it returns (``run``, ``demo``, ``echo``, ``replay``, ``view``) ends the process
    with its exit code through :func:`~zenoh_perception.service.signals.leave` rather than
    let the interpreter finalize under them.
    """
    args = build_parser().parse_args(argv)
    code = _run(args)
    if argv is None and getattr(args, "leaves_threads", False):
        leave(code)
    return code


def _run(args: argparse.Namespace) -> int:
    configure_logging(args.log_level)
    if not sys.stderr.isatty():
        # Zenoh's log (Rust's tracing) colours its lines unless NO_COLOR is set: a log file
        # or a journal would get raw ANSI codes.
        os.environ.setdefault("NO_COLOR", "1")
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
