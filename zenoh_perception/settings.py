"""The service's settings: one frozen dataclass, loaded from a TOML file, overridable by flags.

The documented file is ``config/perception.toml``; every field below is a key there and a flag
of ``zenoh-perception run`` (``tag_key`` -> ``--tag-key``). Zenoh's own configuration (mode,
endpoints, TLS, ...) is not here: it comes from the Zenoh flags and ``-c`` JSON5 file.
"""

from __future__ import annotations

import argparse
import math
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import MISSING, Field, asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from zenoh_perception.detect.types import DETECTORS, dictionary_name
from zenoh_perception.errors import SettingsError
from zenoh_perception.selection import Policy

METRICS = ("area", "distance")

TagSizes = tuple[tuple[int, float], ...]


def _doc(text: str) -> dict[str, str]:
    return {"help": text}


@dataclass(frozen=True, slots=True)
class Settings:
    """Everything the perception service can be told (see ``config/perception.toml``)."""

    # Zenoh keys
    input_key: str = field(default="zed/left/image", metadata=_doc("key of incoming frames"))
    tag_key: str = field(default="tag", metadata=_doc("key of the StarterProjectTag CDR output"))
    record_key: str = field(
        default="perception/tags", metadata=_doc("key of the msgpack record with every detection")
    )
    debug_image_key: str = field(
        default="perception/debug/image/compressed",
        metadata=_doc("key of the annotated JPEG (sensor_msgs/CompressedImage CDR)"),
    )
    status_key: str = field(default="perception/status", metadata=_doc("status queryable key"))
    liveliness_key: str = field(
        default="perception/alive", metadata=_doc("prefix of the service's liveliness token")
    )
    camera_info_key: str = field(
        default="", metadata=_doc("key of sensor_msgs/CameraInfo CDR giving intrinsics; '' = off")
    )
    ros_package: str = field(
        default="mrover", metadata=_doc("ROS package of StarterProjectTag (type name only)")
    )
    # Detection
    dictionary: str = field(default="DICT_4X4_50", metadata=_doc("predefined ArUco dictionary"))
    detector: str = field(
        default="tracking",
        metadata=_doc("'tracking' (OpenCV's detector, whole frames only when needed) or 'opencv'"),
    )
    full_scan_period: int = field(
        default=4,
        metadata=_doc("tracking: whole-frame scan at least every N frames (new tags within N)"),
    )
    opencv_threads: int = field(
        default=0, metadata=_doc("OpenCV worker threads; 0 = OpenCV's default")
    )
    min_tag_side_px: float = field(
        default=0.0,
        metadata=_doc("drop tags whose mean side is shorter than this, pixels; 0 = off"),
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
        default=5.0, metadata=_doc("at most one warning per rejection reason per interval")
    )

    def __post_init__(self) -> None:
        _validate(self)

    def tag_size_for(self, tag_id: int) -> float:
        """Physical size of ``tag_id`` in metres (0.0 when unknown)."""
        for known_id, size in self.tag_sizes:
            if known_id == tag_id:
                return size
        return self.tag_size_m

    @property
    def has_intrinsics(self) -> bool:
        return self.camera_fx > 0.0 and self.camera_fy > 0.0

    def as_dict(self) -> dict[str, Any]:
        """Plain-data view (for the status reply and logs)."""
        data = asdict(self)
        data["tag_sizes"] = {str(k): v for k, v in self.tag_sizes}
        return data


def _validate(settings: Settings) -> None:
    for name in ("input_key", "tag_key", "record_key", "status_key", "liveliness_key"):
        if not getattr(settings, name):
            msg = f"{name} must not be empty"
            raise SettingsError(msg)
    if settings.policy not in tuple(Policy):
        msg = f"policy must be one of {', '.join(Policy)}, not {settings.policy!r}"
        raise SettingsError(msg)
    if settings.metric not in METRICS:
        msg = f"metric must be one of {', '.join(METRICS)}, not {settings.metric!r}"
        raise SettingsError(msg)
    if settings.detector not in DETECTORS:
        msg = f"detector must be one of {', '.join(DETECTORS)}, not {settings.detector!r}"
        raise SettingsError(msg)
    dictionary_name(settings.dictionary)
    positive = ("max_range_m", "debug_image_max_hz")
    non_negative = (
        "min_tag_side_px",
        "tag_size_m",
        "camera_fx",
        "camera_fy",
        "camera_cx",
        "camera_cy",
        "stats_interval_s",
        "log_interval_s",
        "opencv_threads",
    )
    for name in positive:
        value = getattr(settings, name)
        if not math.isfinite(value) or value <= 0:
            msg = f"{name} must be a positive number, not {value!r}"
            raise SettingsError(msg)
    for name in non_negative:
        value = getattr(settings, name)
        if not math.isfinite(value) or value < 0:
            msg = f"{name} must be zero or positive, not {value!r}"
            raise SettingsError(msg)
    if not 1 <= settings.full_scan_period <= 1000:
        msg = f"full_scan_period must be 1..1000, not {settings.full_scan_period}"
        raise SettingsError(msg)
    if not 1 <= settings.debug_jpeg_quality <= 100:
        msg = f"debug_jpeg_quality must be 1..100, not {settings.debug_jpeg_quality}"
        raise SettingsError(msg)
    for tag_id, size in settings.tag_sizes:
        if tag_id < 0 or not math.isfinite(size) or size <= 0:
            msg = f"tag_sizes entry {tag_id}={size} needs an id >= 0 and a size > 0"
            raise SettingsError(msg)
    if (
        settings.metric == "distance"
        and not (settings.has_intrinsics and (settings.tag_size_m > 0 or settings.tag_sizes))
        and not settings.camera_info_key
    ):
        msg = "metric 'distance' needs camera intrinsics (or camera_info_key) and a tag size"
        raise SettingsError(msg)


def _field_kind(f: Field[Any]) -> type:
    hint = typing.get_type_hints(Settings)[f.name]
    if hint in (str, int, float, bool):
        return typing.cast(type, hint)
    return tuple  # tag sizes


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
            items.append((key, size))
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
    try:
        pairs = tuple(sorted((int(str(k)), float(str(v))) for k, v in items))
    except ValueError as err:
        msg = f"tag_sizes: {err}"
        raise SettingsError(msg) from err
    return pairs


def _coerce(f: Field[Any], value: object) -> object:
    kind = _field_kind(f)
    if kind is tuple:
        return _parse_tag_sizes(value)
    if kind is bool:
        if isinstance(value, bool):
            return value
    elif kind is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
    elif kind is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif isinstance(value, str):
        return value
    msg = f"setting {f.name} must be {kind.__name__}, not {value!r}"
    raise SettingsError(msg)


def settings_from_mapping(
    values: Mapping[str, object], base: Settings | None = None, *, source: str = "settings"
) -> Settings:
    """``base`` (default: the defaults) with ``values`` applied; unknown keys are errors."""
    known = {f.name: f for f in fields(Settings)}
    unknown = sorted(set(values) - set(known))
    if unknown:
        msg = f"{source}: unknown setting(s) {', '.join(unknown)}"
        raise SettingsError(msg)
    coerced = {name: _coerce(known[name], value) for name, value in values.items()}
    return replace(base if base is not None else Settings(), **coerced)  # type: ignore[arg-type]


def load_settings(path: Path | None, overrides: Mapping[str, object] | None = None) -> Settings:
    """Defaults, then the TOML file at ``path`` (if any), then ``overrides``.

    Raises:
        SettingsError: unreadable file, bad TOML, unknown key, wrong type or invalid value.

    """
    settings = Settings()
    if path is not None:
        try:
            with path.open("rb") as stream:
                data = tomllib.load(stream)
        except (OSError, tomllib.TOMLDecodeError) as err:
            msg = f"cannot read settings file {path}: {err}"
            raise SettingsError(msg) from err
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
        help_text = f"{f.metadata.get('help', '')} (default: {default!r})"
        if kind is bool:
            group.add_argument(
                flag,
                dest=f.name,
                action=argparse.BooleanOptionalAction,
                default=None,
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
    "DETECTORS",
    "METRICS",
    "Settings",
    "add_settings_arguments",
    "load_settings",
    "setting_names",
    "settings_from_args",
    "settings_from_mapping",
]
