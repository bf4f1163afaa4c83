"""zenoh-bridge-ros2dds's liveliness tokens, against the bridge's own source:
eclipse-zenoh/zenoh-plugin-ros2dds, tag 1.10.0 (commit 63e9d614cdf0f64c208d79a058c90db96f7b50ce),
``zenoh-plugin-ros2dds/src/liveliness_mgt.rs`` (the ``kedefine!`` of every token, the QoS
chunk of ``qos_to_key_expr`` and its ``test_qos_key_expr``), ``src/ros2_utils.rs``
(``key_expr_to_ros2_name``, ``ros2_name_to_key_expr``) and ``src/lib.rs``
(``parse_announcement_event``)."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from zenoh_perception.errors import MessageDecodeError
from zenoh_perception.wire.bridge_liveliness import (
    ALL_TOKENS,
    BridgeQos,
    BridgeToken,
    BridgeTokenError,
    Durability,
    History,
    Kind,
    Reliability,
    parse_token,
    publisher_token,
    ros_name_to_key,
)

ZID = "5e7c1a0b9d2f4e6a8c1b3d5f7a9c0e2b"
TYPEHASH = "typehash=RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47;"


# test_qos_key_expr: the default QoS keyless and keyed, then one policy at a time
# (ReliabilityKind::RELIABLE = 1, DurabilityKind::TRANSIENT_LOCAL = 1, KEEP_LAST = 0 depth 3).
@pytest.mark.parametrize(
    ("qos", "text"),
    [
        (BridgeQos(), ":::"),
        (BridgeQos(keyless=False), "K:::"),
        (BridgeQos(reliability=Reliability.RELIABLE), ":1::"),
        (BridgeQos(durability=Durability.TRANSIENT_LOCAL), "::1:"),
        (BridgeQos(history=History.KEEP_LAST, depth=3), ":::0,3"),
        (BridgeQos(reliability=Reliability.BEST_EFFORT), ":0::"),
        (BridgeQos(reliability=Reliability.RELIABLE, user_data=TYPEHASH), f":1:::{TYPEHASH}"),
    ],
)
def test_qos_chunk_as_the_bridge_writes_and_reads_it(qos: BridgeQos, text: str) -> None:
    assert qos.keyexpr() == text
    assert BridgeQos.parse(text) == qos


def test_publisher_token_has_the_bridges_shape() -> None:
    # ke_liveliness_pub: "@/${zenoh_id:*}/@ros2_lv/MP/${ke:*}/${typ:*}/${qos_ke:*}", the key
    # and the type with every '/' written '§'.
    qos = BridgeQos(
        reliability=Reliability.RELIABLE,
        durability=Durability.VOLATILE,
        history=History.KEEP_LAST,
        depth=10,
        user_data=TYPEHASH,
    )
    token = publisher_token(ZID, "rover/front/tag", "sensor_msgs/msg/Image", qos)
    assert token == (
        f"@/{ZID}/@ros2_lv/MP/rover§front§tag/sensor_msgs§msg§Image/:1:0:0,10:{TYPEHASH}"
    )
    parsed = parse_token(token)
    assert parsed == BridgeToken(
        Kind.PUBLISHER, ZID, "rover/front/tag", "sensor_msgs/msg/Image", qos
    )
    assert parsed.ros_name() == "/rover/front/tag"


@pytest.mark.parametrize("kind", [Kind.SERVICE_SERVER, Kind.SERVICE_CLIENT, Kind.ACTION_SERVER])
def test_service_and_action_tokens_have_no_qos(kind: Kind) -> None:
    # ke_liveliness_service_srv / _cli, ke_liveliness_action_srv / _cli: ".../<ke>/<typ>".
    token = BridgeToken(kind, ZID, "add_two_ints", "example_interfaces/srv/AddTwoInts")
    assert token.keyexpr() == (
        f"@/{ZID}/@ros2_lv/{kind.value}/add_two_ints/example_interfaces§srv§AddTwoInts"
    )
    assert parse_token(token.keyexpr()) == token


@pytest.mark.parametrize(
    ("key", "namespace", "ros_name"),
    [
        ("tag", "/", "/tag"),
        ("rover/tag", "/", "/rover/tag"),
        ("rover/tag", "/rover", "/tag"),
        ("other/tag", "/rover", "/other/tag"),
        # key_expr_to_ros2_name strips the namespace as plain text, not at a '/'.
        ("roverx/tag", "/rover", "x/tag"),
    ],
)
def test_ros_name_follows_key_expr_to_ros2_name(key: str, namespace: str, ros_name: str) -> None:
    token = BridgeToken(Kind.PUBLISHER, ZID, key, "std_msgs/msg/String", BridgeQos())
    assert token.ros_name(namespace) == ros_name


def test_ros_name_to_key_prefixes_the_namespace() -> None:
    assert ros_name_to_key("/tag") == "tag"
    assert ros_name_to_key("/tag", "/rover") == "rover/tag"


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        # Rust's integer FromStr takes a leading '+' (and i32 a '-').
        (":+1::", BridgeQos(reliability=Reliability.RELIABLE)),
        (":::1,-1", BridgeQos(history=History.KEEP_ALL, depth=-1)),
        # Any first field but '' means keyed.
        ("X:::", BridgeQos(keyless=False)),
        # An empty fifth field is no USER_DATA; fields after the fifth are ignored.
        ("::::", BridgeQos()),
        (f"::::{TYPEHASH}:more", BridgeQos(user_data=TYPEHASH)),
    ],
)
def test_qos_chunk_is_read_leniently_where_the_bridge_is(text: str, expected: BridgeQos) -> None:
    assert BridgeQos.parse(text) == expected


@pytest.mark.parametrize(
    "text",
    [
        "",
        "tag",
        "/tag",
        "tag/",
        "a//b",
        f"@/{ZID}/@ros2_lv",  # the bridge's own presence, no route
        f"@/{ZID}/@ros2_lv/MP",
        f"@/{ZID}/@ros2_lv/XX/tag/std_msgs§msg§String/:::",
        f"@/{ZID}/@other/MP/tag/std_msgs§msg§String/:::",
        f"@@/{ZID}/@ros2_lv/MP/tag/std_msgs§msg§String/:::",
        f"@/{ZID}/@ros2_lv/MP/tag/std_msgs§msg§String",  # no QoS
        f"@/{ZID}/@ros2_lv/MP/tag/std_msgs§msg§String/:::/x",
        f"@/{ZID}/@ros2_lv/SS/add/example_interfaces§srv§AddTwoInts/:::",
        "@/*/@ros2_lv/MP/tag/std_msgs§msg§String/:::",  # wild
        f"@/{ZID}/@ros2_lv/MP/a§§b/std_msgs§msg§String/:::",  # unescapes to a//b
        f"@/{ZID}/@ros2_lv/MP/§tag/std_msgs§msg§String/:::",
        f"@/{ZID}/@ros2_lv/MP/tag§/std_msgs§msg§String/:::",
        f"@/{ZID}/@ros2_lv/MP/tag/std_msgs§§String/:::",
        f"@/{ZID}/@ros2_lv/MP/t$ag/std_msgs§msg§String/:::",
    ],
)
def test_keys_that_are_not_tokens_are_refused(text: str) -> None:
    with pytest.raises(BridgeTokenError):
        parse_token(text)


@pytest.mark.parametrize(
    "qos",
    [
        "::",  # fewer than four fields
        ":2::",  # no ReliabilityKind 2: the bridge's From would panic
        "::4:",
        ":::2,1",
        ":::0",  # history without depth
        ":::0,",
        ":::,3",
        ":::0,x",
        ":::0,2147483648",
        ":::0,1,2",
        ":-1::",  # a u32
        ": 1::",
        ":1 ::",
        ":\u0661::",  # Arabic-Indic one: Python's int() would take it, Rust's does not
        ":1_0::",
        ":4294967297::",
    ],
)
def test_bad_qos_chunks_are_refused(qos: str) -> None:
    with pytest.raises(BridgeTokenError):
        parse_token(f"@/{ZID}/@ros2_lv/MP/tag/std_msgs§msg§String/{qos}")


@pytest.mark.parametrize(
    "build",
    [
        lambda: BridgeToken(Kind.PUBLISHER, ZID, "tag", "std_msgs/msg/String"),
        lambda: BridgeToken(Kind.SERVICE_SERVER, ZID, "add", "a/srv/B", BridgeQos()),
        lambda: BridgeToken(Kind.PUBLISHER, "a/b", "tag", "std_msgs/msg/String", BridgeQos()),
        lambda: BridgeToken(Kind.PUBLISHER, ZID, "/tag", "std_msgs/msg/String", BridgeQos()),
        lambda: BridgeToken(Kind.PUBLISHER, ZID, "a§b", "std_msgs/msg/String", BridgeQos()),
        lambda: BridgeToken(Kind.PUBLISHER, ZID, "rover/*", "std_msgs/msg/String", BridgeQos()),
        lambda: BridgeQos(history=History.KEEP_LAST),
        lambda: BridgeQos(depth=3),
        lambda: BridgeQos(history=History.KEEP_LAST, depth=2**31),
        lambda: BridgeQos(user_data=""),
        lambda: BridgeQos(user_data="a:b"),
        lambda: BridgeQos(user_data="a/b"),
    ],
)
def test_fields_that_cannot_make_a_token_are_refused(build: object) -> None:
    assert callable(build)
    with pytest.raises(BridgeTokenError):
        build()


def test_the_error_is_counted_like_other_network_input() -> None:
    assert issubclass(BridgeTokenError, MessageDecodeError)
    assert BridgeTokenError.reason == "bad_bridge_token"


_NAME = st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,8}", fullmatch=True)
_KEYS = st.lists(_NAME, min_size=1, max_size=4).map("/".join)
_TYPES = st.tuples(_NAME, st.sampled_from(["msg", "srv", "action"]), _NAME).map("/".join)
_QOS = st.builds(
    lambda keyless, reliability, durability, history, user_data: BridgeQos(
        keyless,
        reliability,
        durability,
        None if history is None else history[0],
        None if history is None else history[1],
        user_data,
    ),
    st.booleans(),
    st.none() | st.sampled_from(Reliability),
    st.none() | st.sampled_from(Durability),
    st.none() | st.tuples(st.sampled_from(History), st.integers(-(2**31), 2**31 - 1)),
    st.none() | st.from_regex(r"typehash=RIHS01_[0-9a-f]{64};", fullmatch=True),
)
_TOKENS = st.one_of(
    st.builds(
        BridgeToken,
        st.sampled_from([Kind.PUBLISHER, Kind.SUBSCRIBER]),
        st.from_regex(r"[0-9a-f]{1,32}", fullmatch=True),
        _KEYS,
        _TYPES,
        _QOS,
    ),
    st.builds(
        BridgeToken,
        st.sampled_from([k for k in Kind if not k.has_qos]),
        st.from_regex(r"[0-9a-f]{1,32}", fullmatch=True),
        _KEYS,
        _TYPES,
    ),
)


@given(_TOKENS)
def test_tokens_round_trip_and_are_canonical_zenoh_keys(token: BridgeToken) -> None:
    text = token.keyexpr()
    assert parse_token(text) == token
    key = zenoh.KeyExpr(text)
    assert str(key) == text
    assert zenoh.KeyExpr(ALL_TOKENS).includes(key)


# Pieces a token is made of, so random keys often get deep into the parser.
_PIECES = st.sampled_from(
    [
        *("@", "@ros2_lv", "MP", "MS", "SS", "AC", ZID, "tag", "§", "/", ":", ",", "K"),
        *("0", "1", "+", "-", "2147483648", "*", "$", "typehash=x;", " ", "\u0661", "\x00"),
    ]
)


@given(st.one_of(st.text(max_size=80), st.lists(_PIECES, max_size=30).map("".join)))
def test_random_keys_raise_nothing_but_the_typed_error(text: str) -> None:
    try:
        token = parse_token(text)
    except BridgeTokenError:
        return
    assert parse_token(token.keyexpr()) == token
