"""The checks of the settings beside the keys', each on the sections it reads, run when
Settings are made (``Settings.__post_init__`` runs them in order): every failure a
:class:`~zenoh_perception.errors.SettingsError` naming the setting (the CLI exits 2)."""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Final

from zenoh_perception.errors import IntrinsicsError, SettingsError
from zenoh_perception.settings.bounds import MAX_TAG_ID, MAX_TAG_SIZES, TAG_SIZE_BOUND
from zenoh_perception.settings.keys import refuse_colliding_names, shown
from zenoh_perception.settings.sections import Group, Inputs, Ros, RosTransportKind, Selection
from zenoh_perception.settings.table import BOUNDS, FLAT, check_bound, section_items
from zenoh_perception.sharing import GROUP_NAME
from zenoh_perception.tags.geometry import check_intrinsics
from zenoh_perception.tags.selection import Metric
from zenoh_perception.wire.rmw_zenoh import is_namespace, is_node_name, is_relative_topic
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction
from zenoh_perception.wire.stream_keys import Keys, key_entries, output_key

#: ROS 2 package names (REP 144): lower-case letters, digits and single underscores, starting
#: with a letter, at least two characters.
_ROS_PACKAGE: Final = re.compile(r"[a-z][a-z0-9]*(?:_[a-z0-9]+)*")
#: Characters a ROS frame id may hold (tf2 refuses others; a leading '/' is deprecated).
_FRAME_PREFIX: Final = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_/.-]*")


def check_ros_package(name: str) -> str:
    """``name`` when it is a valid ROS 2 package name (REP 144), else SettingsError."""
    if len(name) < 2 or not _ROS_PACKAGE.fullmatch(name):
        msg = (
            f"ros_package {name!r} is not a ROS package name (lower-case letters, digits and "
            "single underscores, starting with a letter, at least 2 characters)"
        )
        raise SettingsError(msg)
    return name


def validate_numbers(sections: Sequence[object], selection: Selection) -> None:
    for section in sections:
        for name, value in section_items(section):
            if name in BOUNDS:
                check_bound(name, value)
    tag_sizes = selection.tag_sizes
    if len(tag_sizes) > MAX_TAG_SIZES:
        msg = f"tag_sizes has {len(tag_sizes)} entries, at most {MAX_TAG_SIZES}"
        raise SettingsError(msg)
    for tag_id, size in tag_sizes:
        if not 0 <= tag_id <= MAX_TAG_ID or not TAG_SIZE_BOUND.admits(size):
            msg = (
                f"tag_sizes entry {tag_id}={size} needs an id in [0, {MAX_TAG_ID}] and a size "
                f"in {TAG_SIZE_BOUND.describe()} m"
            )
            raise SettingsError(msg)


def _validate_intrinsics(selection: Selection) -> None:
    s = selection
    fx, fy, cx, cy = s.camera_fx, s.camera_fy, s.camera_cx, s.camera_cy
    if fx == 0 and fy == 0:
        return
    try:
        check_intrinsics(fx, fy, cx, cy)
    except IntrinsicsError as err:
        msg = f"camera_fx, camera_fy, camera_cx, camera_cy: {err}"
        raise SettingsError(msg) from err


def validate_ros(ros: Ros, keys: dict[str, Keys]) -> None:
    """A ROS package, node name and namespace; on an rmw_zenoh graph ``keys`` (each ROS
    topic's, :func:`~.sections.topic_keys`) relative topic names."""
    check_ros_package(ros.ros_package)
    if not is_node_name(ros.ros_node_name):
        msg = (
            f"ros_node_name {ros.ros_node_name!r} is not a ROS node name (letters, digits "
            "and underscores, not starting with a digit)"
        )
        raise SettingsError(msg)
    if not is_namespace(ros.ros_namespace):
        msg = (
            f"ros_namespace {ros.ros_namespace!r} is not a ROS namespace ('' or absolute, "
            "e.g. '/rover', tokens of letters, digits and underscores, no trailing '/')"
        )
        raise SettingsError(msg)
    if ros.ros_transport is not RosTransportKind.RMW_ZENOH:
        return
    for topic in ROS_TOPICS:  # on an rmw_zenoh graph each of these keys is a ROS topic name
        setting = keys[topic.key_setting]
        for value in key_entries(setting):
            # a camera topic may be a pattern ('*/image'), an output its stream's
            # ('{stream}/tag')
            name = output_key(value, "stream")
            if topic.direction is Direction.SUBSCRIBE:
                name = "/".join("x" if c in ("*", "**") else c for c in name.split("/"))
            if not is_relative_topic(name):
                listed = "" if isinstance(setting, str) else f" (in {shown(setting)})"
                msg = (
                    f"{topic.key_setting} = {value!r}{listed} is not a relative ROS topic name, "
                    "as ros_transport = 'rmw_zenoh' needs (tokens of letters, digits and "
                    "underscores separated by '/'; '*' chunks only in an input, '{stream}' "
                    "only in an output)"
                )
                raise SettingsError(msg)


def validate_text(sections: Sequence[object]) -> None:
    """No control character in any text setting: keys and names end up in log lines."""
    for name, value in (item for section in sections for item in section_items(section)):
        texts = (value,) if isinstance(value, str) else value if FLAT[name].is_keys else ()
        for text in texts:
            if any(ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F for c in text):
                msg = f"{name} = {text!r} holds a control character"
                raise SettingsError(msg)


def validate_group(inputs: Inputs, group: Group) -> None:
    refuse_colliding_names(inputs)
    name = group.share_group
    if not name:
        return
    if not GROUP_NAME.fullmatch(name):
        msg = (
            f"share_group {name!r} is not a group name (1-64 letters, digits, '_', '.' or '-', "
            "not starting with '.' or '-')"
        )
        raise SettingsError(msg)


def validate_streams(inputs: Inputs) -> None:
    for name, value in inputs.frame_inputs:
        if len(key_entries(value)) > inputs.max_streams:
            msg = (
                f"{name} lists {len(key_entries(value))} keys, more than max_streams = "
                f"{inputs.max_streams}: raise max_streams"
            )
            raise SettingsError(msg)


def validate_tf_prefix(tf_prefix: str) -> None:
    if not _FRAME_PREFIX.fullmatch(tf_prefix):
        msg = (
            f"tf_prefix {tf_prefix!r} is not the start of a frame id (letters, digits, "
            "'_', '/', '.', '-', not starting with '/')"
        )
        raise SettingsError(msg)


def validate_selection(selection: Selection, inputs: Inputs) -> None:
    """Plausible intrinsics; the distance metric with what it needs."""
    _validate_intrinsics(selection)
    if (
        selection.metric is Metric.DISTANCE
        and not (selection.has_intrinsics and (selection.tag_size_m > 0 or selection.tag_sizes))
        and not inputs.camera_info_key
    ):
        msg = "metric 'distance' needs camera intrinsics (or camera_info_key) and a tag size"
        raise SettingsError(msg)
