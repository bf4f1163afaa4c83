"""The sections of the settings: each a frozen dataclass whose field names are the flat keys
of ``config/perception.toml`` (and the flags), each field documented and, when a number,
bounded. A component takes the sections it uses; :class:`~.model.Settings` holds them all."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

from zenoh_perception.detect.types import DetectorKind
from zenoh_perception.errors import SettingsError
from zenoh_perception.settings.bounds import DEFAULT_MAX_FRAME_BYTES, Bound, cpu_count
from zenoh_perception.tags.geometry import FOCAL_PX_MAX, FOCAL_PX_MIN, MAX_DIMENSION
from zenoh_perception.tags.selection import Metric, Policy
from zenoh_perception.wire.key_advice import FOLLOWS_INPUT, compressed_keys
from zenoh_perception.wire.rmw_zenoh import DOMAIN_ID_MAX
from zenoh_perception.wire.stream_keys import Keys, StreamNames, key_entries

TagSizes = tuple[tuple[int, float], ...]

#: The ZED's left image, the camera the service reads unless told otherwise.
DEFAULT_INPUT_KEY: Final = "zed/left/image"


class DetectorProcess(StrEnum):
    """When detection runs in a child process (with a frame deadline): ``on_stall``, in the
    service's process until a frame stalls past the deadline, then in the child for a while;
    ``always``, every frame (each then costs a hand-off to another process, and a crash inside
    OpenCV kills only the child)."""

    ON_STALL = "on_stall"
    ALWAYS = "always"


class RosTransportKind(StrEnum):
    """How the service meets a ROS 2 graph: through zenoh-bridge-ros2dds, or as a ROS 2 node
    of its own on an rmw_zenoh graph."""

    BRIDGE = "bridge"
    RMW_ZENOH = "rmw_zenoh"


def _doc(text: str, bound: Bound | None = None) -> dict[str, object]:
    return {"help": text} if bound is None else {"help": text, "bound": bound}


def key_list(name: str, value: object) -> Keys:
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


@dataclass(frozen=True, slots=True)
class Inputs:
    """What the service subscribes to, and how many streams it keeps."""

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
    camera_info_key: Keys = field(
        default="",
        metadata=_doc(
            "key of sensor_msgs/CameraInfo CDR giving intrinsics (a flag per key for several "
            "cameras); '' = off"
        ),
    )
    # Streams (one per concrete key a wildcard input matches)
    max_streams: int = field(
        default=16,
        metadata=_doc(
            "most streams served at once; frames of further keys are refused (counted)",
            Bound(1, 4096),
        ),
    )
    stream_idle_s: float = field(
        default=60.0,
        metadata=_doc(
            "a wildcard input's stream without a frame for this long is forgotten",
            Bound(1, 86_400),
        ),
    )

    def __post_init__(self) -> None:
        # a list as a tuple; a list of one entry is that entry
        object.__setattr__(self, "input_key", key_list("input_key", self.input_key))
        compressed = key_list("compressed_input_key", self.compressed_input_key)
        if compressed == FOLLOWS_INPUT:  # image_transport's convention
            compressed = self.compressed_by_convention()
        object.__setattr__(self, "compressed_input_key", compressed)
        object.__setattr__(
            self, "camera_info_key", key_list("camera_info_key", self.camera_info_key)
        )

    def compressed_by_convention(self) -> Keys:
        """Each input_key entry plus ``/compressed``; with input_key off, the default camera's
        (``input_key = ""`` alone: compressed frames only, on the ZED's compressed key)."""
        return compressed_keys(self.input_key or DEFAULT_INPUT_KEY)

    @property
    def follows_input(self) -> bool:
        """Whether the compressed input is the input_key's by convention."""
        return self.compressed_input_key == self.compressed_by_convention()

    @property
    def frame_inputs(self) -> tuple[tuple[str, Keys], ...]:
        """The inputs of frames (each stream's), by setting name."""
        return (
            ("input_key", self.input_key),
            ("compressed_input_key", self.compressed_input_key),
        )

    @property
    def key_lists(self) -> tuple[tuple[str, Keys], ...]:
        """Every input: key expressions (wildcards allowed), each one key or a list."""
        return (*self.frame_inputs, ("camera_info_key", self.camera_info_key))

    @property
    def input_entries(self) -> tuple[str, ...]:
        """The entries of ``input_key``; ``()`` when off."""
        return key_entries(self.input_key)

    @property
    def camera_info_entries(self) -> tuple[str, ...]:
        return key_entries(self.camera_info_key)

    @property
    def several(self) -> bool:
        """Whether the service may serve several streams: an input is a pattern or a list."""
        return any(StreamNames(value).several for _, value in self.frame_inputs)


@dataclass(frozen=True, slots=True)
class Outputs:
    """The keys the service publishes on, serves or declares."""

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

    @property
    def always(self) -> tuple[tuple[str, str], ...]:
        """The keys the service always publishes on or serves, by setting name."""
        return (
            ("tag_key", self.tag_key),
            ("record_key", self.record_key),
            ("debug_image_key", self.debug_image_key),
            ("status_key", self.status_key),
        )

    @property
    def optional(self) -> tuple[tuple[str, str], ...]:
        """The outputs that '' turns off, by setting name."""
        return (("detections_key", self.detections_key), ("tf_key", self.tf_key))


@dataclass(frozen=True, slots=True)
class Group:
    """Sharing the streams with other instances."""

    share_group: str = field(
        default="",
        metadata=_doc(
            "divide the announced camera streams with the other instances of this "
            "group; '' = take every stream"
        ),
    )


@dataclass(frozen=True, slots=True)
class Ros:
    """How the service meets the ROS 2 graph."""

    ros_package: str = field(
        default="mrover", metadata=_doc("ROS package of StarterProjectTag (type name only)")
    )
    ros_transport: RosTransportKind = field(
        default=RosTransportKind.BRIDGE,
        metadata=_doc("'bridge' (zenoh-bridge-ros2dds) or 'rmw_zenoh' (a ROS 2 node itself)"),
    )
    bridge_announce: bool = field(
        default=True,
        metadata=_doc("bridge: announce each ROS output to zenoh-bridge-ros2dds at once"),
    )
    ros_domain_id: int = field(
        default=0,
        metadata=_doc("rmw_zenoh: ROS_DOMAIN_ID of the graph", Bound(0, DOMAIN_ID_MAX)),
    )
    ros_node_name: str = field(
        default="zenoh_perception", metadata=_doc("rmw_zenoh: the service's ROS node name")
    )
    ros_namespace: str = field(
        default="", metadata=_doc("rmw_zenoh: the node's namespace, e.g. '/rover'; '' = '/'")
    )


@dataclass(frozen=True, slots=True)
class DetectorSettings:
    """What finds the tags in a frame."""

    dictionary: str = field(
        default="DICT_4X4_50",
        metadata=_doc("predefined ArUco dictionary, or several separated by commas"),
    )
    detector: DetectorKind = field(
        default=DetectorKind.OPENCV,
        metadata=_doc("'opencv' (OpenCV's detector, every frame) or 'tracking' (experimental)"),
    )
    full_scan_period: int = field(
        default=4,
        metadata=_doc(
            "tracking: whole-frame scan at least every N frames (new tags within N)",
            Bound(1, 1000),
        ),
    )
    second_look: bool = field(
        default=True,
        metadata=_doc(
            "look again for tags OpenCV's default read misses (small, blurred, a cell read "
            "wrong): frames up to 1000 px a side at 2x now and then, larger ones at the small "
            "quads it rejected, also where it found none; beside a tag over 32 px, after the tag"
        ),
    )
    opencv_threads: int = field(
        default=0,
        metadata=_doc(
            "OpenCV worker threads; 0 = OpenCV's default",
            Bound(0, 4 * cpu_count(), text="[0, 4 x CPU cores]"),
        ),
    )
    min_tag_side_px: float = field(
        default=0.0,
        metadata=_doc(
            "drop tags whose mean side is shorter than this, pixels; 0 = off",
            Bound(0, MAX_DIMENSION),
        ),
    )
    verify: bool = field(
        default=True,
        metadata=_doc("re-read each tag OpenCV reports and veto look-alikes (never adds one)"),
    )
    confirm_frames: int = field(
        default=1,
        metadata=_doc(
            "report a tag once seen on N frames in a row, about in place; 1 = at once",
            Bound(1, 100),
        ),
    )
    refine_corners: bool = field(
        default=True,
        metadata=_doc("refine OpenCV's corners to sub-pixel by an edge fit along each side"),
    )


@dataclass(frozen=True, slots=True)
class Limits:
    """What a frame may cost: its size, its time, the threads that read it."""

    max_frame_bytes: int = field(
        default=DEFAULT_MAX_FRAME_BYTES,
        metadata=_doc(
            "largest frame payload, bytes; larger ones are refused before any copy",
            Bound(1024, 4 << 30),
        ),
    )
    max_frame_pixels: int = field(
        default=4096 * 4096,
        metadata=_doc(
            "largest frame, pixels (width x height); larger ones are refused",
            Bound(1, MAX_DIMENSION * MAX_DIMENSION),
        ),
    )
    frame_budget_ms: float = field(
        default=100.0,
        metadata=_doc(
            "frames whose decode + convert + detect take longer are counted over budget",
            Bound(0.1, 60_000),
        ),
    )
    frame_deadline_ms: float = field(
        default=400.0,
        metadata=_doc(
            "a detection running longer is abandoned (counted); 0 = no deadline",
            Bound(10, 600_000, zero="off"),
        ),
    )
    detector_process: DetectorProcess = field(
        default=DetectorProcess.ON_STALL,
        metadata=_doc("with a deadline, when detection runs in a child process: on_stall | always"),
    )
    workers: int = field(
        default=0,
        metadata=_doc(
            "threads reading frames, each stream in one at a time; 0 = one per core",
            Bound(0, 4 * cpu_count(), zero="one per core", text="[1, 4 x CPU cores]"),
        ),
    )


@dataclass(frozen=True, slots=True)
class Selection:
    """Which tag is answered, its closeness, and its pose (intrinsics and physical size)."""

    policy: Policy = field(default=Policy.CLOSEST, metadata=_doc("tag selection: closest | center"))
    metric: Metric = field(default=Metric.AREA, metadata=_doc("closeness metric: area | distance"))
    max_range_m: float = field(
        default=10.0,
        metadata=_doc("distance metric: range mapped to closeness 1", Bound(0.01, 10_000)),
    )
    # Pose (optional): intrinsics and physical tag size
    tag_size_m: float = field(
        default=0.0,
        metadata=_doc(
            "black-border edge length of tags in metres; 0 = unknown",
            Bound(0.001, 100, zero="unknown"),
        ),
    )
    tag_sizes: TagSizes = field(
        default=(), metadata=_doc("per-id tag sizes, e.g. '3=0.2,7=0.1' (TOML: a table)")
    )
    camera_fx: float = field(
        default=0.0,
        metadata=_doc(
            "focal length x, pixels; 0 = unknown", Bound(FOCAL_PX_MIN, FOCAL_PX_MAX, zero="unknown")
        ),
    )
    camera_fy: float = field(
        default=0.0,
        metadata=_doc(
            "focal length y, pixels; 0 = unknown", Bound(FOCAL_PX_MIN, FOCAL_PX_MAX, zero="unknown")
        ),
    )
    camera_cx: float = field(
        default=0.0, metadata=_doc("principal point x, pixels", Bound(0, MAX_DIMENSION))
    )
    camera_cy: float = field(
        default=0.0, metadata=_doc("principal point y, pixels", Bound(0, MAX_DIMENSION))
    )

    def tag_size_for(self, tag_id: int) -> float:
        """Physical size of ``tag_id`` in metres (0.0 when unknown)."""
        for known_id, size in self.tag_sizes:
            if known_id == tag_id:
                return size
        return self.tag_size_m

    @property
    def has_intrinsics(self) -> bool:
        return self.camera_fx > 0.0 and self.camera_fy > 0.0


@dataclass(frozen=True, slots=True)
class DebugImage:
    """The annotated image."""

    debug_image: bool = field(
        default=True, metadata=_doc("publish the annotated image while someone subscribes")
    )
    debug_image_max_hz: float = field(
        default=10.0, metadata=_doc("debug image rate cap", Bound(0.01, 1000))
    )
    debug_jpeg_quality: int = field(
        default=80, metadata=_doc("debug image JPEG quality 1-100", Bound(1, 100))
    )


@dataclass(frozen=True, slots=True)
class Logs:
    """What the service says, and how often."""

    stats_interval_s: float = field(
        default=5.0,
        metadata=_doc("period of the info log line; 0 = off", Bound(0.1, 86_400, zero="off")),
    )
    log_interval_s: float = field(
        default=5.0,
        metadata=_doc(
            "at most one line per repeating event (and reason) per interval", Bound(0.1, 86_400)
        ),
    )
    no_tag_hint_s: float = field(
        default=30.0,
        metadata=_doc(
            "hint once when no frame had a tag for this long; 0 = off",
            Bound(1, 86_400, zero="off"),
        ),
    )


def topic_keys(inputs: Inputs, outputs: Outputs) -> dict[str, Keys]:
    """The key of each ROS topic (:data:`~zenoh_perception.wire.ros_topics.ROS_TOPICS`), by
    the name of the setting that holds it."""
    return {
        "input_key": inputs.input_key,
        "compressed_input_key": inputs.compressed_input_key,
        "camera_info_key": inputs.camera_info_key,
        "tag_key": outputs.tag_key,
        "debug_image_key": outputs.debug_image_key,
        "detections_key": outputs.detections_key,
        "tf_key": outputs.tf_key,
    }


#: Each section of :class:`~.model.Settings`: its attribute there and its class.
SECTIONS: Final[Mapping[str, type]] = {
    "inputs": Inputs,
    "outputs": Outputs,
    "group": Group,
    "ros": Ros,
    "detection": DetectorSettings,
    "limits": Limits,
    "selection": Selection,
    "debug": DebugImage,
    "logs": Logs,
}
