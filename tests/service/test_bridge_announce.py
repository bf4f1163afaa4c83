"""Through the bridge the service announces each ROS output with zenoh-bridge-ros2dds's own
publisher token, so a bridge offers the topic to ROS, with its type, before any ROS node
subscribes. The tokens are those of the bridge's ``liveliness_mgt.rs`` (zenoh-plugin-ros2dds
1.10.0, commit 63e9d614cdf0f64c208d79a058c90db96f7b50ce): ``tests/wire/test_bridge_liveliness.py``
holds the format to it; here, what the running service declares."""

from __future__ import annotations

import queue
import time

import zenoh

from tests.helpers import WAIT_S, open_session
from zenoh_perception.service.node import PerceptionService
from zenoh_perception.settings import Settings
from zenoh_perception.wire.bridge_liveliness import (
    ALL_TOKENS,
    BridgeQos,
    BridgeToken,
    Durability,
    History,
    Kind,
    Reliability,
    parse_token,
)
from zenoh_perception.wire.messages import make_typestore
from zenoh_perception.wire.rmw_zenoh import type_hash

TAG_HASH = type_hash(make_typestore("mrover"), "mrover/msg/StarterProjectTag")
# sensor_msgs/msg/CompressedImage as ROS 2 Jazzy generates it (see tests/wire/test_rmw_zenoh.py)
COMPRESSED_HASH = "RIHS01_15640771531571185e2efc8a100baf923961a4d15d5569652e6cb6691e8e371a"


def _tokens(session: zenoh.Session) -> dict[str, str]:
    """The bridge tokens the session knows of, by route key (its own are known at once)."""
    found = {}
    for reply in session.liveliness().get(ALL_TOKENS, timeout=5.0):
        if reply.ok is not None:
            text = str(reply.ok.key_expr)
            found[parse_token(text).key] = text
    return found


def test_each_output_is_announced_as_the_bridge_announces_a_publisher() -> None:
    with (
        open_session() as session,
        PerceptionService(session, Settings.from_flat(stats_interval_s=0.0)),
    ):
        zid = str(session.zid())
        tokens = _tokens(session)
    assert set(tokens) == {
        "tag",
        "perception/debug/image/compressed",
        "perception/detections",
        "tf",
    }
    # ke_liveliness_pub with the tag's QoS: keyless, RELIABLE (1), VOLATILE (0), KEEP_LAST (0)
    # depth 10, and the type hash in USER_DATA as rmw_cyclonedds writes it.
    assert tokens["tag"] == (
        f"@/{zid}/@ros2_lv/MP/tag/mrover§msg§StarterProjectTag/:1:0:0,10:typehash={TAG_HASH};"
    )
    assert parse_token(tokens["perception/debug/image/compressed"]) == BridgeToken(
        Kind.PUBLISHER,
        zid,
        "perception/debug/image/compressed",
        "sensor_msgs/msg/CompressedImage",
        BridgeQos(
            reliability=Reliability.BEST_EFFORT,
            durability=Durability.VOLATILE,
            history=History.KEEP_LAST,
            depth=5,
            user_data=f"typehash={COMPRESSED_HASH};",
        ),
    )


def test_the_tokens_go_with_the_service() -> None:
    with open_session() as session:
        with PerceptionService(session, Settings.from_flat(stats_interval_s=0.0)):
            assert _tokens(session)
        assert _tokens(session) == {}


def test_no_token_when_announcing_is_off_or_on_an_rmw_zenoh_graph() -> None:
    for settings in (
        Settings.from_flat(stats_interval_s=0.0, bridge_announce=False),
        Settings.from_flat(stats_interval_s=0.0, ros_transport="rmw_zenoh"),
    ):
        with open_session() as session, PerceptionService(session, settings):
            assert _tokens(session) == {}


def test_a_bridge_elsewhere_sees_the_announcement(endpoint: str) -> None:
    # The bridge's liveliness subscriber on @/*/@ros2_lv/** is a querying one (lib.rs):
    # it gets the tokens alive when it starts and those declared after.
    seen: queue.Queue[str] = queue.Queue()
    with (
        open_session(listen=[endpoint]) as bridge,
        open_session(connect=[endpoint]) as session,
    ):
        subscriber = bridge.liveliness().declare_subscriber(
            ALL_TOKENS, lambda sample: seen.put(str(sample.key_expr)), history=True
        )
        with PerceptionService(session, Settings.from_flat(stats_interval_s=0.0)):
            deadline = time.monotonic() + WAIT_S
            keys = set()
            while "tag" not in keys:
                keys.add(parse_token(seen.get(timeout=deadline - time.monotonic())).key)
        subscriber.undeclare()
