"""The service's settings: one frozen dataclass, loaded from a TOML file, overridable by flags.

The documented file is ``config/perception.toml``; every field below is a key there and a flag
of ``zenoh-perception run`` (``tag_key`` -> ``--tag-key``). Zenoh's own configuration (mode,
endpoints, TLS, ...) is not here: it comes from the Zenoh flags and ``-c`` JSON5 file.

Validation (every failure is a :class:`SettingsError` naming the setting; the CLI exits 2):

- every number lies within its documented bounds (:data:`BOUNDS`);
- keys are Zenoh key expressions as written (no auto-canonisation); the inputs
  (``input_key``, ``camera_info_key``) may hold wildcards, every key the service publishes,
  serves or declares on must be concrete, and no output may intersect an input;
- an input may be a list of keys (a TOML array, or its flag given once per key): no key
  matched by two entries, each entry a stream name of its own, no more than ``max_streams``;
  with several streams (a wildcard or a list) the outputs hold ``{stream}``;
- ``ros_package`` is a valid ROS package name; ``ros_node_name`` and ``ros_namespace`` are
  valid ROS names, and with ``ros_transport = "rmw_zenoh"`` every key of a ROS topic is a
  relative ROS topic name;
- intrinsics, when given, are plausible (:func:`~zenoh_perception.tags.geometry.check_intrinsics`);
- the settings file is a regular UTF-8 file of at most :data:`MAX_SETTINGS_FILE_BYTES`.
"""

from __future__ import annotations

import argparse
import difflib
import math
import os
import re
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, Field, asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Final

import zenoh

from zenoh_perception.detect.types import DETECTORS, dictionary_names
from zenoh_perception.errors import IntrinsicsError, SettingsError, zenoh_error_text
from zenoh_perception.files import MAX_TEXT_FILE_BYTES, check_nesting, read_text_file
from zenoh_perception.sharing import GROUP_NAME
from zenoh_perception.tags.geometry import (
    FOCAL_PX_MAX,
    FOCAL_PX_MIN,
    MAX_DIMENSION,
    check_intrinsics,
)
from zenoh_perception.tags.selection import Metric, Policy
from zenoh_perception.wire.key_advice import (
    FOLLOWS_INPUT,
    Change,
    compressed_keys,
    refusal,
    stream_example,
    unknown_placeholders,
)
from zenoh_perception.wire.rmw_zenoh import (
    DOMAIN_ID_MAX,
    is_namespace,
    is_node_name,
    is_relative_topic,
)
from zenoh_perception.wire.ros_topics import ROS_TOPICS, Direction
from zenoh_perception.wire.stream_keys import (
    STREAM,
    Keys,
    StreamNames,
    any_stream_key,
    colliding_keys,
    has_wildcard,
    key_entries,
    output_key,
)

METRICS = tuple(Metric)
#: When detection runs in a child process (with a frame deadline): ``on_stall``, in the
#: service's process until a frame stalls past the deadline, then in the child for a while;
#: ``always``, every frame (each then costs a hand-off to another process, and a crash inside
#: OpenCV kills only the child).
DETECTOR_PROCESSES: Final = ("on_stall", "always")

#: Largest settings file read, bytes.
MAX_SETTINGS_FILE_BYTES: Final = MAX_TEXT_FILE_BYTES
#: Default largest frame payload: far below Zenoh's default message limit
#: (transport/link/rx/max_message_size, 1 GiB), above any camera frame up to 4K BGRA.
DEFAULT_MAX_FRAME_BYTES: Final = 64 << 20
#: How to let larger frames through, for the messages of every tool that refuses one.
FRAME_LIMITS_HINT: Final = (
    "raise max_frame_bytes (--max-frame-bytes) on the camera side and at the service alike, "
    "and beyond 1 GiB also Zenoh's transport/link/rx/max_message_size on every receiver "
    "(see docs/robustness.md)"
)
#: Most entries of ``tag_sizes``, and the largest id (the tag message's id is an int32).
MAX_TAG_SIZES: Final = 1024
MAX_TAG_ID: Final = 2**31 - 1
#: ROS 2 package names (REP 144): lower-case letters, digits and single underscores, starting
#: with a letter, at least two characters.
_ROS_PACKAGE: Final = re.compile(r"[a-z][a-z0-9]*(?:_[a-z0-9]+)*")

TagSizes = tuple[tuple[int, float], ...]


#: The ZED's left image, the camera the service reads unless told otherwise.
DEFAULT_INPUT_KEY: Final = "zed/left/image"


def _doc(text: str) -> dict[str, str]:
    return {"help": text}


@dataclass(frozen=True, slots=True)
class Settings:
    """Everything the perception service can be told (see ``config/perception.toml``)."""

    # Zenoh keys
    input_key: Keys = field(
        default=DEFAULT_INPUT_KEY,
        metadata=_doc(
            "key of raw / sensor_msgs/Image CDR frames (a flag per key for several cameras); "
            "'' = off (compressed only)"
        ),
    )
    compressed_input_key: Keys = field(
        default=FOLLOWS_INPUT,
        metadata=_doc(
            "key of sensor_msgs/CompressedImage CDR frames (JPEG, PNG; a flag per key for "
            "several cameras); default: each input_key entry + '/compressed'; '' = off"
        ),
    )
    tag_key: str = field(default="tag", metadata=_doc("key of the StarterProjectTag CDR output"))
    record_key: str = field(
        default="perception/tags", metadata=_doc("key of the msgpack record with every detection")
    )
    debug_image_key: str = field(
        default="perception/debug/image/compressed",
        metadata=_doc("key of the annotated JPEG (sensor_msgs/CompressedImage CDR)"),
    )
    detections_key: str = field(
        default="perception/detections",
        metadata=_doc("key of every detection as apriltag_msgs/AprilTagDetectionArray; '' = off"),
    )
    tf_key: str = field(
        default="tf", metadata=_doc("key of tf2_msgs/TFMessage, camera -> tag poses; '' = off")
    )
    tf_prefix: str = field(
        default="tag_", metadata=_doc("child frame of a tag's transform: <tf_prefix><id>")
    )
    status_key: str = field(default="perception/status", metadata=_doc("status queryable key"))
    liveliness_key: str = field(
        default="perception/alive", metadata=_doc("prefix of the service's liveliness token")
    )
    camera_info_key: Keys = field(
        default="",
        metadata=_doc(
            "key of sensor_msgs/CameraInfo CDR giving intrinsics (a flag per key for several "
            "cameras); '' = off"
        ),
    )
    share_group: str = field(
        default="",
        metadata=_doc(
            "divide the announced camera streams with the other instances of this "
            "group; '' = take every stream"
        ),
    )
    ros_package: str = field(
        default="mrover", metadata=_doc("ROS package of StarterProjectTag (type name only)")
    )
    # ROS 2 graph
    ros_transport: str = field(
        default="bridge",
        metadata=_doc("'bridge' (zenoh-bridge-ros2dds) or 'rmw_zenoh' (a ROS 2 node itself)"),
    )
    bridge_announce: bool = field(
        default=True,
        metadata=_doc("bridge: announce each ROS output to zenoh-bridge-ros2dds at once"),
    )
    ros_domain_id: int = field(default=0, metadata=_doc("rmw_zenoh: ROS_DOMAIN_ID of the graph"))
    ros_node_name: str = field(
        default="zenoh_perception", metadata=_doc("rmw_zenoh: the service's ROS node name")
    )
    ros_namespace: str = field(
        default="", metadata=_doc("rmw_zenoh: the node's namespace, e.g. '/rover'; '' = '/'")
    )
    # Detection
    dictionary: str = field(
        default="DICT_4X4_50",
        metadata=_doc("predefined ArUco dictionary, or several separated by commas"),
    )
    detector: str = field(
        default="opencv",
        metadata=_doc("'opencv' (OpenCV's detector, every frame) or 'tracking' (experimental)"),
    )
    full_scan_period: int = field(
        default=4,
        metadata=_doc("tracking: whole-frame scan at least every N frames (new tags within N)"),
    )
    second_look: bool = field(
        default=True,
        metadata=_doc(
            "look again for tags OpenCV's default read misses (small, blurred, a cell read "
            "wrong): frames up to 1000 px a side at 2x now and then, larger ones at the small "
            "quads it rejected, also where it found none; beside a tag over 32 px, after the tag"
        ),
    )
    coarse_first_read: bool = field(
        default=True,
        metadata=_doc(
            "near tags (previous frame's over 48 px): read the frame at half size first and "
            "publish the tag from it when nothing larger can have escaped; closest/area only"
        ),
    )
    opencv_threads: int = field(
        default=0, metadata=_doc("OpenCV worker threads; 0 = OpenCV's default")
    )
    min_tag_side_px: float = field(
        default=0.0,
        metadata=_doc("drop tags whose mean side is shorter than this, pixels; 0 = off"),
    )
    verify: bool = field(
        default=True,
        metadata=_doc("re-read each tag OpenCV reports and veto look-alikes (never adds one)"),
    )
    confirm_frames: int = field(
        default=1,
        metadata=_doc("report a tag once seen on N frames in a row, about in place; 1 = at once"),
    )
    refine_corners: bool = field(
        default=True,
        metadata=_doc("refine OpenCV's corners to sub-pixel by an edge fit along each side"),
    )
    # Limits and budget
    max_frame_bytes: int = field(
        default=DEFAULT_MAX_FRAME_BYTES,
        metadata=_doc("largest frame payload, bytes; larger ones are refused before any copy"),
    )
    max_frame_pixels: int = field(
        default=4096 * 4096,
        metadata=_doc("largest frame, pixels (width x height); larger ones are refused"),
    )
    frame_budget_ms: float = field(
        default=100.0,
        metadata=_doc("frames whose decode + convert + detect take longer are counted over budget"),
    )
    frame_deadline_ms: float = field(
        default=400.0,
        metadata=_doc("a detection running longer is abandoned (counted); 0 = no deadline"),
    )
    detector_process: str = field(
        default="on_stall",
        metadata=_doc("with a deadline, when detection runs in a child process: on_stall | always"),
    )
    # Streams (one per concrete key a wildcard input matches)
    max_streams: int = field(
        default=16,
        metadata=_doc("most streams served at once; frames of further keys are refused (counted)"),
    )
    stream_idle_s: float = field(
        default=60.0,
        metadata=_doc("a wildcard input's stream without a frame for this long is forgotten"),
    )
    workers: int = field(
        default=0,
        metadata=_doc("threads reading frames, each stream in one at a time; 0 = one per core"),
    )
    # Selection and closeness
    policy: str = field(default="closest", metadata=_doc("tag selection: closest | center"))
    metric: str = field(default="area", metadata=_doc("closeness metric: area | distance"))
    max_range_m: float = field(
        default=10.0, metadata=_doc("distance metric: range mapped to closeness 1")
    )
    # Pose (optional): intrinsics and physical tag size
    tag_size_m: float = field(
        default=0.0, metadata=_doc("black-border edge length of tags in metres; 0 = unknown")
    )
    tag_sizes: TagSizes = field(
        default=(), metadata=_doc("per-id tag sizes, e.g. '3=0.2,7=0.1' (TOML: a table)")
    )
    camera_fx: float = field(default=0.0, metadata=_doc("focal length x, pixels; 0 = unknown"))
    camera_fy: float = field(default=0.0, metadata=_doc("focal length y, pixels; 0 = unknown"))
    camera_cx: float = field(default=0.0, metadata=_doc("principal point x, pixels"))
    camera_cy: float = field(default=0.0, metadata=_doc("principal point y, pixels"))
    # Debug image
    debug_image: bool = field(
        default=True, metadata=_doc("publish the annotated image while someone subscribes")
    )
    debug_image_max_hz: float = field(default=10.0, metadata=_doc("debug image rate cap"))
    debug_jpeg_quality: int = field(default=80, metadata=_doc("debug image JPEG quality 1-100"))
    # Observability
    stats_interval_s: float = field(
        default=5.0, metadata=_doc("period of the info log line; 0 = off")
    )
    log_interval_s: float = field(
        default=5.0, metadata=_doc("at most one line per repeating event (and reason) per interval")
    )
    no_tag_hint_s: float = field(
        default=30.0, metadata=_doc("hint once when no frame had a tag for this long; 0 = off")
    )

    def __post_init__(self) -> None:
        for name in KEY_LISTS:  # a list as a tuple; a list of one entry is that entry
            object.__setattr__(self, name, _key_list(name, getattr(self, name)))
        if self.compressed_input_key == FOLLOWS_INPUT:  # image_transport's convention
            object.__setattr__(self, "compressed_input_key", _compressed_by_convention(self))
        _validate(self)
        # the dictionaries as OpenCV spells them, whatever case they were given in
        object.__setattr__(self, "dictionary", ", ".join(dictionary_names(self.dictionary)))

    def tag_size_for(self, tag_id: int) -> float:
        """Physical size of ``tag_id`` in metres (0.0 when unknown)."""
        for known_id, size in self.tag_sizes:
            if known_id == tag_id:
                return size
        return self.tag_size_m

    def entries(self, name: str) -> tuple[str, ...]:
        """The entries of input setting ``name`` (one of :data:`KEY_LISTS`); ``()`` when off."""
        return key_entries(getattr(self, name))

    @property
    def several(self) -> bool:
        """Whether the service may serve several streams: an input is a pattern or a list."""
        return any(StreamNames(getattr(self, n)).several for n in _FRAME_INPUTS)

    @property
    def has_intrinsics(self) -> bool:
        return self.camera_fx > 0.0 and self.camera_fy > 0.0

    def as_dict(self) -> dict[str, Any]:
        """Plain-data view (for the status reply and logs)."""
        data = asdict(self)
        data["tag_sizes"] = {str(k): v for k, v in self.tag_sizes}
        return data


@dataclass(frozen=True, slots=True)
class Bound:
    """The values a numeric setting accepts: [``low``, ``high``], and 0 when ``zero`` says
    what 0 means there (``off``, ``unknown``)."""

    low: float
    high: float
    zero: str | None = None
    text: str | None = None  # how the bounds read when ``high`` depends on the machine

    def admits(self, value: float) -> bool:
        # an int is compared as it is: math.isfinite of a 400-digit one overflows
        if isinstance(value, float) and not math.isfinite(value):
            return False
        return (self.zero is not None and value == 0) or self.low <= value <= self.high

    def describe(self) -> str:
        text = self.text or f"[{_number(self.low)}, {_number(self.high)}]"
        return text if self.zero is None else f"{text}, or 0 = {self.zero}"


def _number(value: float) -> str:
    """``value`` as written in the documentation: whole numbers without a decimal point."""
    return str(int(value)) if float(value).is_integer() else f"{value:g}"


def _cpu_count() -> int:
    return os.cpu_count() or 1


#: The bounds of every numeric setting (``config/perception.toml`` states them too).
BOUNDS: Final[Mapping[str, Bound]] = {
    "full_scan_period": Bound(1, 1000),
    "confirm_frames": Bound(1, 100),
    "opencv_threads": Bound(0, 4 * _cpu_count(), text="[0, 4 x CPU cores]"),
    "min_tag_side_px": Bound(0, MAX_DIMENSION),
    "max_frame_bytes": Bound(1024, 4 << 30),
    "max_frame_pixels": Bound(1, MAX_DIMENSION * MAX_DIMENSION),
    "frame_budget_ms": Bound(0.1, 60_000),
    "frame_deadline_ms": Bound(10, 600_000, zero="off"),
    "max_streams": Bound(1, 4096),
    "stream_idle_s": Bound(1, 86_400),
    "workers": Bound(0, 4 * _cpu_count(), zero="one per core", text="[1, 4 x CPU cores]"),
    "max_range_m": Bound(0.01, 10_000),
    "tag_size_m": Bound(0.001, 100, zero="unknown"),
    "camera_fx": Bound(FOCAL_PX_MIN, FOCAL_PX_MAX, zero="unknown"),
    "camera_fy": Bound(FOCAL_PX_MIN, FOCAL_PX_MAX, zero="unknown"),
    "camera_cx": Bound(0, MAX_DIMENSION),
    "camera_cy": Bound(0, MAX_DIMENSION),
    "debug_image_max_hz": Bound(0.01, 1000),
    "debug_jpeg_quality": Bound(1, 100),
    "stats_interval_s": Bound(0.1, 86_400, zero="off"),
    "log_interval_s": Bound(0.1, 86_400),
    "no_tag_hint_s": Bound(1, 86_400, zero="off"),
    "ros_domain_id": Bound(0, DOMAIN_ID_MAX),
}
#: Sizes in ``tag_sizes``, metres.
TAG_SIZE_BOUND: Final = Bound(0.001, 100)


def check_bound(name: str, value: float) -> None:
    """Raise :class:`SettingsError` unless ``value`` is within the bounds of setting ``name``."""
    bound = BOUNDS[name]
    if not bound.admits(value):
        msg = f"{name} must be in {bound.describe()}, not {value!r}"
        raise SettingsError(msg)


def check_ros_package(name: str) -> str:
    """``name`` when it is a valid ROS 2 package name (REP 144), else SettingsError."""
    if len(name) < 2 or not _ROS_PACKAGE.fullmatch(name):
        msg = (
            f"ros_package {name!r} is not a ROS package name (lower-case letters, digits and "
            "single underscores, starting with a letter, at least 2 characters)"
        )
        raise SettingsError(msg)
    return name


#: Keys the service subscribes to: key expressions (wildcards allowed), each setting one key
#: or a list of them.
KEY_LISTS: Final = ("input_key", "compressed_input_key", "camera_info_key")
#: The inputs of frames (each stream's).
_FRAME_INPUTS: Final = ("input_key", "compressed_input_key")
#: Keys the service publishes on or serves: concrete, never intersecting an input.
_OUTPUT_KEYS: Final = ("tag_key", "record_key", "debug_image_key", "status_key")
#: Outputs that "" turns off; when set, held to the same rules as the others.
_OPTIONAL_OUTPUT_KEYS: Final = ("detections_key", "tf_key")
#: Outputs that may hold ``{stream}`` (and, with a wildcard input, must: but for TF).
_STREAM_KEYS: Final = ("tag_key", "record_key", "debug_image_key", "detections_key", "tf_key")
#: Characters a ROS frame id may hold (tf2 refuses others; a leading '/' is deprecated).
_FRAME_PREFIX: Final = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_/.-]*")


def _key_list(name: str, value: object) -> Keys:
    """An input setting as kept: a string, or a tuple of two strings or more."""
    if isinstance(value, str):
        return value
    if not isinstance(value, tuple | list) or not all(isinstance(v, str) for v in value):
        msg = f"setting {name} must be a key or a list of keys, not {value!r}"
        raise SettingsError(msg)
    entries = tuple(str(v) for v in value)
    if len(entries) == 1:  # a list of one key is that key ('' = off, as a flag given once)
        return entries[0]
    if not all(entries):
        msg = f"{name} = {list(entries)!r}: a list holds one key or more, none empty ('' = off)"
        raise SettingsError(msg)
    return entries


def _shown(value: Keys) -> str:
    """An input setting as written in a message: one key, or the list."""
    return repr(value) if isinstance(value, str) else repr(list(value))


def _key_expr(name: str, value: str) -> zenoh.KeyExpr:
    try:
        return zenoh.KeyExpr(value)  # as written: no auto-canonisation
    except zenoh.ZError as err:
        msg = f"{name} = {value!r} is not a valid Zenoh key expression: {zenoh_error_text(err)}"
        raise SettingsError(msg) from err


def check_key(name: str, value: str, *, concrete: bool) -> str:
    """``value`` when it is a Zenoh key expression (without wildcards when ``concrete``: a
    key published on or served), for a command's key flag named ``name``.

    Raises:
        SettingsError: empty, a control character, not a key expression, or a wildcard in a
            concrete key.

    """
    if not value or any(ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F for c in value):
        msg = f"{name} = {value!r} must be a non-empty key without control characters"
        raise SettingsError(msg)
    _key_expr(name, value)
    if concrete and ("*" in value or "$" in value):
        msg = f"{name} = {value!r} must be a concrete key (no '*', '**' or '$*')"
        raise SettingsError(msg)
    return value


def _stream_template(name: str, value: str) -> str:
    """An output key with ``{stream}`` as a concrete key (to check it), refusing it where no
    stream is."""
    if STREAM not in value:
        return value
    if name not in _STREAM_KEYS:
        msg = f"{name} = {value!r}: only {', '.join(_STREAM_KEYS)} may hold {STREAM!r}"
        raise SettingsError(msg)
    return output_key(value, "stream")


def _any_stream(value: str) -> str:
    """An output key with ``{stream}`` as the key expression of every stream's key."""
    return any_stream_key(value)


def _validate_placeholders(settings: Settings) -> None:
    unknown = [
        f"{name} = {value!r} holds {', '.join(map(repr, found))}"
        for name in (*KEY_LISTS, *_OUTPUT_KEYS, *_OPTIONAL_OUTPUT_KEYS, "liveliness_key")
        for value in key_entries(getattr(settings, name))
        if (found := unknown_placeholders(value))
    ]
    if unknown:
        msg = (
            f"unknown placeholder: {'; '.join(unknown)}; the only placeholder is {STREAM!r} "
            "(each camera's name, in output keys)"
        )
        raise SettingsError(msg)


def _validate_keys(settings: Settings) -> None:
    _validate_placeholders(settings)
    for name in (*_OUTPUT_KEYS, "liveliness_key"):
        if not getattr(settings, name):
            msg = f"{name} must not be empty"
            raise SettingsError(msg)
    if not settings.input_key and not settings.compressed_input_key:
        msg = "input_key and compressed_input_key are both empty: the service needs an input"
        raise SettingsError(msg)
    for name in KEY_LISTS:
        if any(STREAM in entry for entry in settings.entries(name)):
            msg = f"{name} = {_shown(getattr(settings, name))}: an input holds no {STREAM!r}"
            raise SettingsError(msg)
    # each entry of each input: (setting, entry, key expression)
    inputs = [
        (name, entry, _key_expr(name, entry))
        for name in KEY_LISTS
        for entry in settings.entries(name)
    ]
    for name in KEY_LISTS:
        _validate_key_list(name, settings.entries(name))
    outputs: dict[str, zenoh.KeyExpr] = {}
    optional = tuple(name for name in _OPTIONAL_OUTPUT_KEYS if getattr(settings, name))
    for name in (*_OUTPUT_KEYS, *optional, "liveliness_key"):
        value = getattr(settings, name)
        concrete = _stream_template(name, value)
        _key_expr(name, concrete)
        if "*" in concrete:
            msg = (
                f"{name} = {value!r} must be a concrete key (no '*', '**' or '$*'): "
                "the service publishes or declares on it"
            )
            raise SettingsError(msg)
        outputs[name] = _key_expr(name, _any_stream(value))
    for out_name in (*_OUTPUT_KEYS, *optional):
        for in_name, entry, in_key in inputs:
            if outputs[out_name].intersects(in_key):
                msg = (
                    f"{out_name} = {getattr(settings, out_name)!r} intersects {in_name} = "
                    f"{entry!r}: the service would receive what it sends"
                )
                raise SettingsError(msg)
    for i, (first, first_entry, first_key) in enumerate(inputs):
        for second, second_entry, second_key in inputs[i + 1 :]:
            if first != second and first_key.intersects(second_key):
                msg = (
                    f"{second} = {second_entry!r} intersects {first} = "
                    f"{first_entry!r}: the two inputs would be mixed"
                )
                raise SettingsError(msg)
    seen: dict[str, str] = {}
    for name in (*_OUTPUT_KEYS, *optional):
        value = getattr(settings, name)
        if value in seen:
            msg = f"{name} and {seen[value]} are both {value!r}: each output needs its own key"
            raise SettingsError(msg)
        seen[value] = name

    several = next(
        (n for n in _FRAME_INPUTS if StreamNames(getattr(settings, n)).several),
        None,
    )
    if several is None:
        if len(settings.entries("camera_info_key")) > 1:
            msg = (
                f"camera_info_key = {_shown(settings.camera_info_key)} is a list while the "
                "input is one camera: give one key"
            )
            raise SettingsError(msg)
        return
    streams = f"{several} = {_shown(getattr(settings, several))} {_why_several(settings, several)}"
    changes: list[Change] = []
    # a concrete input beside several streams would be a stream named "" among the others
    for name in _FRAME_INPUTS:
        value = getattr(settings, name)
        if value and not StreamNames(value).several:
            why = "one concrete key beside several cameras: the same wildcards, a list, or ''"
            example = compressed_keys(settings.input_key) if name != several else ""
            changes.append(Change(name, value, why, example))
    # each stream answers on keys of its own; TF is one topic whose transforms each name
    # their camera's frame
    cameras = settings.entries(several)
    for name in (*_OUTPUT_KEYS, *optional):
        value = getattr(settings, name)
        if name in _STREAM_KEYS and name != "tf_key" and STREAM not in value:
            why = f"must hold {STREAM!r}: each camera needs keys of its own"
            changes.append(Change(name, value, why, stream_example(cameras, value)))
    if changes:
        raise SettingsError(refusal(streams, changes))


def _why_several(settings: Settings, name: str) -> str:
    value = getattr(settings, name)
    return "has wildcards" if isinstance(value, str) else "lists several keys"


def _validate_key_list(name: str, entries: tuple[str, ...]) -> None:
    """The entries of one input: no key matched by two of them, each concrete one a stream
    name of its own (the key less the chunks every entry starts and ends with)."""
    if len(entries) < 2:
        return
    twice = next((e for i, e in enumerate(entries) if e in entries[:i]), None)
    if twice is not None:
        msg = f"{name} = {_shown(entries)} gives {twice!r} twice: give each camera once"
        raise SettingsError(msg)
    keys = [_key_expr(name, entry) for entry in entries]
    for i, first in enumerate(entries):
        for j in range(i + 1, len(entries)):
            if keys[i].intersects(keys[j]):
                msg = (
                    f"{name}: the entries {first!r} and {entries[j]!r} overlap (a key both "
                    "match would be two streams): give each camera once"
                )
                raise SettingsError(msg)
    names = StreamNames(entries)
    for entry in entries:
        if not has_wildcard(entry) and not names.entry_name(entry):
            msg = (
                f"{name}: the entry {entry!r} names no stream once the chunks common to "
                f"every entry are left out (streams of {_shown(entries)}: the chunks where "
                "the entries differ)"
            )
            raise SettingsError(msg)


def _validate_numbers(settings: Settings) -> None:
    for name in BOUNDS:
        check_bound(name, getattr(settings, name))
    if len(settings.tag_sizes) > MAX_TAG_SIZES:
        msg = f"tag_sizes has {len(settings.tag_sizes)} entries, at most {MAX_TAG_SIZES}"
        raise SettingsError(msg)
    for tag_id, size in settings.tag_sizes:
        if not 0 <= tag_id <= MAX_TAG_ID or not TAG_SIZE_BOUND.admits(size):
            msg = (
                f"tag_sizes entry {tag_id}={size} needs an id in [0, {MAX_TAG_ID}] and a size "
                f"in {TAG_SIZE_BOUND.describe()} m"
            )
            raise SettingsError(msg)


def _validate_intrinsics(settings: Settings) -> None:
    fx, fy, cx, cy = settings.camera_fx, settings.camera_fy, settings.camera_cx, settings.camera_cy
    if fx == 0 and fy == 0:
        return
    try:
        check_intrinsics(fx, fy, cx, cy)
    except IntrinsicsError as err:
        msg = f"camera_fx, camera_fy, camera_cx, camera_cy: {err}"
        raise SettingsError(msg) from err


ROS_TRANSPORTS: Final = ("bridge", "rmw_zenoh")


def _validate_ros(settings: Settings) -> None:
    if settings.ros_transport not in ROS_TRANSPORTS:
        msg = (
            f"ros_transport must be one of {', '.join(ROS_TRANSPORTS)}, "
            f"not {settings.ros_transport!r}"
        )
        raise SettingsError(msg)
    if not is_node_name(settings.ros_node_name):
        msg = (
            f"ros_node_name {settings.ros_node_name!r} is not a ROS node name (letters, digits "
            "and underscores, not starting with a digit)"
        )
        raise SettingsError(msg)
    if not is_namespace(settings.ros_namespace):
        msg = (
            f"ros_namespace {settings.ros_namespace!r} is not a ROS namespace ('' or absolute, "
            "e.g. '/rover', tokens of letters, digits and underscores, no trailing '/')"
        )
        raise SettingsError(msg)
    if settings.ros_transport != "rmw_zenoh":
        return
    for topic in ROS_TOPICS:  # on an rmw_zenoh graph each of these keys is a ROS topic name
        setting = getattr(settings, topic.key_setting)
        for value in key_entries(setting):
            # a camera topic may be a pattern ('*/image'), an output its stream's
            # ('{stream}/tag')
            name = output_key(value, "stream")
            if topic.direction is Direction.SUBSCRIBE:
                name = "/".join("x" if c in ("*", "**") else c for c in name.split("/"))
            if not is_relative_topic(name):
                shown = "" if isinstance(setting, str) else f" (in {_shown(setting)})"
                msg = (
                    f"{topic.key_setting} = {value!r}{shown} is not a relative ROS topic name, "
                    "as ros_transport = 'rmw_zenoh' needs (tokens of letters, digits and "
                    "underscores separated by '/'; '*' chunks only in an input, '{stream}' "
                    "only in an output)"
                )
                raise SettingsError(msg)


def _validate_text(settings: Settings) -> None:
    """No control character in any text setting: keys and names end up in log lines."""
    for f in fields(Settings):
        value = getattr(settings, f.name)
        texts = (value,) if isinstance(value, str) else value if f.name in KEY_LISTS else ()
        for text in texts:
            if any(ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F for c in text):
                msg = f"{f.name} = {text!r} holds a control character"
                raise SettingsError(msg)


def _refuse_colliding_names(settings: Settings) -> None:
    """No two cameras an input matches may get one stream name (one mailbox, one detector
    state for both): a pattern of two ``**`` or more that allows it is refused."""
    for setting in _FRAME_INPUTS:
        for entry in settings.entries(setting):
            pair = colliding_keys(entry)
            if pair is not None:
                msg = (
                    f"{setting} = {entry!r} gives two cameras one stream name ({pair[0]!r} and "
                    f"{pair[1]!r} would be one stream): use one '**' at most, or list the "
                    "cameras"
                )
                raise SettingsError(msg)


def _validate_group(settings: Settings) -> None:
    _refuse_colliding_names(settings)
    name = settings.share_group
    if not name:
        return
    if not GROUP_NAME.fullmatch(name):
        msg = (
            f"share_group {name!r} is not a group name (1-64 letters, digits, '_', '.' or '-', "
            "not starting with '.' or '-')"
        )
        raise SettingsError(msg)


def _validate(settings: Settings) -> None:
    _validate_text(settings)
    _validate_keys(settings)
    _validate_group(settings)
    check_ros_package(settings.ros_package)
    _validate_ros(settings)
    if not _FRAME_PREFIX.fullmatch(settings.tf_prefix):
        msg = (
            f"tf_prefix {settings.tf_prefix!r} is not the start of a frame id (letters, digits, "
            "'_', '/', '.', '-', not starting with '/')"
        )
        raise SettingsError(msg)
    if settings.policy not in tuple(Policy):
        msg = f"policy must be one of {', '.join(Policy)}, not {settings.policy!r}"
        raise SettingsError(msg)
    if settings.metric not in METRICS:
        msg = f"metric must be one of {', '.join(METRICS)}, not {settings.metric!r}"
        raise SettingsError(msg)
    if settings.detector_process not in DETECTOR_PROCESSES:
        msg = (
            f"detector_process must be one of {', '.join(DETECTOR_PROCESSES)}, "
            f"not {settings.detector_process!r}"
        )
        raise SettingsError(msg)
    if settings.detector not in DETECTORS:
        msg = f"detector must be one of {', '.join(DETECTORS)}, not {settings.detector!r}"
        raise SettingsError(msg)
    dictionary_names(settings.dictionary)
    _validate_numbers(settings)
    for name in _FRAME_INPUTS:
        if len(settings.entries(name)) > settings.max_streams:
            msg = (
                f"{name} lists {len(settings.entries(name))} keys, more than max_streams = "
                f"{settings.max_streams}: raise max_streams"
            )
            raise SettingsError(msg)
    _validate_intrinsics(settings)
    if (
        settings.metric == "distance"
        and not (settings.has_intrinsics and (settings.tag_size_m > 0 or settings.tag_sizes))
        and not settings.camera_info_key
    ):
        msg = "metric 'distance' needs camera intrinsics (or camera_info_key) and a tag size"
        raise SettingsError(msg)


def _field_kind(f: Field[Any]) -> type:
    if f.name in KEY_LISTS:
        return list  # one key, or several
    hint = typing.get_type_hints(Settings)[f.name]
    if hint in (str, int, float, bool):
        return typing.cast(type, hint)
    return tuple  # tag sizes


#: A tag id as ``tag_sizes`` keys must write it: decimal, no sign, no leading zero or space.
_TAG_ID: Final = re.compile(r"0|[1-9][0-9]{0,9}")


def _parse_tag_sizes(value: object) -> TagSizes:
    """Accept a TOML table {"3" = 0.2} or a flag string "3=0.2,7=0.1"."""
    items: list[tuple[object, object]]
    if isinstance(value, Mapping):
        items = list(value.items())
    elif isinstance(value, str):
        items = []
        for part in filter(None, (p.strip() for p in value.split(","))):
            key, sep, size = part.partition("=")
            if not sep:
                msg = f"tag_sizes entry {part!r} is not ID=SIZE"
                raise SettingsError(msg)
            items.append((key.strip(), size.strip()))
    elif isinstance(value, tuple | list):
        items = []
        for pair in value:
            if not isinstance(pair, tuple | list) or len(pair) != 2:
                msg = f"tag_sizes entry {pair!r} is not an (id, size) pair"
                raise SettingsError(msg)
            items.append((pair[0], pair[1]))
    else:
        msg = f"tag_sizes must be a table of id = size, not {type(value).__name__}"
        raise SettingsError(msg)
    pairs: list[tuple[int, float]] = []
    seen: dict[int, object] = {}
    for raw_key, raw_size in items:
        # one spelling per id: "3", "03" and " 3" would otherwise all be id 3
        if not (isinstance(raw_key, int) and not isinstance(raw_key, bool)) and not (
            isinstance(raw_key, str) and _TAG_ID.fullmatch(raw_key)
        ):
            msg = f"tag_sizes id {raw_key!r} is not a tag id written plainly (0, 1, 2, ...)"
            raise SettingsError(msg)
        tag_id = int(raw_key)
        if tag_id in seen:
            msg = f"tag_sizes gives id {tag_id} twice ({seen[tag_id]!r} and {raw_key!r})"
            raise SettingsError(msg)
        seen[tag_id] = raw_key
        try:
            pairs.append((tag_id, float(str(raw_size))))
        except ValueError as err:
            msg = f"tag_sizes: {err}"
            raise SettingsError(msg) from err
    return tuple(sorted(pairs))


def _coerce(f: Field[Any], value: object) -> object:
    kind = _field_kind(f)
    if kind is tuple:
        return _parse_tag_sizes(value)
    if kind is list:
        return _key_list(f.name, value)
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            try:
                return float(value)
            except OverflowError as err:
                msg = f"setting {f.name} = {str(value)[:40]}... is too large for a number"
                raise SettingsError(msg) from err
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(value, str):
        return value
    msg = f"setting {f.name} must be {kind.__name__}, not {value!r}"
    raise SettingsError(msg)


def _compressed_by_convention(settings: Settings) -> Keys:
    """Each input_key entry plus ``/compressed``; with input_key off, the default camera's
    (``input_key = ""`` alone: compressed frames only, on the ZED's compressed key)."""
    return compressed_keys(settings.input_key or DEFAULT_INPUT_KEY)


def _follows_input(settings: Settings) -> bool:
    """Whether ``settings``' compressed input is its input_key's by convention."""
    return settings.compressed_input_key == _compressed_by_convention(settings)


def settings_from_mapping(
    values: Mapping[str, object], base: Settings | None = None, *, source: str = "settings"
) -> Settings:
    """``base`` (default: the defaults) with ``values`` applied; unknown keys are errors."""
    known = {f.name: f for f in fields(Settings)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        hints = [
            f"{name} (did you mean {close[0]}?)"
            if (close := difflib.get_close_matches(name, known, n=1))
            else name
            for name in unknown
        ]
        msg = f"{source}: unknown setting(s) {', '.join(hints)}"
        raise SettingsError(msg)
    base = base if base is not None else Settings()
    try:
        coerced = {name: _coerce(known[name], value) for name, value in values.items()}
        if _follows_input(base) and "compressed_input_key" not in coerced:
            coerced["compressed_input_key"] = FOLLOWS_INPUT  # follows the new input_key
        return replace(base, **coerced)  # type: ignore[arg-type]
    except SettingsError as err:
        msg = f"{source}: {err}"
        raise SettingsError(msg) from err


def _read_settings_file(path: Path) -> dict[str, Any]:
    """The TOML table of ``path``: a regular UTF-8 file of at most MAX_SETTINGS_FILE_BYTES,
    nested at most MAX_NESTING levels (tomllib recurses per level)."""
    text = read_text_file(path, "settings file", MAX_SETTINGS_FILE_BYTES)
    check_nesting(text, f"settings file {path}")
    try:
        return tomllib.loads(text)
    except ValueError as err:  # TOMLDecodeError, or an integer past Python's digit limit
        msg = f"cannot read settings file {path}: {err}"
        raise SettingsError(msg) from err
    except RecursionError as err:  # tomllib recurses once per nested array or table
        msg = f"cannot read settings file {path}: nested too deeply"
        raise SettingsError(msg) from err


def load_settings(path: Path | None, overrides: Mapping[str, object] | None = None) -> Settings:
    """Defaults, then the TOML file at ``path`` (if any), then ``overrides``.

    Raises:
        SettingsError: unreadable file (missing, not a regular file, over 1 MiB, not UTF-8),
            bad TOML, unknown key, wrong type or invalid value.

    """
    settings = Settings()
    if path is not None:
        data = _read_settings_file(path)
        settings = settings_from_mapping(data, settings, source=str(path))
    if overrides:
        settings = settings_from_mapping(overrides, settings, source="flags")
    return settings


def add_settings_arguments(parser: argparse.ArgumentParser) -> None:
    """One flag per setting (``--tag-key``...), defaulting to 'not given'."""
    group = parser.add_argument_group("perception settings (override the --settings file)")
    group.add_argument(
        "-s",
        "--settings",
        type=Path,
        default=None,
        metavar="FILE",
        help="TOML settings file (see config/perception.toml)",
    )
    for f in fields(Settings):
        flag = "--" + f.name.replace("_", "-")
        kind = _field_kind(f)
        default = f.default if f.default is not MISSING else None
        bound = BOUNDS.get(f.name)
        limits = f"; {bound.describe()}" if bound is not None else ""
        help_text = f"{f.metadata.get('help', '')}{limits} (default: {default!r})"
        if kind is bool:
            group.add_argument(
                flag,
                dest=f.name,
                action=argparse.BooleanOptionalAction,
                default=None,
                help=help_text,
            )
        elif kind is list:  # given several times: a list
            group.add_argument(
                flag,
                dest=f.name,
                action="append",
                default=None,
                metavar=f.name.upper(),
                help=help_text,
            )
        else:
            group.add_argument(
                flag,
                dest=f.name,
                type=str if kind is tuple else kind,
                default=None,
                metavar=f.name.upper(),
                help=help_text,
            )


def settings_from_args(args: argparse.Namespace) -> Settings:
    """Settings from ``--settings FILE`` plus every per-setting flag that was given."""
    overrides = {
        f.name: getattr(args, f.name)
        for f in fields(Settings)
        if getattr(args, f.name, None) is not None
    }
    path: Path | None = getattr(args, "settings", None)
    return load_settings(path, overrides)


def setting_names() -> Sequence[str]:
    return [f.name for f in fields(Settings)]


__all__ = [
    "BOUNDS",
    "DETECTORS",
    "FRAME_LIMITS_HINT",
    "METRICS",
    "Bound",
    "Settings",
    "add_settings_arguments",
    "check_bound",
    "check_key",
    "check_ros_package",
    "load_settings",
    "setting_names",
    "settings_from_args",
    "settings_from_mapping",
]
