"""The bridge config for each set-up, held to the bridge's own rules (zenoh-plugin-ros2dds 1.10.0,
commit 63e9d614cdf0f64c208d79a058c90db96f7b50ce): ``src/config.rs`` compiles each ``allow``
entry as ``^entry$`` and joins them with ``|`` (Rust ``Regex::is_match`` on the plain ROS name),
``src/ros2_utils.rs`` maps ``/a/b`` onto the key ``<namespace>/a/b``. Both directions: every key
the service uses is admitted, and every admitted name is a key the service uses (Zenoh's own
matching decides)."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache

import json5
import pytest
import zenoh
from hypothesis import given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st

from zenoh_perception.errors import SettingsError
from zenoh_perception.settings import Settings, load_settings
from zenoh_perception.wire.bridge_config import (
    BridgeRoutes,
    bridge_routes,
    key_regex,
    render,
    stream_name_patterns,
)
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction
from zenoh_perception.wire.stream_keys import Keys, StreamNames, key_entries, output_key

OUTPUTS = ("tag_key", "debug_image_key", "detections_key", "tf_key")


def _outputs(prefix: str) -> dict[str, object]:
    return {
        "tag_key": f"{prefix}/{{stream}}/tag",
        "record_key": f"{prefix}/{{stream}}/perception/tags",
        "debug_image_key": f"{prefix}/{{stream}}/perception/debug/image/compressed",
        "detections_key": f"{prefix}/{{stream}}/perception/detections",
    }


@dataclass(frozen=True)
class Setup:
    """One set-up: settings overrides, the bridge namespace, camera keys the service serves
    (with their stream names computed by the service's own rules) and ROS names it must
    not get."""

    overrides: Mapping[str, object]
    namespace: str
    cameras: Sequence[str]
    refused: Sequence[str]


SETUPS = {
    "one camera": Setup(
        {},
        "/",
        ["zed/left/image", "zed/left/image/compressed"],
        ["/zed/right/image", "/zed/left/image/x", "/rover/tag", "/tag/x", "/rosout"],
    ),
    "several by pattern": Setup(
        {"input_key": "rover/*/image", "compressed_input_key": "", **_outputs("rover")},
        "/",
        ["rover/front/image", "rover/rear/image", "rover/x_1/image"],
        ["/rover/image", "/rover/a/b/image", "/rover/tag", "/rover/a/b/tag", "/zed/left/image"],
    ),
    "several by list": Setup(
        {
            "input_key": ["cams/front/image", "cams/rear/image"],
            "compressed_input_key": "",
            **_outputs("cams"),
        },
        "/",
        ["cams/front/image", "cams/rear/image"],
        ["/cams/side/image", "/cams/side/tag", "/cams/front/image/compressed", "/cams/tag"],
    ),
    "a namespace": Setup(
        {
            "input_key": "rover1/zed/left/image",
            "compressed_input_key": "rover1/zed/left/image/compressed",
            "tag_key": "rover1/tag",
            "record_key": "rover1/perception/tags",
            "debug_image_key": "rover1/perception/debug/image/compressed",
            "detections_key": "rover1/perception/detections",
            "tf_key": "rover1/tf",
            "camera_info_key": "rover1/zed/left/camera_info",
        },
        "/rover1",
        ["rover1/zed/left/image", "rover1/zed/left/image/compressed"],
        ["/rover1/tag", "/rover1/zed/left/image", "/zed/right/image"],
    ),
    "depths by **": Setup(
        {"input_key": "bots/**/image", "compressed_input_key": "", **_outputs("bots")},
        "/",
        ["bots/image", "bots/a/image", "bots/a/b/image"],
        ["/other/image", "/bots/a/tags", "/bots/a/image/x"],
    ),
    "partial chunk $*": Setup(
        {"input_key": "cam$*/image", "compressed_input_key": "", **_outputs("out")},
        "/",
        ["cam/image", "cam1/image", "cam_left/image"],
        ["/ca/image", "/x/cam1/image", "/out/x/cam1/tag"],
    ),
    "a list with a pattern": Setup(
        {
            "input_key": ["left/*/image", "right/image"],
            "compressed_input_key": "",
            **_outputs("out"),
        },
        "/",
        ["left/a/image", "left/b/image", "right/image"],
        ["/left/image", "/right/a/image", "/out/a/tag", "/out/other/tag"],
    ),
}


def _plugin_regex(entries: Sequence[str]) -> re.Pattern[str] | None:
    """``Allowance`` as the plugin builds it: each entry anchored, all joined with '|'; an
    empty list: nothing of that kind."""
    return re.compile("|".join(f"^{e}$" for e in entries)) if entries else None


def _admits(entries: Sequence[str], ros_name: str) -> bool:
    regex = _plugin_regex(entries)
    return regex is not None and regex.search(ros_name) is not None


def _ros_name(key: str, namespace: str) -> str:
    """The inverse of ``ros2_name_to_key_expr`` (``key_expr_to_ros2_name``)."""
    return "/" + key if namespace == "/" else key.removeprefix(namespace[1:])


def _key(ros_name: str, namespace: str) -> str:
    """``ros2_name_to_key_expr``."""
    return ros_name[1:] if namespace == "/" else f"{namespace[1:]}/{ros_name[1:]}"


@cache
def _settings_of(name: str) -> Settings:
    return load_settings(None, SETUPS[name].overrides)


def _settings(setup: Setup) -> Settings:
    return _settings_of(next(n for n, s in SETUPS.items() if s is setup))


def _routes(setup: Setup) -> BridgeRoutes:
    settings = _settings(setup)
    values = settings.topic_keys()
    return bridge_routes(values, ros_package="mrover", namespace=setup.namespace)


def _allow(setup: Setup) -> dict[str, list[str]]:
    return _allow_of(next(n for n, s in SETUPS.items() if s is setup))


@cache
def _allow_of(name: str) -> dict[str, list[str]]:
    """The ``allow`` section of the rendered file, read back as the bridge reads JSON5."""
    setup = SETUPS[name]
    text = render(_routes(setup), namespace=setup.namespace, source="test")
    allow: dict[str, list[str]] = json5.loads(text)["plugins"]["ros2dds"]["allow"]
    return allow


def _value(settings: Settings, name: str) -> Keys:
    """The key setting ``name`` (a ROS topic's)."""
    return settings.topic_keys()[name]


def _service_outputs(settings: Settings, camera: str) -> list[str]:
    """The output keys the service uses for the stream of the concrete key ``camera``."""
    for name in ("input_key", "compressed_input_key"):
        keys = _value(settings, name)
        stream = StreamNames(keys).name(camera) if key_entries(keys) else None
        if stream is not None:
            o = settings.outputs
            values = (o.tag_key, o.debug_image_key, o.detections_key, o.tf_key)  # OUTPUTS
            return [output_key(v, stream) for v in values if v]
    raise AssertionError(f"{camera} is no camera of these settings")


@pytest.mark.parametrize("name", SETUPS)
def test_every_key_the_service_uses_is_routed_its_way(name: str) -> None:
    setup = SETUPS[name]
    settings = _settings(setup)
    allow = _allow(setup)
    for camera in setup.cameras:
        ros_name = _ros_name(camera, setup.namespace)
        assert _admits(allow["publishers"], ros_name), ros_name
        assert not _admits(allow["subscribers"], ros_name), ros_name
        for output in _service_outputs(settings, camera):
            ros_name = _ros_name(output, setup.namespace)
            assert _admits(allow["subscribers"], ros_name), ros_name
            assert not _admits(allow["publishers"], ros_name), ros_name


@pytest.mark.parametrize("name", SETUPS)
def test_names_the_service_does_not_use_are_refused(name: str) -> None:
    setup = SETUPS[name]
    allow = _allow(setup)
    for ros_name in [*setup.refused, "/rosout", "/parameter_events", "tag", "/perception/status"]:
        for kind, entries in allow.items():
            assert not _admits(entries, ros_name), f"{kind} admits {ros_name}"


def test_camera_info_is_routed_to_zenoh() -> None:
    allow = _allow(SETUPS["a namespace"])
    assert _admits(allow["publishers"], "/zed/left/camera_info")
    assert not _admits(allow["subscribers"], "/zed/left/camera_info")


def _used_keys(settings: Settings, direction: Direction) -> list[zenoh.KeyExpr]:
    """The key expressions the service subscribes to (SUBSCRIBE) or publishes on, outputs
    with ``{stream}`` standing for any stream its inputs can name (Zenoh's own wildcards)."""
    names = [
        n
        for i in ("input_key", "compressed_input_key")
        if key_entries(_value(settings, i))
        for n in stream_name_patterns(_value(settings, i))
    ]
    exprs: list[zenoh.KeyExpr] = []
    for topic in ROS_TOPICS:
        if topic.direction is not direction:
            continue
        for entry in key_entries(_value(settings, topic.key_setting)):
            for name in names if "{stream}" in entry else [""]:
                exprs.append(zenoh.KeyExpr(output_key(entry, name)))
    return exprs


_TOKENS = st.sampled_from(
    [
        *("rover", "rover1", "bots", "cams", "cam", "cam1", "out", "left", "right", "front"),
        *("a", "zed", "image", "compressed", "tag", "perception", "debug", "detections", "tf"),
        "x_1",
    ]
)
_ROS_NAMES = st.lists(_TOKENS, min_size=1, max_size=6).map(lambda t: "/" + "/".join(t))


@cache
def _used_of(name: str, direction: Direction) -> list[zenoh.KeyExpr]:
    return _used_keys(_settings_of(name), direction)


@pytest.mark.parametrize("name", SETUPS)
@hypothesis_settings(max_examples=60)
@given(ros_name=_ROS_NAMES)
def test_an_admitted_name_is_a_key_the_service_uses(name: str, ros_name: str) -> None:
    setup = SETUPS[name]
    allow = _allow(setup)
    key = zenoh.KeyExpr(_key(ros_name, setup.namespace))
    for kind, direction in (
        ("publishers", Direction.SUBSCRIBE),
        ("subscribers", Direction.PUBLISH),
    ):
        used = any(expr.intersects(key) for expr in _used_of(name, direction))
        assert _admits(allow[kind], ros_name) == used, (kind, ros_name)


def test_the_default_routes() -> None:
    routes = _routes(SETUPS["one camera"])
    assert [r.regex for r in routes.publishers] == ["/zed/left/image", "/zed/left/image/compressed"]
    assert [r.regex for r in routes.subscribers] == [
        "/tag",
        "/perception/debug/image/compressed",
        "/perception/detections",
        "/tf",
    ]
    assert routes.subscribers[0].ros_type == "mrover/msg/StarterProjectTag"


@pytest.mark.parametrize(
    ("key", "namespace", "regex"),
    [
        ("rover/*/image", "/", "/rover/[^/]+/image"),
        ("rover/**/image", "/", "/rover(?:/[^/]+)*/image"),
        ("cam$*/image", "/", "/cam[^/]*/image"),
        ("rover1/tag", "/rover1", "/tag"),
        ("a/b/tag", "/a/b", "/tag"),
    ],
)
def test_key_regex(key: str, namespace: str, regex: str) -> None:
    assert key_regex("tag_key", key, namespace) == regex


@pytest.mark.parametrize(
    ("key", "namespace"),
    [
        ("tag", "/rover1"),  # not under the namespace
        ("rover1", "/rover1"),  # nothing left once it is removed
        ("rover10/tag", "/rover1"),
        ("perception-tags", "/"),  # '-' is no part of a ROS name
        ("1tag", "/"),
        ("a/b.c", "/"),
    ],
)
def test_keys_the_bridge_cannot_route_are_refused_naming_the_setting(
    key: str, namespace: str
) -> None:
    with pytest.raises(SettingsError, match="tag_key"):
        key_regex("tag_key", key, namespace)


@pytest.mark.parametrize("namespace", ["", "rover", "/rover/", "/1x", "/a__b"])
def test_bad_namespaces_are_refused(namespace: str) -> None:
    with pytest.raises(SettingsError, match="namespace"):
        bridge_routes({"input_key": "zed/left/image"}, ros_package="mrover", namespace=namespace)
