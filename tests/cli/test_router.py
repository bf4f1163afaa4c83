"""``router``: Zenoh's own router from the real CLI; clients that meet only through it talk,
it says where it listens, and SIGINT or SIGTERM end it with exit 0."""

from __future__ import annotations

import signal

import zenoh

from tests.helpers import (
    Collector,
    OutputLines,
    loopback_config,
    loopback_endpoint,
    run_cli,
    running_cli,
    sigterm_exit,
    wait_until,
)


def test_two_clients_meet_through_the_router_which_says_where_it_listens(endpoint: str) -> None:
    with running_cli("router", "-l", endpoint, "--no-multicast-scouting") as proc:
        lines = OutputLines(proc)
        listening = lines.wait_for("listening on")
        assert endpoint in listening
        assert "zid=" in listening
        client = loopback_config(mode="client", connect=[endpoint])
        with zenoh.open(client) as sender, zenoh.open(client) as receiver:
            got = Collector(receiver, "a/b")
            # the subscription reaches the sender through the router: put until one lands
            wait_until(lambda: sender.put("a/b", b"x") is None and not got.queue.empty())
            got.undeclare()
        code, _ = sigterm_exit(proc)
    assert code == 0


def test_sigint_ends_it_with_exit_0_and_a_taken_port_with_exit_2(endpoint: str) -> None:
    with running_cli("router", "-l", endpoint, "--no-multicast-scouting") as proc:
        OutputLines(proc).wait_for("listening on")
        taken = run_cli("router", "-l", endpoint, "--no-multicast-scouting", timeout=60)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0
    assert taken.returncode == 2
    assert len(taken.stderr.strip().splitlines()) == 1, taken.stderr


def test_a_router_connects_to_another() -> None:
    first, second = loopback_endpoint(), loopback_endpoint()
    with (
        running_cli("router", "-l", first, "--no-multicast-scouting") as a,
        running_cli("router", "-l", second, "-e", first, "--no-multicast-scouting") as b,
    ):
        OutputLines(a).wait_for("listening on")
        assert first in OutputLines(b).wait_for("connecting to")
        with (
            zenoh.open(loopback_config(mode="client", connect=[first])) as sender,
            zenoh.open(loopback_config(mode="client", connect=[second])) as receiver,
        ):
            got = Collector(receiver, "a/b")
            wait_until(lambda: sender.put("a/b", b"x") is None and not got.queue.empty())
            got.undeclare()
